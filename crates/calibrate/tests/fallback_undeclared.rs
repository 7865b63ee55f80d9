//! The fallback for effects the library does not name (issue #15): on runs made by the
//! independent generator (`synth`: exact time-domain deposition at fine sub-steps, never
//! calibrate's FFT model) with power-law texture down to the pixel scale, white noise in both
//! maps, circular dropouts, round and square apertures and an off-centre measured spot, an
//! effect the library has no kind for is reported by a fallback kind that localises it, and the
//! residual is cut by at least half; on null runs the fallback accepts nothing.

mod common;

use bonnetlab_calibrate::run::{Calibration, EffectReport};
use bonnetlab_calibrate::synth::true_tif::TrueTif;
use bonnetlab_calibrate::synth::{InitialSurface, Injected, SynthConfig};
use bonnetlab_process::tif::GaussianTif;
use common::{alternate, run};

/// A 70 mm part on a 200 x 200 map (0.35 mm pixels): power-law surface (exponent 1.8-2.6),
/// round aperture on odd `r`, 3-4 circular dropouts, 0.5-1.8 nm noise per map.
///
/// The paper's bonnet spot (about 10 mm across) averages a rate alternating between adjacent
/// lines 2-3 mm apart down to below the noise (on such runs a +-6 % direction rate leaves the
/// baseline residual at the floor: nothing to find). The direction runs use a smaller spot
/// (`small_spot`), through which the alternation shows.
fn scenario(r: u64, tif: TrueTif, effects: Vec<Injected>) -> SynthConfig {
    let exponent = [2.2, 1.8, 2.6, 2.0][r as usize % 4];
    let (nb, na) = [(1.0, 0.7), (0.5, 1.6), (1.8, 1.2), (0.8, 0.9)][r as usize % 4];
    let base = SynthConfig::realistic(
        70 + r,
        200,
        70.0,
        InitialSurface::realistic_texture(exponent),
    )
    .with_noise_nm(nb, na);
    SynthConfig {
        tif,
        deposit_step_mm: 0.08,
        effects,
        ..alternate(base, r, 63.0)
    }
}

fn bonnet() -> TrueTif {
    TrueTif::bonnet(800.0)
}

/// A truncated Gaussian spot, sigma 1.2 mm, 7 mm across, peak 40 nm/s.
fn small_spot() -> TrueTif {
    TrueTif::Gaussian(GaussianTif {
        sigma_mm: 1.2,
        diameter_mm: 7.0,
        peak_rate_nm_per_s: 40.0,
    })
}

fn kinds(c: &Calibration) -> Vec<&str> {
    c.effects.iter().map(|e| e.kind.as_str()).collect()
}

/// Share of the baseline residual's excess over the true noise floor (mean squares) that the
/// calibration removed. The maps' white noise cannot be removed by any effect, so the cut is
/// measured on what stands above it.
fn excess_cut(c: &Calibration, floor: f64) -> f64 {
    let ex = |r: f64| (r * r - floor * floor).max(0.0);
    1.0 - ex(c.final_.residual_rms_nm) / ex(c.baseline.residual_rms_nm)
}

/// The residual is cut by at least half of its excess over the floor and ends within 10 % of
/// the floor; the baseline stood well above it (the effect was there to find).
fn assert_cut(c: &Calibration, floor: f64, r: u64) {
    let (b, f) = (c.baseline.residual_rms_nm, c.final_.residual_rms_nm);
    assert!(
        b >= 1.1 * floor,
        "run {r}: baseline {b:.3} nm vs floor {floor:.3} nm"
    );
    assert!(
        excess_cut(c, floor) >= 0.5 && f <= 1.1 * floor,
        "run {r}: residual {b:.3} -> {f:.3} nm, floor {floor:.3} nm ({:?})",
        kinds(c)
    );
}

fn find<'a>(c: &'a Calibration, kind: &str) -> &'a EffectReport {
    c.effects
        .iter()
        .find(|e| e.kind == kind)
        .unwrap_or_else(|| panic!("{kind} not accepted: {:?}", kinds(c)))
}

fn num(e: &EffectReport, k: &str) -> f64 {
    e.params
        .get(k)
        .and_then(|v| v.as_f64())
        .unwrap_or_else(|| panic!("{} has no {k}: {:?}", e.kind, e.params))
}

fn list(e: &EffectReport, k: &str) -> Vec<f64> {
    e.params
        .get(k)
        .and_then(|v| v.as_array())
        .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
        .unwrap_or_else(|| panic!("{} has no {k}: {:?}", e.kind, e.params))
}

