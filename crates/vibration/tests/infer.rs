//! Forcing inference and difference attribution (issue 16) against independent truth: the
//! measured runs are made by direct time-domain deposition of the instantaneous TIF under the
//! vibration (`coupling::direct_removal`, no expansion), on a textured before surface with
//! measurement noise on both maps; the inference uses the fast expansion with its own noise seed.

use bonnetlab_process::path::RasterSpec;
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::GaussianTif;
use bonnetlab_process::{Grid, PathLog};
use bonnetlab_surface::{Surface, Term};
use bonnetlab_vibration::coupling::{
    direct_removal, fast_maps, predict, CouplingInput, CouplingOptions,
};
use bonnetlab_vibration::infer::synth::{measured_pair, white_noise};
use bonnetlab_vibration::infer::{
    attribute_difference, counterfactual_effect, infer_forcing, shared_forcing, vibration_effects,
    CauseEffect, Difference, ForcingFit, ForcingModel, InferOptions, RunEffects,
};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use ndarray::Array2;

const N: usize = 200;
const D: f64 = 0.25;
const PITCH: f64 = 3.0;
const RPM: f64 = 558.0;
const FEED: f64 = 30.0;

/// The run's tool (process's TIF front end) from a Gaussian TIF, at the map pixel.
fn tool_of(t: GaussianTif) -> ToolModel {
    ToolModel::from_source(&TifSource::Gaussian(t), None, D, D).unwrap()
}

fn grid() -> Grid {
    Grid::new(N, N, D, D, 0.0, 0.0).unwrap()
}

fn path() -> PathLog {
    let mut spec = RasterSpec::over_rect((0.0, 50.0), (-3.0, 53.0), PITCH, FEED);
    spec.overtravel_mm = 6.0;
    spec.sample_dt_s = 0.02;
    spec.generate().unwrap()
}

fn tif(scale: f64) -> GaussianTif {
    GaussianTif::new(1.0 * scale, 8.0 * scale, 1500.0 / (scale * scale)).unwrap()
}

/// The robot at the x2 resonance (558 rpm), broadband force 0.5 N RMS, robot damping `zeta`.
fn params(fn_n: f64, zeta: f64) -> VibrationParams {
    VibrationParams {
        spindle_rpm: RPM,
        fn_n,
        noise_force_rms_n: 0.5,
        zeta1: zeta,
        zeta2: zeta,
        ..Default::default()
    }
}

/// Default robot damping ratio and the same plus the suppression element's ζ_e = η / 2.
const ZETA: f64 = 0.05;
const ZETA_DAMPED: f64 = 0.05 + 0.115 / 2.0;

fn opts(seed: u64) -> CouplingOptions {
    CouplingOptions {
        sample_hz: 500.0,
        seed,
        ..Default::default()
    }
}

fn noise(seed: u64, rms: f64) -> Array2<f64> {
    white_noise(N, N, rms, seed)
}

fn surf(z: Array2<f64>) -> Surface {
    Surface::new(z, Some(D), Some(D)).unwrap()
}

/// A measured run: before, after (direct deposition + noise), measured removal.
struct Measured {
    before: Surface,
    after: Surface,
    removal: Surface,
}

fn measure(truth_removal: &Array2<f64>, seed: u64, noise_nm: f64) -> Measured {
    let (b, a) = measured_pair(truth_removal, D, 77, seed, noise_nm);
    let removal = &b - &a;
    Measured {
        before: surf(b),
        after: surf(a),
        removal: surf(removal),
    }
}

struct Fitted {
    model: ForcingModel,
    fit: ForcingFit,
    m: Measured,
}

