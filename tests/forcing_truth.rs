//! The forcing fit (`bonnetlab_vibration::infer::infer_forcing`) against independent truth: the
//! original recipe run (`recipe_samples`: 5 N spindle-harmonic forcing, 0.5 N broadband, the
//! original bonnet, a 15-45 mm/s raster at 3 mm pitch) made by the generator's exact time-domain
//! deposition (`VibrationDeposition`, 500 Hz vibration series, its own seed), fitted with the
//! fast coupling expansion on the accurate (true Gaussian) TIF and the logged path.
//!
//! Cases: the clean removal (no path effect, no noise) and the removal with the original run's
//! 0.3 mm direction lag (servo lag along the travel, not in the forcing model) plus 0.7 nm RMS
//! white measurement noise (the sample runs' removal noise: 0.5 nm per map in quadrature).

use bonnetlab::pipeline::bonnets::Options;
use bonnetlab::pipeline::recipe_samples::{
    generate_run_with, recipe_runs, recipe_tif, recipe_vibration, synth_config, RECIPE_SEED,
};
use bonnetlab_calibrate::synth::Injected;
use bonnetlab_calibrate::synth::SynthRun;
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::measured::{MeasuredTif, Rim, SpotModel, SpotOptions};
use bonnetlab_process::tif::{RateField, Tif};
use bonnetlab_process::Grid;
use bonnetlab_spectrum::{psd_xy, PsdOptions};
use bonnetlab_surface::Surface;
use bonnetlab_vibration::coupling::{direction_lag_path, CouplingInput};
use bonnetlab_vibration::infer::synth::white_noise;
use bonnetlab_vibration::infer::{infer_forcing, ForcingFit, ForcingModel};
use bonnetlab_vibration::params::VibrationParams;
use ndarray::Array2;

/// Truth of the spindle-harmonic forcing, N.
const TRUE_FN_N: f64 = 5.0;

struct Case {
    removal: Surface,
    model: ForcingModel,
}

/// Which TIF the forcing model is built on.
#[derive(Clone, Copy, Debug)]
enum Tool {
    /// The generator's true Gaussian.
    True,
    /// The run's measured spot through the TIF front end with this rim.
    Spot(Rim),
}

/// The run's measured spot (`run.spot`, the generator's `spot.dat`) through the TIF front end.
fn spot_field(run: &SynthRun, rim: Rim) -> MeasuredTif {
    let o = SpotOptions {
        rim,
        ..Default::default()
    };
    MeasuredTif::from_spot(&run.spot, run.spot_dwell_s, &o).unwrap()
}

fn tool_model(run: &SynthRun, tool: Tool, dx: f64, dy: f64) -> ToolModel {
    match tool {
        Tool::True => {
            ToolModel::from_source(&TifSource::Gaussian(recipe_tif()), None, dx, dy).unwrap()
        }
        Tool::Spot(rim) => {
            let m = spot_field(run, rim);
            ToolModel::Measured(Tif::sample(&m, dx, dy).unwrap(), Box::new(m))
        }
    }
}

fn case(lag_mm: Option<f64>, noise_nm: f64) -> Case {
    case_with(lag_mm, noise_nm, Tool::True, false)
}

fn case_with(lag_mm: Option<f64>, noise_nm: f64, which: Tool, model_lag: bool) -> Case {
    let spec = recipe_runs(RECIPE_SEED)[0].clone();
    let mut cfg = synth_config(&spec);
    cfg.effects = lag_mm
        .map(|l| vec![Injected::DirectionLag { lag_mm: l }])
        .unwrap_or_default();
    let run = generate_run_with(&spec, &cfg, &recipe_vibration()).unwrap();
    let grid = Grid::of(&run.before).unwrap();
    let (dx, dy) = (grid.dx_mm, grid.dy_mm);
    let z: Array2<f64> = &run.true_removal_nm + &white_noise(grid.rows, grid.cols, noise_nm, 4242);
    let removal = Surface::new(z, Some(dx), Some(dy)).unwrap();
    let tool = tool_model(&run, which, dx, dy);
    let params = recipe_vibration();
    let input = CouplingInput {
        grid,
        valid: None,
        tool: &tool,
        path: &run.path,
        params: &params,
        pitch_mm: Some(run.pitch_mm),
    };
    let model_lag_mm = lag_mm.filter(|_| model_lag).unwrap_or(0.0);
    let model = ForcingModel::build_lagged(
        &input,
        spec.bonnet,
        &Options::default().coupling,
        model_lag_mm,
    )
    .unwrap();
    Case { removal, model }
}

