//! Hold-out selection on synthetic runs: noise alone accepts nothing; two simultaneous effects
//! are both found; effects outside the library's exact forms are reported (as an effect of the
//! library's generic kinds or as unexplained structure) and the residual falls by at least half.

mod common;

use bonnetlab::calibrate::run::Calibration;
use bonnetlab::calibrate::synth::{Injected, SynthConfig, Waveform, WiggleCoord};
use common::calibrate::{param, run, run_cfg, summary};

/// No effect injected (issue 14's null runs): noise-free or noisy, the measured spot centred or
/// 0.25 or 0.8 mm off its map centre: nothing is accepted. Before the calibration used the
/// process crate's forward model, 0.25 mm off (seed 23) accepted a feed covariate of -0.04 s/mm
/// at the noise floor, noise-free runs accepted tif_scale 1.0044 plus a feed covariate, and the
/// tests' own spot pipeline reported a path offset of (-0.68, +0.45) mm at 0.8 mm off.
#[test]
fn off_centre_spots_accept_no_effect() {
    let mut bad = Vec::new();
    for (seed, noise_nm) in [(23, 0.3), (24, 0.0)] {
        for off in [0.0, 0.25, 0.8] {
            let c = run_cfg(&SynthConfig {
                seed,
                noise_nm,
                spot_noise_nm: if noise_nm > 0.0 { 0.1 } else { 0.0 },
                spot_offset_mm: (off, -0.6 * off),
                ..SynthConfig::default()
            });
            if !c.effects.is_empty() {
                bad.push(format!(
                    "seed {seed} noise {noise_nm} off {off}: {}",
                    summary(&c)
                ));
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// A spot map without noise of the precessing bonnet (a simulated spot), centred, on textured
/// runs with noisy maps and no effect: nothing is accepted. Before the TIF front end's noise
/// test had a floor (`FIT_NOISE_FLOOR`), the border ring's zero noise refused the exact bonnet
/// fit, the pixel interpolant's unresolved rim made the TIF about 1 % narrow, and 6 of 12 such
/// runs of issue 15's harness (400^2) accepted tif_scale 1.010-1.015.
#[test]
fn a_noise_free_spot_accepts_no_effect() {
    let mut bad = Vec::new();
    for seed in [3, 4, 5] {
        let cfg = SynthConfig {
            spot_noise_nm: 0.0,
            spot_offset_mm: (0.0, 0.0),
            ..SynthConfig::realistic(
                seed,
                200,
                100.0,
                bonnetlab::calibrate::synth::InitialSurface::realistic_texture(2.2),
            )
        };
        let c = run_cfg(&cfg);
        if !c.effects.is_empty() {
            bad.push(format!("seed {seed}: {}", summary(&c)));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn noise_only_accepts_no_effect() {
    for seed in [21, 22] {
        let c = run(vec![], seed);
        assert!(c.effects.is_empty(), "seed {seed}: {}", summary(&c));
        assert!(
            c.final_.residual_rms_nm <= 1.3 * c.noise_floor_rms_nm,
            "{}",
            summary(&c)
        );
        // The floor estimate matches the injected noise: 0.3 nm per map, in quadrature.
        assert!(
            (c.noise_floor_rms_nm - 0.3 * 2f64.sqrt()).abs() < 0.05,
            "{}",
            summary(&c)
        );
    }
}

#[test]
fn drift_and_misregistration_are_both_found() {
    let c = run(
        vec![
            Injected::RateDrift {
                fraction_per_run: 0.2,
            },
            Injected::Registration {
                dx_mm: -0.3,
                dy_mm: 0.25,
                rotation_deg: 0.0,
            },
        ],
        23,
    );
    let kinds: Vec<&str> = c.effects.iter().map(|e| e.kind.as_str()).collect();
    assert!(
        kinds.contains(&"rate_drift") && kinds.contains(&"registration"),
        "{}",
        summary(&c)
    );
    let f = c
        .effects
        .iter()
        .find(|e| e.kind == "rate_drift")
        .unwrap()
        .params["fraction_per_run"]
        .as_f64()
        .unwrap();
    assert!((f - 0.2).abs() < 0.04, "{}", summary(&c));
    let dx = c
        .effects
        .iter()
        .find(|e| e.kind == "registration")
        .unwrap()
        .params["dx_mm"]
        .as_f64()
        .unwrap();
    assert!((dx + 0.3).abs() < 0.06, "{}", summary(&c));
    assert!(
        c.final_.residual_rms_nm <= 1.3 * c.noise_floor_rms_nm,
        "{}",
        summary(&c)
    );
}

/// Three at once (drift, lag, misregistration with rotation): exactly these three, each within
/// 20 %, residual at the floor.
#[test]
fn three_effects_at_once_are_all_found() {
    let c = run(
        vec![
            Injected::RateDrift {
                fraction_per_run: -0.15,
            },
            Injected::DirectionLag { lag_mm: 0.3 },
            Injected::Registration {
                dx_mm: 0.25,
                dy_mm: 0.1,
                rotation_deg: -0.08,
            },
        ],
        11,
    );
    assert_eq!(c.effects.len(), 3, "{}", summary(&c));
    for (kind, name, want) in [
        ("rate_drift", "fraction_per_run", -0.15),
        ("direction_lag", "lag_mm", 0.3),
        ("registration", "dx_mm", 0.25),
        ("registration", "dy_mm", 0.1),
        ("registration", "rotation_deg", -0.08),
    ] {
        let got = param(&c, kind, name);
        assert!(
            (got - want).abs() <= 0.2 * want.abs(),
            "{kind} {name} {got}: {}",
            summary(&c)
        );
    }
    assert!(
        c.final_.residual_rms_nm <= 1.3 * c.noise_floor_rms_nm,
        "{}",
        summary(&c)
    );
}

/// A misregistration of several millimetres is first mistaken for a path offset (a wiggle at
/// the raster pitch wins round one); once the registration is found, that stand-in refines to
/// nothing (3 um) and the backward check must drop it: only the registration is reported.
#[test]
fn large_misregistration_leaves_no_stand_in_effect() {
    let c = run(
        vec![Injected::Registration {
            dx_mm: 3.3,
            dy_mm: -0.9,
            rotation_deg: 0.4,
        }],
        11,
    );
    let kinds: Vec<&str> = c.effects.iter().map(|e| e.kind.as_str()).collect();
    assert_eq!(kinds, ["registration"], "{}", summary(&c));
    assert!((param(&c, "registration", "dx_mm") - 3.3).abs() < 0.05 * 3.3);
    assert!((param(&c, "registration", "rotation_deg") - 0.4).abs() < 0.05 * 0.4);
    assert!(
        c.final_.residual_rms_nm <= 1.3 * c.noise_floor_rms_nm,
        "{}",
        summary(&c)
    );
}

/// Outside the exact forms: reported (any effect or unexplained entry) and residual halved.
fn outside(effects: Vec<Injected>, seed: u64) -> Calibration {
    let c = run(effects, seed);
    assert!(
        !c.effects.is_empty() || !c.unexplained.is_empty(),
        "{}",
        summary(&c)
    );
    c
}

#[test]
fn rate_oscillating_in_time_is_found_and_removed() {
    let c = outside(
        vec![Injected::RateOscillation {
            amplitude_fraction: 0.1,
            period_s: 170.0,
        }],
        24,
    );
    let e = c
        .effects
        .iter()
        .find(|e| e.kind == "rate_oscillation")
        .unwrap_or_else(|| panic!("{}", summary(&c)));
    let p = e.params["period_s"].as_f64().unwrap();
    let a = e.params["amplitude_fraction"].as_f64().unwrap();
    assert!(
        (p - 170.0).abs() < 0.2 * 170.0 && (a - 0.1).abs() < 0.02,
        "{}",
        summary(&c)
    );
    assert!(
        c.final_.residual_rms_nm <= 0.5 * c.baseline.residual_rms_nm,
        "{}",
        summary(&c)
    );
}

/// On a 100 mm part a slow rate oscillation (300 s, about one cycle per twenty raster lines)
/// varies along y like a path wiggle in y that squeezes the line spacing: their linearised
/// held-out scores tie (0.99 vs 0.94 of the residual), and the spec-first preference alone
/// took the wiggle (final 0.77 nm vs a 0.43 nm floor). Refining both and comparing must pick
/// the oscillation and reach the floor.
/// Open (issue 15, identifiability): with the generator on process's kinematics, seed 5 takes a
/// 0.42 mm y-wiggle of 27 mm period plus a 0.9 % oscillation at 154 s (final 0.64 nm vs a
/// 0.42 nm floor; the generator's author saw seed 7 fail and seeds 6 and 8 pass). Seed 6 is
/// held here so the right answer cannot regress; the tie needs the joint refit and the
/// both-reported rule.
#[test]
fn slow_rate_oscillation_beats_a_path_wiggle_on_a_large_part() {
    let cfg = SynthConfig {
        rows: 200,
        cols: 200,
        pixel_mm: 0.5,
        deposit_step_mm: 0.2,
        seed: 6,
        effects: vec![Injected::RateOscillation {
            amplitude_fraction: 0.1,
            period_s: 300.0,
        }],
        ..SynthConfig::default()
    };
    let c = run_cfg(&cfg);
    assert_eq!(c.effects.len(), 1, "{}", summary(&c));
    assert_eq!(c.effects[0].kind, "rate_oscillation", "{}", summary(&c));
    let period = c.effects[0].params["period_s"].as_f64().unwrap();
    let amp = c.effects[0].params["amplitude_fraction"].as_f64().unwrap();
    assert!((period - 300.0).abs() < 0.2 * 300.0, "{}", summary(&c));
    assert!((amp - 0.1).abs() < 0.02, "{}", summary(&c));
    assert!(
        c.final_.residual_rms_nm <= 1.3 * c.noise_floor_rms_nm,
        "{}",
        summary(&c)
    );
}

#[test]
fn pressure_step_is_absorbed() {
    let c = outside(
        vec![Injected::RateStep {
            at_tau: 0.6,
            fraction: -0.15,
        }],
        25,
    );
    assert!(
        c.final_.residual_rms_nm <= 0.5 * c.baseline.residual_rms_nm,
        "{}",
        summary(&c)
    );
}

#[test]
fn triangle_path_error_is_reported_and_reduced() {
    let c = outside(
        vec![Injected::PeriodicPathError {
            axis_x: true,
            amplitude_mm: 0.4,
            period_mm: 15.0,
            phase_rad: 0.0,
            coord: WiggleCoord::Arc,
            waveform: Waveform::Triangle,
        }],
        26,
    );
    assert!(
        c.final_.residual_rms_nm <= 0.5 * c.baseline.residual_rms_nm,
        "{}",
        summary(&c)
    );
}

#[test]
fn local_defect_is_unexplained_and_located() {
    let c = run(
        vec![Injected::LocalDefect {
            x_mm: 30.0,
            y_mm: 50.0,
            radius_mm: 2.5,
            depth_nm: 8.0,
        }],
        27,
    );
    let u = c
        .unexplained
        .first()
        .unwrap_or_else(|| panic!("{}", summary(&c)));
    let r = u.region_mm;
    assert!(
        r[0] <= 30.0 && r[1] >= 30.0 && r[2] <= 50.0 && r[3] >= 50.0,
        "{}",
        summary(&c)
    );
}

/// The accepted round's score of `kind` (held-out z, reduction as a fraction of the held-out
/// sum of squares), from the calibration's own rounds.
fn accepted_score(c: &Calibration, kind: &str) -> Option<(f64, f64)> {
    let r = c
        .rounds
        .iter()
        .find(|r| r.accepted.as_deref().is_some_and(|a| a.starts_with(kind)))?;
    let s = r.candidates.iter().find(|s| s.key.starts_with(kind))?;
    Some((s.z, s.heldout_reduction_fraction))
}

/// A signal odd in the travel direction is held to its held-out z alone, not to the size bar
/// (`selection::odd_in_travel`), on textured, noisy runs (0.7 and 1.0 nm white noise) with a
/// round aperture: a 0.4 mm lag (issue 15's 1x size, 3 mm pitch) and a +-6 % rate between +x
/// and -x lines (a kind no library entry names, found as `rate_per_direction`; 2 mm pitch,
/// where the spot averages most of it away) are each accepted with a held-out reduction below
/// `MIN_FRACTION`, so the size bar would have refused them as it did before the rule; each
/// twin run without the effect accepts nothing; both parameters come out within 20 %. Seeds
/// 31-36 all pass (lag z 4.8-6.8 at 0.0013-0.0037 of the sum of squares, 0.35-0.41 mm; rate
/// z 7.1-8.5 at 0.0030-0.0045, 0.059-0.064); one is kept.
#[test]
fn signals_odd_in_travel_are_found_under_the_size_bar() {
    use bonnetlab::calibrate::selection::MIN_FRACTION;
    use bonnetlab::calibrate::synth::InitialSurface;
    for (effect, kind, pitch_mm, name, truth) in [
        (
            Injected::DirectionLag { lag_mm: 0.4 },
            "direction_lag",
            3.0,
            "lag_mm",
            0.4,
        ),
        (
            Injected::DirectionRate { fraction: 0.06 },
            "rate_per_direction",
            2.0,
            "fraction",
            0.06,
        ),
    ] {
        let base = SynthConfig {
            aperture_diameter_mm: Some(90.0),
            pitch_mm,
            ..SynthConfig::realistic(32, 400, 100.0, InitialSurface::realistic_texture(2.2))
                .with_noise_nm(0.7, 1.0)
        };
        let twin = run_cfg(&base);
        assert!(twin.effects.is_empty(), "{kind} twin: {}", summary(&twin));
        let c = run_cfg(&SynthConfig {
            effects: vec![effect],
            ..base
        });
        let kinds: Vec<&str> = c.effects.iter().map(|e| e.kind.as_str()).collect();
        assert_eq!(kinds, [kind], "{}", summary(&c));
        let (z, fraction) = accepted_score(&c, kind).expect("the accepted round's score");
        assert!(
            z >= 4.0 && fraction < MIN_FRACTION,
            "{kind}: z {z}, reduction {fraction}"
        );
        let v = param(&c, kind, name);
        assert!(
            (v - truth).abs() <= 0.2 * truth,
            "{kind} {name} {v}: {}",
            summary(&c)
        );
    }
}

/// A 0.4 mm lag on a 2 mm raster over a square part: neighbouring lines run in opposite
/// directions and the lag's first-order terms cancel under the 10 mm spot, so what it leaves is
/// mostly second order (the line ends' dwell spread along the travel) and the linear lag column
/// explains 12-15 % of it (issue #15's harness). The candidate is the secant column at the lag
/// the linear one implies (`effects::direction_lag`), scored by the block z that follows a
/// signal living at the turnarounds (`selection::block_z`). Seeds 31-36: all six found at
/// 0.385-0.406 mm, held-out z 7.9-15; before, four at z 5.0-5.2 and seeds 34 and 36 not at all
/// (those two are kept). Each twin without the lag accepts nothing.
#[test]
fn a_lag_on_a_fine_raster_is_found_by_its_second_order_signal() {
    use bonnetlab::calibrate::synth::InitialSurface;
    for seed in [34, 36] {
        let base = SynthConfig {
            pitch_mm: 2.0,
            ..SynthConfig::realistic(seed, 400, 100.0, InitialSurface::realistic_texture(2.2))
                .with_noise_nm(0.7, 1.0)
        };
        let twin = run_cfg(&base);
        assert!(
            twin.effects.is_empty(),
            "seed {seed} twin: {}",
            summary(&twin)
        );
        let c = run_cfg(&SynthConfig {
            effects: vec![Injected::DirectionLag { lag_mm: 0.4 }],
            ..base
        });
        let kinds: Vec<&str> = c.effects.iter().map(|e| e.kind.as_str()).collect();
        assert_eq!(kinds, ["direction_lag"], "seed {seed}: {}", summary(&c));
        let (z, _) = accepted_score(&c, "direction_lag").expect("the accepted round's score");
        assert!(z >= 6.0, "seed {seed}: z {z}");
        let v = param(&c, "direction_lag", "lag_mm");
        assert!(
            (v - 0.4).abs() <= 0.04,
            "seed {seed}: lag {v}: {}",
            summary(&c)
        );
    }
}