/// One measured run made by direct deposition with the true TIF `t` (vibration seed 11) and its
/// forcing fitted with the fast model on TIF `t_model` (vibration seed 2: the inference does not
/// know the truth's noise realisation).
fn run(truth: &VibrationParams, bonnet: Bonnet, t: &GaussianTif, t_model: &GaussianTif) -> Fitted {
    let g = grid();
    let p = path();
    let tool_1 = tool_of(*t);
    let input = CouplingInput {
        grid: g,
        valid: None,
        tool: &tool_1,
        path: &p,
        params: truth,
        pitch_mm: Some(PITCH),
    };
    let direct = direct_removal(&input, bonnet, &opts(11)).unwrap();
    let m = measure(&direct, 1000 + (truth.fn_n * 10.0) as u64, 1.0);
    let tool_2 = tool_of(*t_model);
    let minput = CouplingInput {
        tool: &tool_2,
        ..input
    };
    let model = ForcingModel::build(&minput, bonnet, &opts(2)).unwrap();
    let fit = infer_forcing(&model, &m.removal, &InferOptions::default()).unwrap();
    eprintln!(
        "{bonnet} (zeta {}): truth {} N; fitted {:.3} N, noise force {:.2} N, rate scale {:.4}, \
         measurement noise {:.3} nm, dchi2(F=0) {:.1}\n  {:?}",
        truth.zeta1,
        truth.fn_n,
        fit.best_fn_n,
        fit.noise_force_rms_n,
        fit.rate_scale,
        fit.meas_noise_rms_nm,
        fit.delta_chi2_zero_fn,
        fit.forcing
    );
    Fitted { model, fit, m }
}

const REMOVE: [Term; 2] = [Term::Piston, Term::Tilt];

fn rms(s: &Surface) -> f64 {
    let (r, _) = bonnetlab_surface::remove_terms(s, &REMOVE).unwrap();
    bonnetlab_surface::height_stats(&r).unwrap().rms_nm
}

/// The run's measured σ1 and CR(RMS) with the coupling mechanisms' effects and `extra` causes.
fn effects(name: &str, f: &Fitted, extra: Vec<CauseEffect>) -> RunEffects {
    let mut causes = vibration_effects(&f.model, &f.fit, &f.m.before, &f.m.after, &REMOVE).unwrap();
    causes.extend(extra);
    let sigma1 = bonnetlab_spectrum::ripple(&f.m.after, PITCH, &Default::default())
        .unwrap()
        .sigma1_nm;
    let cr = (rms(&f.m.before) - rms(&f.m.after)) / rms(&f.m.before);
    for c in &causes {
        eprintln!(
            "  {name} {:<16} d_sigma1 {:+.4} ± {:.4} nm, d_cr {:+.5} ± {:.5}",
            c.cause, c.sigma1_nm, c.sigma1_sd_nm, c.cr_rms, c.cr_rms_sd
        );
    }
    eprintln!("  {name}: sigma1 {sigma1:.4} nm, CR(RMS) {cr:.5}");
    RunEffects {
        name: name.into(),
        sigma1_nm: sigma1,
        cr_rms: cr,
        sigma1_noise_sd_nm: 0.0,
        cr_rms_noise_sd: 0.0,
        causes,
    }
}

const VIBRATION: [&str; 4] = ["normal_offset", "lateral_jitter", "envelope", "interaction"];

fn vibration_share(d: &Difference) -> f64 {
    d.causes
        .iter()
        .filter(|c| VIBRATION.contains(&c.cause.as_str()))
        .map(|c| c.share_of_sigma1_difference)
        .sum()
}

fn within(x: f64, truth: f64, tol: f64) -> bool {
    (x - truth).abs() <= tol * truth
}