fn fit(c: &Case, what: &str) -> ForcingFit {
    let f = infer_forcing(&c.model, &c.removal, &Options::default().infer).unwrap();
    eprintln!(
        "{what}: fitted {:.3} N (truth {TRUE_FN_N}), broadband {:.2} N (truth 0.5), rate scale \
         {:.4}, noise {:.3} nm, bins {}, residual var {:.4}, dchi2(F=0) {:.1}\n  {:?}",
        f.best_fn_n,
        f.noise_force_rms_n,
        f.rate_scale,
        f.meas_noise_rms_nm,
        f.bins,
        f.residual_var,
        f.delta_chi2_zero_fn,
        f.forcing
    );
    f
}

fn check(f: &ForcingFit, tol: f64, what: &str, interval: bool) {
    let v = &f.forcing;
    assert!(v.constrained, "{what}: {v:?}");
    let fitted = v.fn_n.unwrap();
    assert!(
        (fitted - TRUE_FN_N).abs() <= tol * TRUE_FN_N,
        "{what}: fitted {fitted:.3} N vs truth {TRUE_FN_N} N (tolerance {tol})"
    );
    let [lo, hi] = v.interval_n.unwrap();
    assert!(
        !interval || (lo <= TRUE_FN_N && TRUE_FN_N <= hi),
        "{what}: 95 % interval [{lo:.3}, {hi:.3}] N misses the truth"
    );
}

/// Measured: clean 4.783 N, 95 % interval [4.231, 5.386] N; lag + noise 5.463 N [5.224, 5.708]
/// N, measurement noise fitted 0.694 nm (truth 0.707). The broadband force (0.5 N true) is not
/// resolved by either fit (0.71 N clean, 3.24 N with the lag: it has no band of its own).
/// Main's fit over every X and Y bin with a free rate scale gave 1.910 N [1.732, 2.133] (clean,
/// rate scale 1.74) and 6.853 N [6.035, 7.788] (lag + noise, broadband 3.24 N): 62 % and 37 %
/// off, both intervals missing the truth.
///
/// With the lag the fitted forcing is 9 % high and its interval misses 5 N by 0.22 N: the lag
/// shifts neighbouring raster lines ±0.3 mm along the scan, which changes how their imprints
/// (about 2.9 mm period) add where the spot overlaps two lines: +17 % imprint power in the
/// band over the clean run's (`lag_model_reproduces_the_lag_change_of_the_imprint`). The
/// commanded-path model cannot have that, and the interval only carries the PSD's scatter; so
/// the lagged case is held to the tolerance and not the interval.
///
/// Why the lag-aware model (`ForcingModel::build_lagged`, what `compare` uses) does not bring
/// it to the truth yet, with 0.7 nm noise and the true TIF: 5.594 N on the run's 50 Hz log.
/// Two model errors outside the lag remain, both measured against the exact deposition:
/// (1) the clock: the coupling re-times the log under the acceleration limit, and the log's
/// samples cut the raster's corners, so the re-timed run takes 65.59 s where the generator's
/// (re-timing its fine motion) takes 64.85 s: the spindle phase from line to line, which sets
/// how neighbouring imprints add, drifts (on the generator's motion the fit reads 5.335 N clean
/// and 5.268 N lagged, and the exact deposition matches the truth to 0.1 % in every band bin);
/// (2) the fast expansion's imprint power falls below the exact deposition's on the same clock
/// by 6 / 16 / 24 / 35 % at 0.30 / 0.36 / 0.40 / 0.46 per mm (clean and lagged alike), which
/// the fit makes up with forcing (+5-7 %).
#[test]
fn forcing_fit_recovers_the_true_forcing_on_exact_deposition() {
    let clean = case(None, 0.0);
    let f_clean = fit(&clean, "clean");
    let lagged = case(Some(0.3), 0.7);
    let f_lag = fit(&lagged, "lag 0.3 mm + 0.7 nm noise");
    check(&f_clean, 0.1, "clean", true);
    check(&f_lag, 0.1, "lag 0.3 mm + 0.7 nm noise", false);
    assert!(
        (f_lag.meas_noise_rms_nm - 0.7).abs() < 0.05,
        "measurement noise {} nm vs 0.7 nm",
        f_lag.meas_noise_rms_nm
    );
}

/// |MTF| (the TIF's transform over its volume) along X at `f` per mm, by a direct sum over a
/// 0.02 mm grid (odd-symmetric part cancels only for a centred TIF, so the modulus is taken).
fn mtf_x(t: &dyn RateField, f: f64) -> f64 {
    let (hx, hy) = t.half_extent_mm();
    let d = 0.02;
    let (nx, ny) = ((hx / d).ceil() as i64, (hy / d).ceil() as i64);
    let (mut v, mut re, mut im) = (0.0, 0.0, 0.0);
    for i in -ny..=ny {
        for j in -nx..=nx {
            let (x, y) = (j as f64 * d, i as f64 * d);
            let r = t.rate_at_mm(x, y);
            let a = 2.0 * std::f64::consts::PI * f * x;
            v += r;
            re += r * a.cos();
            im += r * a.sin();
        }
    }
    re.hypot(im) / v
}