/// A rate 6 % higher on lines travelled in +x than at turns and 6 % lower in -x (either sign):
/// reported as `rate_per_direction` with the right sign and size within 20 %, the residual's
/// excess over the noise floor cut by half.
#[test]
fn direction_rate_is_reported_per_direction() {
    for (r, f) in [(0, 0.06), (1, -0.06)] {
        let (c, floor) = run(&scenario(
            r,
            small_spot(),
            vec![Injected::DirectionRate { fraction: f }],
        ));
        let e = find(&c, "rate_per_direction");
        let est = num(e, "fraction");
        assert!(
            (est - f).abs() <= 0.2 * f.abs(),
            "run {r}: fraction {est:.4} vs true {f}: {:?}",
            kinds(&c)
        );
        assert_eq!(e.params.get("axis").and_then(|v| v.as_str()), Some("x"));
        assert_cut(&c, floor, r);
    }
}

/// Every raster line with its own rate (4 % RMS): reported as `rate_per_line` with a rate per
/// line whose RMS is the injected one within 30 %, the residual's excess over the floor cut by
/// half.
#[test]
fn line_rate_is_reported_per_line() {
    for r in [2, 3] {
        let (c, floor) = run(&scenario(
            r,
            bonnet(),
            vec![Injected::LineRate { rms_fraction: 0.04 }],
        ));
        let e = find(&c, "rate_per_line");
        let rel = list(e, "rate_change_fraction");
        let pos = list(e, "line_position_mm");
        assert_eq!(rel.len(), pos.len());
        let rms = (rel.iter().map(|v| v * v).sum::<f64>() / rel.len() as f64).sqrt();
        assert!(
            (0.7..=1.3).contains(&(rms / 0.04)),
            "run {r}: line rate RMS {rms:.4} vs 0.04 ({:?})",
            kinds(&c)
        );
        let pitch = if r % 2 == 0 { 2.0 } else { 3.0 };
        for w in pos.windows(2) {
            assert!((w[1] - w[0] - pitch).abs() < 0.05, "lines at {pos:?}");
        }
        assert_cut(&c, floor, r);
    }
}

/// Null runs (nothing injected, four seeds, both pitches, apertures and spots): nothing accepted, so
/// no fallback either.
#[test]
fn null_runs_accept_no_fallback() {
    for r in 4..8 {
        let tif = if r < 6 { bonnet() } else { small_spot() };
        let (c, _) = run(&scenario(r, tif, Vec::new()));
        assert!(c.effects.is_empty(), "run {r}: accepted {:?}", kinds(&c));
    }
}

/// A smooth rate map (5 % RMS, 15 mm correlation: finer than the rate map's knots two spot
/// radii apart can follow) on square parts with two textures: reported as `rate_map` refined
/// by `rate_map_fine`, whose knots lie over the part between the map's, and the residual ends
/// within 5 % of the noise floor (with the map alone it stood 10-28 % above it on the
/// harness's 400^2 runs). (On the round part of run 1 the map alone leaves 3 % above the floor
/// and the refinement, 4.5 % of the held-out sum of squares, stays below its bar.)
#[test]
fn a_rate_map_finer_than_the_knots_is_refined() {
    for r in [0, 2] {
        let (c, floor) = run(&scenario(
            r,
            bonnet(),
            vec![Injected::RateMap {
                amplitude_fraction: 0.05,
                correlation_mm: 15.0,
            }],
        ));
        let coarse = find(&c, "rate_map");
        let fine = find(&c, "rate_map_fine");
        let (cx, fx) = (list(coarse, "knot_x_mm"), list(fine, "knot_x_mm"));
        let fy = list(fine, "knot_y_mm");
        assert!(
            fx.len() > cx.len(),
            "{} fine knots vs {}",
            fx.len(),
            cx.len()
        );
        let (lo, hi) = cx.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
            (a.0.min(v), a.1.max(v))
        });
        for (x, y) in fx.iter().zip(&fy) {
            assert!(*x > lo && *x < hi, "fine knot x {x} outside ({lo}, {hi})");
            assert!(!cx.contains(x) || !list(coarse, "knot_y_mm").contains(y));
        }
        let f = c.final_.residual_rms_nm;
        assert!(
            f <= 1.05 * floor,
            "run {r}: residual {:.3} -> {f:.3} nm, floor {floor:.3} nm ({:?})",
            c.baseline.residual_rms_nm,
            kinds(&c)
        );
        assert_cut(&c, floor, r);
    }
}