/// Two runs of the same bonnet, forcing and path (fn 5 N at the x2 resonance, 30 mm/s feed so the
/// spindle imprint along the scan, 9.3 Hz / 30 mm/s = 0.31 /mm, passes the 1 mm-sigma spot);
/// the only difference is the robot damping (ζ 0.05 vs 0.1075 = 0.05 + η/2). A third run with the
/// suppression bonnet (same added damping plus its series compliance) joins the shared fit.
///
/// Measured (this seed set, fn 5 N true): fitted 5.07 N (ζ 0.05; 95 % interval [4.82, 5.33]),
/// 5.26 N (ζ 0.1075; [4.94, 5.61]), 5.27 N (suppression bonnet; [4.87, 5.68]); end-of-robot
/// amplitude 0.140 mm vs 0.068 mm; one shared forcing 5.17 N fits all three (Δχ² = 1.13 on 4 dof,
/// p = 0.890). σ1 (after map) B − A = +0.149 nm (the rectified offset swing widens the mean spot
/// and lowers the ripple of the less damped run); shares: normal_offset 0.926, all vibration
/// mechanisms 0.922, unexplained 0.078. The broadband level (0.5 N true) is not resolved here:
/// fitted 0 N with a 95 % interval reaching above 1 N, which must contain the truth.
#[test]
fn damping_pair_forcing_within_30_percent_and_difference_attributed_to_vibration() {
    let t = tif(1.0);
    let a = run(&params(5.0, ZETA), Bonnet::Original, &t, &t);
    let b = run(&params(5.0, ZETA_DAMPED), Bonnet::Original, &t, &t);
    let c = run(&params(5.0, ZETA), Bonnet::Suppression, &t, &t);
    for f in [&a, &b, &c] {
        let v = &f.fit.forcing;
        assert!(v.constrained, "{v:?}");
        let fitted = v.fn_n.unwrap();
        assert!(within(fitted, 5.0, 0.3), "fitted {fitted} N vs 5 N");
        let [lo, hi] = v.interval_n.unwrap();
        assert!(
            lo <= 5.0 && 5.0 <= hi,
            "95 % interval [{lo}, {hi}] misses 5 N"
        );
        assert!(v.upper_bound_n.is_none() && v.end_amplitude_mm.unwrap() > 0.0);
        let [nlo, nhi] = f.fit.noise_interval_n.expect("broadband interval");
        assert!(
            nlo <= 0.5 && 0.5 <= nhi,
            "broadband [{nlo}, {nhi}] misses 0.5 N"
        );
    }
    // More damping, less end-of-robot motion at the same forcing.
    assert!(
        b.fit.forcing.end_amplitude_mm.unwrap() < 0.7 * a.fit.forcing.end_amplitude_mm.unwrap()
    );

    let sh = shared_forcing(&[&a.fit, &b.fit, &c.fit]).unwrap();
    eprintln!("shared: {}", sh.reason);
    assert!(sh.consistent && sh.plausible, "{}", sh.reason);
    assert!(within(sh.forcing[0].fn_n.unwrap(), 5.0, 0.3));

    let ea = effects("A", &a, vec![]);
    let eb = effects("B", &b, vec![]);
    let d = attribute_difference(&ea, &eb);
    eprintln!("{d:#?}");
    let vib = vibration_share(&d);
    eprintln!("vibration share of the sigma1 difference: {vib:.3}");
    assert!(
        d.sigma1_difference_nm.abs() > 0.05,
        "{}",
        d.sigma1_difference_nm
    );
    assert!(VIBRATION.contains(&d.causes[0].cause.as_str()) && d.causes[0].significant);
    assert!((0.7..=1.3).contains(&vib), "vibration share {vib}");
    let sum: f64 = d.causes.iter().map(|c| c.share_of_sigma1_difference).sum();
    assert!((sum + d.unexplained_share_of_sigma1_difference - 1.0).abs() < 1e-12);
}