/// Peak (nm/s), volume (nm mm^2/s) and RMS radius along X (mm) of a field.
fn moments(t: &dyn RateField) -> (f64, f64, f64) {
    let (hx, hy) = t.half_extent_mm();
    let d = 0.02;
    let (nx, ny) = ((hx / d).ceil() as i64, (hy / d).ceil() as i64);
    let (mut peak, mut v, mut xx) = (0.0f64, 0.0, 0.0);
    for i in -ny..=ny {
        for j in -nx..=nx {
            let (x, y) = (j as f64 * d, i as f64 * d);
            let r = t.rate_at_mm(x, y);
            peak = peak.max(r);
            v += r;
            xx += r * x * x;
        }
    }
    (peak, v * d * d, (xx / v).sqrt())
}

/// Issue 14: the sample runs' measured spot (the generator's `spot.dat`: the true Gaussian,
/// sigma 1.35 mm, dwelled 0.2 s at 0.25 mm pixels with 0.3 nm noise) through the TIF front end,
/// against the true TIF, in the imprint band and in the forcing fit. The bonnet fit is rejected
/// on this spot; main then interpolated the pixels, whose footprint is cut at 0.5 % of the peak
/// and rolled off to 1.3 times that radius: that tail cut is a ripple in the transfer where the
/// Gaussian's is 1e-3 of its volume. The smooth model describes the spot (residual within the
/// noise) and is kept to 1e-6 of its peak.
///
/// Measured (|MTF_x| relative to the true TIF's at 0.24 / 0.30 / 0.35 / 0.40 / 0.46 per mm,
/// where it is 0.126 / 0.039 / 0.012 / 0.0032 / 0.0005): interpolated -0.2 / +0.6 / +6.4 /
/// +25 / +100 %; smooth model (sigma 1.3494 mm, beta 0.9991, peak 850.7 nm/s) +0.03 / +0.24 /
/// +0.76 / +1.7 / +6.4 %. Forcing fitted with 0.7 nm noise (truth 5 N): true TIF 5.044 N,
/// smooth 5.054 N, interpolated 4.352 N (-13 %); with the 0.3 mm lag and the model with the
/// lag at the run's clock (what `compare` does): true 5.594 N, smooth 5.602 N (with the moved
/// and re-timed path before: 5.284 / 5.298 N, interpolated 4.646 N). (The
/// noise-free cases are not held: with no noise the fit weighs model errors far below any
/// measurement, and even the true TIF reads 4.78 N clean, 5.10 N lagged.)
#[test]
fn spot_derived_tif_reads_the_forcing_as_the_true_tif_does() {
    let spec = recipe_runs(RECIPE_SEED)[0].clone();
    let run = generate_run_with(&spec, &synth_config(&spec), &recipe_vibration()).unwrap();
    let truth = recipe_tif();
    let interp = spot_field(&run, Rim::Interpolate);
    let smooth = spot_field(&run, Rim::ModelPlusResidual);
    let Some(SpotModel::Smooth(g)) = smooth.model() else {
        panic!(
            "the sample spot is not described by the smooth model: {:?}",
            smooth.model()
        );
    };
    eprintln!("smooth model {g:?}");
    assert!((g.sigma_mm / truth.sigma_mm - 1.0).abs() < 0.005, "{g:?}");
    let fields: [(&str, &dyn RateField); 2] = [("interpolated", &interp), ("smooth", &smooth)];
    for (name, t) in fields {
        let (peak, vol, sx) = moments(t);
        eprintln!(
            "{name}: radius {:.2} mm, peak {peak:.2} nm/s, volume {vol:.2} nm mm^2/s, rms x {sx:.4} mm",
            t.half_extent_mm().0
        );
        for f in [0.24, 0.3, 0.35, 0.4, 0.46] {
            let rel = mtf_x(t, f) / mtf_x(&truth, f) - 1.0;
            eprintln!(
                "  |MTF_x| at {f} /mm: {:.5} ({:+.2} %)",
                mtf_x(t, f),
                100.0 * rel
            );
            if name == "smooth" && f <= 0.4 {
                assert!(
                    rel.abs() < 0.03,
                    "smooth TIF's transfer at {f} /mm off by {rel}"
                );
            }
        }
    }
    let fn_of = |lag: Option<f64>, tool: Tool| {
        let c = case_with(lag, 0.7, tool, lag.is_some());
        let what = format!("{tool:?}, lag {lag:?} (in the model too), 0.7 nm noise");
        fit(&c, &what).forcing.fn_n.unwrap()
    };
    fn_of(None, Tool::Spot(Rim::Interpolate));
    for lag in [None, Some(0.3)] {
        let t = fn_of(lag, Tool::True);
        let s = fn_of(lag, Tool::Spot(Rim::ModelPlusResidual));
        assert!(
            (s / t - 1.0).abs() < 0.01,
            "lag {lag:?}: forcing {s:.3} N with the spot's TIF, {t:.3} N with the true TIF"
        );
    }
}