/// A rate rising 25 % per sigma of the 5 mm-smoothed initial height (issue 15's case, which the
/// 2 px height left at 1.9x the noise floor over 50 harness runs): reported as the height
/// covariate with a fitted smoothing length near 5 mm, on a square and a round part, and the
/// residual's excess over the floor cut by at least half.
#[test]
fn a_rate_following_the_smoothed_height_is_found_with_its_length() {
    for r in [0, 1] {
        let (c, floor) = run(&scenario(
            r,
            bonnet(),
            vec![Injected::HeightRate {
                per_sigma: 0.25,
                smooth_mm: 5.0,
            }],
        ));
        let e = c
            .effects
            .iter()
            .find(|e| e.params.get("smoothing_mm").is_some())
            .unwrap_or_else(|| panic!("run {r}: no smoothed height: {:?}", kinds(&c)));
        assert_eq!(
            e.params.get("covariate").and_then(|v| v.as_str()),
            Some("height")
        );
        let len = num(e, "smoothing_mm");
        eprintln!(
            "run {r}: smoothing {len:.2} mm, residual {:.3} -> {:.3} nm (floor {floor:.3}), {:?}",
            c.baseline.residual_rms_nm,
            c.final_.residual_rms_nm,
            kinds(&c)
        );
        assert!(
            (3.5..=6.5).contains(&len),
            "run {r}: smoothing {len:.2} mm vs 5 ({:?})",
            kinds(&c)
        );
        assert!(
            excess_cut(&c, floor) >= 0.5,
            "run {r}: residual {:.3} -> {:.3} nm, floor {floor:.3} nm ({:?})",
            c.baseline.residual_rms_nm,
            c.final_.residual_rms_nm,
            kinds(&c)
        );
    }
}

/// The paper's bonnet (about 10 mm across) on a 2 mm raster with a rate 6 % higher on lines
/// travelled one way than the other: the spot averages the alternation between adjacent lines
/// to a ripple far below the noise (the structure is 0.1-0.7 % of the residual's sum of
/// squares), under the size bar. A signal odd in the travel direction cannot stand for the
/// forward model's own error, so it is held to its held-out z alone
/// (`selection::odd_in_travel`): it is added as a `rate_per_direction` with the right sign and
/// size within 20 %, and the final model takes at least half of the effect's own signal
/// (measured against the twin run without the effect: the same part, noise and dropouts, so
/// the maps' noise cancels exactly). The twin accepts nothing and reports nothing below the
/// bars. Before the rule these runs reported it under `unexplained`, below the bars, and the
/// signal stayed in the residual.
#[test]
fn a_direction_rate_under_the_size_bar_is_found_on_its_z() {
    for (r, f) in [(0, 0.06), (4, -0.06), (8, 0.06)] {
        let (c, floor) = run(&scenario(
            r,
            bonnet(),
            vec![Injected::DirectionRate { fraction: f }],
        ));
        let s = format!(
            "run {r}: effects {:?}, residual {:.3} -> {:.3} nm, floor {floor:.3} nm, rounds {:?}",
            kinds(&c),
            c.baseline.residual_rms_nm,
            c.final_.residual_rms_nm,
            c.rounds
                .iter()
                .map(|r| (r.accepted.clone(), r.candidates.len()))
                .collect::<Vec<_>>()
        );
        assert_eq!(kinds(&c), ["rate_per_direction"], "{s}");
        let est = c.effects[0].params["fraction"].as_f64().unwrap();
        assert!(
            (est - f).abs() <= 0.2 * f.abs(),
            "fraction {est:.4} vs {f}: {s}"
        );
        // Under the size bar: what it takes on held-out data is below MIN_FRACTION.
        let score = c.rounds[0]
            .candidates
            .iter()
            .find(|k| k.key == "rate_per_direction")
            .unwrap_or_else(|| panic!("no score: {s}"));
        assert!(
            score.heldout_reduction_fraction < bonnetlab_calibrate::selection::MIN_FRACTION
                && score.z >= bonnetlab_calibrate::effects::fallback::FALLBACK_Z,
            "z {} reduction {}: {s}",
            score.z,
            score.heldout_reduction_fraction
        );
        let (t, _) = run(&scenario(r, bonnet(), Vec::new()));
        assert!(
            t.effects.is_empty() && t.unexplained.iter().all(|u| u.below_bar.is_none()),
            "null twin of run {r}: {:?} {:?}",
            kinds(&t),
            t.unexplained
        );
        let cut = signal_cut(&c, &t);
        assert!(cut >= 0.5, "signal cut {cut:.3}: {s}");
    }
}

/// Share of an effect's own signal the final model of `c` takes, against `twin` (the same run
/// without the effect, which accepts nothing): the run's baseline residual minus the twin's is
/// the signal the baseline leaves (the baseline fit is linear in the removal), its final
/// residual minus the twin's the signal the final model leaves; the noise cancels exactly.
fn signal_cut(c: &Calibration, twin: &Calibration) -> f64 {
    let map = |m: &Option<(ndarray::Array2<f64>, ndarray::Array2<bool>)>| m.clone().unwrap();
    let (fin, fv) = map(&c.maps.final_residual_nm);
    let (base, bv) = map(&c.maps.baseline_residual_nm);
    let (tw, tv) = map(&twin.maps.baseline_residual_nm);
    let (mut left, mut total) = (0.0, 0.0);
    assert!(fin.dim() == tw.dim() && base.dim() == tw.dim());
    for (((((f, fv), b), bv), t), tv) in fin.iter().zip(&fv).zip(&base).zip(&bv).zip(&tw).zip(&tv) {
        if *fv && *bv && *tv {
            left += (f - t) * (f - t);
            total += (b - t) * (b - t);
        }
    }
    1.0 - left / total
}