/// Same bonnet, same vibration (fn 5 N), but run B's working spot is 15 % wider (same volume
/// rate). The lead's wiring is played here: B's forcing is fitted on the calibrated (wider) TIF
/// and the calibrated `tif_scale` effect is the counterfactual with the nominal TIF's removal at
/// the fitted forcing, SD from a scale uncertainty of 0.02.
///
/// Measured: B's fitted forcing 5.05 N (95 % [4.69, 5.44]); σ1 B − A = −8.04 nm; shares:
/// tif_scale 1.010 (significant), vibration mechanisms −0.030, unexplained 0.019.
#[test]
fn wider_spot_pair_gives_vibration_less_than_10_percent() {
    let t = tif(1.0);
    let wide = tif(1.15);
    let a = run(&params(5.0, ZETA), Bonnet::Original, &t, &t);
    let b = run(&params(5.0, ZETA), Bonnet::Original, &wide, &wide);
    assert!(
        within(b.fit.forcing.fn_n.unwrap(), 5.0, 0.3),
        "{:?}",
        b.fit.forcing
    );

    let p = path();
    let prm = params(5.0, ZETA);
    let tool_3 = tool_of(t);
    let nominal = ForcingModel::build(
        &CouplingInput {
            grid: grid(),
            valid: None,
            tool: &tool_3,
            path: &p,
            params: &prm,
            pitch_mm: Some(PITCH),
        },
        Bonnet::Original,
        &opts(2),
    )
    .unwrap();
    let (f, s) = (b.fit.best_fn_n, b.fit.noise_force_rms_n);
    let added = (b.model.maps(f, s).total() - nominal.maps(f, s).total()) * b.fit.rate_scale;
    let (ds, dc) = counterfactual_effect(&b.m.before, &b.m.after, &added, PITCH, &REMOVE).unwrap();
    let rel = 0.02 / 0.15;
    let tif_scale = CauseEffect {
        cause: "tif_scale".into(),
        sigma1_nm: ds,
        sigma1_sd_nm: ds.abs() * rel,
        cr_rms: dc,
        cr_rms_sd: dc.abs() * rel,
    };
    let ea = effects("A", &a, vec![]);
    let eb = effects("B", &b, vec![tif_scale]);
    let d = attribute_difference(&ea, &eb);
    eprintln!("{d:#?}");
    let vib = vibration_share(&d);
    eprintln!("vibration share of the sigma1 difference: {vib:.4}");
    assert!(
        d.sigma1_difference_nm < -1.0,
        "wider spot smooths the ripple"
    );
    assert!(vib.abs() < 0.1, "vibration share {vib}");
    assert_eq!(d.causes[0].cause, "tif_scale");
    assert!(d.causes[0].significant);
    assert!((0.8..=1.2).contains(&d.causes[0].share_of_sigma1_difference));
}

/// No spindle-harmonic forcing at all (broadband noise and ring-down only): the fit must say it
/// cannot constrain the amplitude and give an upper bound, never a number.
///
/// Measured: one-sided 95 % upper bound 0.158 N (end amplitude at the bound 0.0044 mm).
#[test]
fn no_vibration_signal_gives_an_upper_bound() {
    let t = tif(1.0);
    let f = run(&params(0.0, ZETA), Bonnet::Original, &t, &t);
    let v = &f.fit.forcing;
    assert!(!v.constrained, "{v:?}");
    assert!(v.fn_n.is_none() && v.interval_n.is_none());
    let ub = v.upper_bound_n.expect("an upper bound");
    // The 5 N forcing of the other tests would have been seen.
    assert!(ub > 0.0 && ub < 1.0, "upper bound {ub} N");
    assert!(v.end_amplitude_mm.unwrap() > 0.0);
    assert!(v.reason.contains("upper bound"), "{}", v.reason);
}

/// The forcing polynomial is exact: at an arbitrary forcing it reproduces a fresh fast coupling
/// run map for map, and its `predicted` matches the coupling's own `predict` at that forcing.
#[test]
fn forcing_polynomial_reproduces_the_coupling_at_any_forcing() {
    let t = tif(1.0);
    let p = path();
    let prm = VibrationParams {
        noise_force_rms_n: 0.8,
        ..params(3.7, ZETA)
    };
    let tool_4 = tool_of(t);
    let input = CouplingInput {
        grid: grid(),
        valid: None,
        tool: &tool_4,
        path: &p,
        params: &prm,
        pitch_mm: Some(PITCH),
    };
    for bonnet in Bonnet::ALL {
        let model = ForcingModel::build(&input, bonnet, &opts(2)).unwrap();
        let poly = model.maps(3.7, 0.8);
        let fresh = fast_maps(&input, bonnet, &opts(2)).unwrap();
        let scale = fresh.total().iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for name in ["normal_offset", "lateral_jitter", "envelope", "interaction"] {
            let (a, b) = (poly.by_name(name).unwrap(), fresh.by_name(name).unwrap());
            let err = (a - b).iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let size = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            eprintln!("{bonnet} {name}: max |poly - fresh| {err:.3e} nm of {size:.3e} nm");
            assert!(size > 0.0 && err <= 1e-9 * scale, "{name}: {err} of {size}");
        }
        let band = CouplingOptions::default().msf_band_per_mm;
        let pred = model.predicted(&input, 3.7, 0.8, 1.0, band, None).unwrap();
        let reference = predict(&input, bonnet, &opts(2)).unwrap();
        let s1 = pred.sigma1_nm.unwrap();
        let r1 = reference.ripple_sigma1_nm.unwrap();
        assert!((s1 - r1).abs() <= 1e-9 * r1, "{s1} vs {r1}");
        assert!(
            (pred.msf_rms_nm - reference.removal_msf_band_rms_nm).abs()
                <= 1e-9 * reference.removal_msf_band_rms_nm
        );
        for (a, b) in pred.mechanisms.iter().zip(&reference.mechanisms) {
            assert_eq!(a.name, b.name);
            assert!(
                (a.share - b.share).abs() < 1e-6,
                "{} {} {}",
                a.name,
                a.share,
                b.share
            );
        }
    }
}