/// X-PSD power (one-sided, nm^2 mm summed over bins) of `z` in [lo, hi] per mm.
fn band_power_x(z: &Array2<f64>, g: &Grid, lo: f64, hi: f64) -> f64 {
    let s = Surface::new(z.clone(), Some(g.dx_mm), Some(g.dy_mm)).unwrap();
    let (x, _) = psd_xy(&s, &PsdOptions::default()).unwrap();
    x.freq_per_mm
        .iter()
        .zip(&x.psd_nm2_mm)
        .filter(|(f, _)| (lo..=hi).contains(*f))
        .map(|(_, p)| p)
        .sum()
}

/// How a servo lag enters the forcing model. The lag is where the tool is at each instant
/// (executed = path − lag · u, the generator's and the calibration's `direction_lag`), so the
/// spindle phase along every raster line stays the run's. Neighbouring lines run in opposite
/// directions, so the lag shifts their imprints by 2 · lag against each other and changes
/// how they add where the spot covers two lines: on the sample run the imprint's power in
/// the band (0.28-0.44 per mm along X, the spindle-harmonic imprint, from the exact
/// deposition at 5 N minus 0 N) rises by 17 % with the 0.3 mm lag.
///
/// The forcing model with the lag applied at the run's clock (`build_lagged`, after the
/// re-timing) is held to that rise, on the generator's motion (the run's true clock). Measured:
/// truth +17.0 %, model +20.5 %. Moving the path's samples back and re-timing that path (main's
/// `lag_path`) stretched the re-timed clock by 4.09 s over 65.6 s (sharper corners stop the
/// robot longer): the spindle phase from line to line is then not the run's.
#[test]
fn lag_model_reproduces_the_lag_change_of_the_imprint() {
    let spec = recipe_runs(RECIPE_SEED)[0].clone();
    let lag = 0.3;
    let band = (0.28, 0.44);
    let mut rise = Vec::new();
    for model_lag in [true, false] {
        let mut p = [0.0; 4];
        for (n, l) in [None, Some(lag)].into_iter().enumerate() {
            let mut cfg = synth_config(&spec);
            cfg.effects = l
                .map(|l| vec![Injected::DirectionLag { lag_mm: l }])
                .unwrap_or_default();
            let gen = |f: f64| {
                let v = VibrationParams {
                    fn_n: f,
                    ..recipe_vibration()
                };
                generate_run_with(&spec, &cfg, &v).unwrap()
            };
            let (r5, r0) = (gen(5.0), gen(0.0));
            let grid = Grid::of(&r5.before).unwrap();
            let tool = tool_model(&r5, Tool::True, grid.dx_mm, grid.dy_mm);
            let params = recipe_vibration();
            let moved = l
                .filter(|_| !model_lag)
                .map(|l| direction_lag_path(&r5.motion, l).unwrap());
            let input = CouplingInput {
                grid,
                valid: None,
                tool: &tool,
                path: moved.as_ref().unwrap_or(&r5.motion),
                params: &params,
                pitch_mm: Some(r5.pitch_mm),
            };
            let ml = l.filter(|_| model_lag).unwrap_or(0.0);
            let m =
                ForcingModel::build_lagged(&input, spec.bonnet, &Options::default().coupling, ml)
                    .unwrap();
            let imp_m = m.maps(5.0, 0.5).total() - m.maps(0.0, 0.5).total();
            let imp_t = &r5.true_removal_nm - &r0.true_removal_nm;
            p[2 * n] = band_power_x(&imp_t, &grid, band.0, band.1);
            p[2 * n + 1] = band_power_x(&imp_m, &grid, band.0, band.1);
        }
        let (t, m) = (p[2] / p[0], p[3] / p[1]);
        eprintln!(
            "model lag at the run's clock {model_lag}: imprint band power lagged / clean: truth \
             {t:.4}, model {m:.4}"
        );
        rise.push((t, m));
    }
    let (t, m) = rise[0];
    assert!(t > 1.1, "truth's rise {t}");
    assert!(
        ((m - 1.0) / (t - 1.0) - 1.0).abs() < 0.25,
        "lagged / clean imprint power: model {m:.4}, truth {t:.4}"
    );
}