/// At the paper's process (1.6 mm/s feed, 1000 rpm) the spindle imprint along the scan sits at
/// 16.7 Hz / 1.6 mm/s = 10.4 /mm, beyond what a 1 mm-sigma spot passes and beyond the 0.25 mm
/// map's Nyquist (2 /mm); the rectified ripple change is a fraction of a percent. Even with the
/// model's own prediction of a true 5 N forcing as the measurement (its most favourable case),
/// the fit must say the data cannot constrain the forcing rather than print a number.
///
/// Measured: no imprint (Δχ²(F = 0) ≈ 0), no bound within the searched 0-20 N.
#[test]
fn paper_feed_cannot_constrain_the_spindle_forcing() {
    let mut spec = RasterSpec::over_rect((0.0, 50.0), (-3.0, 53.0), PITCH, 1.6);
    spec.overtravel_mm = 6.0;
    let p = spec.generate().unwrap();
    let t = GaussianTif::new(1.0, 8.0, 80.0).unwrap();
    let prm = VibrationParams {
        spindle_rpm: 1000.0,
        ..params(5.0, ZETA)
    };
    let tool_5 = tool_of(t);
    let input = CouplingInput {
        grid: grid(),
        valid: None,
        tool: &tool_5,
        path: &p,
        params: &prm,
        pitch_mm: Some(PITCH),
    };
    let truth = fast_maps(&input, Bonnet::Original, &opts(11))
        .unwrap()
        .total();
    let removal = surf(truth + noise(4, 1.4));
    let model = ForcingModel::build(&input, Bonnet::Original, &opts(2)).unwrap();
    let fit = infer_forcing(&model, &removal, &InferOptions::default()).unwrap();
    eprintln!(
        "dchi2(F=0) {:.3}: {:?}",
        fit.delta_chi2_zero_fn, fit.forcing
    );
    let v = &fit.forcing;
    assert!(
        !v.constrained && v.fn_n.is_none() && v.interval_n.is_none(),
        "{v:?}"
    );
    // Whatever bound there is must not exclude the true 5 N.
    assert!(v.upper_bound_n.is_none_or(|u| u >= 5.0), "{v:?}");
}

/// A measured map on another grid is an error naming both shapes, not a panic.
#[test]
fn mismatched_map_is_an_error() {
    let t = tif(1.0);
    let p = path();
    let prm = params(1.0, ZETA);
    let tool_6 = tool_of(t);
    let input = CouplingInput {
        grid: grid(),
        valid: None,
        tool: &tool_6,
        path: &p,
        params: &prm,
        pitch_mm: Some(PITCH),
    };
    let model = ForcingModel::build(&input, Bonnet::Original, &opts(2)).unwrap();
    let small = Surface::new(Array2::zeros((50, 60)), Some(D), Some(D)).unwrap();
    let e = infer_forcing(&model, &small, &InferOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("50x60") && e.contains("200x200"), "{e}");
}
