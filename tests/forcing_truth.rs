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
use bonnetlab_process::path::kinematics::{apply_limits, Limits};
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::{ToolModel, ToolShape};
use bonnetlab_process::tif::measured::{MeasuredTif, Rim, SpotModel, SpotOptions};
use bonnetlab_process::tif::{RateField, Tif};
use bonnetlab_process::Grid;
use bonnetlab_process::PathLog;
use bonnetlab_spectrum::{psd_xy, PsdOptions};
use bonnetlab_surface::Surface;
use bonnetlab_vibration::coupling::fast::executed_path;
use bonnetlab_vibration::coupling::{
    direction_lag_path, fast_maps, CouplingInput, CouplingOptions, Mechanisms,
};
use bonnetlab_vibration::infer::synth::white_noise;
use bonnetlab_vibration::infer::{infer_forcing, ForcingFit, ForcingModel};
use bonnetlab_vibration::params::VibrationParams;
use ndarray::Array2;

/// The run made with the recipe's vibration at a 5 N forcing and at none (the same seed).
fn forced_and_unforced(
    spec: &bonnetlab::pipeline::recipe_samples::RecipeRunSpec,
    cfg: &bonnetlab_calibrate::synth::SynthConfig,
) -> (SynthRun, SynthRun) {
    let at = |f: f64| {
        let v = VibrationParams {
            fn_n: f,
            ..recipe_vibration()
        };
        generate_run_with(spec, cfg, &v).unwrap()
    };
    (at(5.0), at(0.0))
}

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
            ToolModel::from(ToolShape::Measured(
                Tif::sample(&m, dx, dy).unwrap(),
                Box::new(m),
            ))
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

/// Held: the fit with 0.7 nm noise, clean and with the 0.3 mm lag in the run and in the model
/// (`build_lagged`, what `compare` uses), within 5 % of 5 N; the lagged run fitted with the
/// commanded-path model (no lag) within 10 %. Measured with the coupling's clock and imprint
/// fixed (`coupling_clock_from_the_log_is_the_runs`,
/// `fast_imprint_power_tracks_exact_deposition_in_the_band`): clean + noise 4.796 N, lag +
/// noise 4.793 N (before: 5.044 N and 5.594 N, the clean one right only because the log's
/// stretched clock and the second-order expansion's 7-36 % low imprint power cancelled); the
/// commanded-path model on the lagged run 5.139 N (5.463 N before).
///
/// The remaining -4 %: on the run's log the coupling's imprint power is still 0-5 % above the
/// exact deposition's in the band (the restored corners' times split the chord's interval at
/// constant speed where the robot decelerates into the corner); on the generator's motion it
/// is within 1.7 %.
///
/// Not held: the noise-free clean removal, 3.974 N (4.783 N before). With no measurement noise
/// the fit weighs the model's errors in bins where the imprint has 1e-7 of its peak power
/// (beyond 0.54 per mm the fourth-order expansion overshoots the exact deposition several
/// times there); any measurement's noise floor covers them.
#[test]
fn forcing_fit_recovers_the_true_forcing_on_exact_deposition() {
    fit(&case(None, 0.0), "clean, no noise (not held)");
    let f_clean = fit(&case(None, 0.7), "clean + 0.7 nm noise");
    let f_lag = fit(
        &case_with(Some(0.3), 0.7, Tool::True, true),
        "lag 0.3 mm (in the model too) + 0.7 nm noise",
    );
    let f_cmd = fit(
        &case(Some(0.3), 0.7),
        "lag 0.3 mm (commanded-path model) + 0.7 nm noise",
    );
    check(&f_clean, 0.05, "clean + 0.7 nm noise", false);
    check(&f_lag, 0.05, "lag 0.3 mm + 0.7 nm noise", false);
    check(&f_cmd, 0.1, "lag 0.3 mm, commanded-path model", false);
    for f in [&f_clean, &f_lag] {
        assert!(
            (f.meas_noise_rms_nm - 0.7).abs() < 0.05,
            "measurement noise {} nm vs 0.7 nm",
            f.meas_noise_rms_nm
        );
    }
}

/// Calls `f(x, y, rate)` at every node of a 0.02 mm grid over the field's extent; returns the
/// node spacing (mm).
fn over_nodes(t: &dyn RateField, mut f: impl FnMut(f64, f64, f64)) -> f64 {
    let (hx, hy) = t.half_extent_mm();
    let d = 0.02;
    let (nx, ny) = ((hx / d).ceil() as i64, (hy / d).ceil() as i64);
    for i in -ny..=ny {
        for j in -nx..=nx {
            let (x, y) = (j as f64 * d, i as f64 * d);
            f(x, y, t.rate_at_mm(x, y));
        }
    }
    d
}

/// |MTF| (the TIF's transform over its volume) along X at `f` per mm, by a direct sum over a
/// 0.02 mm grid (odd-symmetric part cancels only for a centred TIF, so the modulus is taken).
fn mtf_x(t: &dyn RateField, f: f64) -> f64 {
    let (mut v, mut re, mut im) = (0.0, 0.0, 0.0);
    over_nodes(t, |x, _, r| {
        let a = 2.0 * std::f64::consts::PI * f * x;
        v += r;
        re += r * a.cos();
        im += r * a.sin();
    });
    re.hypot(im) / v
}

/// Peak (nm/s), volume (nm mm^2/s) and RMS radius along X (mm) of a field.
fn moments(t: &dyn RateField) -> (f64, f64, f64) {
    let (mut peak, mut v, mut xx) = (0.0f64, 0.0, 0.0);
    let d = over_nodes(t, |x, _, r| {
        peak = peak.max(r);
        v += r;
        xx += r * x * x;
    });
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
/// +0.76 / +1.7 / +6.4 %. Forcing fitted with 0.7 nm noise (truth 5 N), with the coupling's
/// clock and imprint fixed: true TIF 4.796 N, smooth 4.806 N, interpolated 3.985 N (-17 %);
/// with the 0.3 mm lag and the model with the lag at the run's clock (what `compare` does):
/// true 4.793 N, smooth 4.806 N. (Before those fixes: 5.044 / 5.054 / 4.352 N and 5.594 /
/// 5.602 N.) The noise-free cases are not held: with no noise the fit weighs model errors far
/// below any measurement.
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
/// truth +17.0 %, model +17.2 % (+20.5 % with the second-order expansion). Moving the path's samples back and re-timing that path (main's
/// `lag_path`) stretched the re-timed clock by 4.09 s over 65.6 s (sharper corners stop the
/// robot longer): the spindle phase from line to line is then not the run's (model +6.7 %).
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
            let (r5, r0) = forced_and_unforced(&spec, &cfg);
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

/// The generator's clock: its deposition re-times the fine motion under the acceleration limit.
fn generator_clock(run: &SynthRun, grid: &Grid) -> PathLog {
    let limits = Limits {
        a_max_mm_per_s2: recipe_vibration().accel_max_mm_per_s2,
        ..Limits::default()
    };
    apply_limits(&run.motion, &limits, 0.5 * grid.dx_mm.min(grid.dy_mm)).unwrap()
}

/// Times (s) at which the path crosses x = `x_mm`, in order.
fn crossings(p: &PathLog, x_mm: f64) -> Vec<f64> {
    let mut v = Vec::new();
    for k in 0..p.len() - 1 {
        let (a, b) = (p.x_mm[k] - x_mm, p.x_mm[k + 1] - x_mm);
        if a * b < 0.0 {
            v.push(p.t_s[k] + (p.t_s[k + 1] - p.t_s[k]) * a / (a - b));
        }
    }
    v
}

/// The coupling's clock (the executed path it builds from the run's 50 Hz log) is the run's:
/// the generator re-times its fine motion; the log's samples cut the raster's corners, and
/// re-timing the chords stretched the run to 65.585 s against the generator's 64.854 s, so
/// the spindle phase from line to line drifted (the imprints of neighbouring lines add with
/// that phase). With the corners restored (`PathLog::with_corners`): 64.858 s.
#[test]
fn coupling_clock_from_the_log_is_the_runs() {
    let spec = recipe_runs(RECIPE_SEED)[0].clone();
    let mut cfg = synth_config(&spec);
    cfg.effects.clear();
    let run = generate_run_with(&spec, &cfg, &recipe_vibration()).unwrap();
    let grid = Grid::of(&run.before).unwrap();
    let truth = generator_clock(&run, &grid);
    let tool = tool_model(&run, Tool::True, grid.dx_mm, grid.dy_mm);
    let params = recipe_vibration();
    let input = CouplingInput {
        grid,
        valid: None,
        tool: &tool,
        path: &run.path,
        params: &params,
        pitch_mm: Some(run.pitch_mm),
    };
    let exec = executed_path(&input, &Mechanisms::ALL).unwrap();
    let (te, tt) = (exec.duration_s(), truth.duration_s());
    let (ce, ct) = (crossings(&exec, 25.0), crossings(&truth, 25.0));
    assert_eq!(ce.len(), ct.len());
    let worst = ce
        .iter()
        .zip(&ct)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f64, f64::max);
    eprintln!(
        "executed from the log {te:.4} s, the generator's {tt:.4} s; {} lines cross x = 25 mm, \
         worst time difference {worst:.4} s ({:.1} deg of the 9.3 Hz spindle)",
        ce.len(),
        360.0 * params.excitation_hz() * worst
    );
    assert!((te - tt).abs() < 0.05, "run's clock {te} s vs {tt} s");
    assert!(
        worst < 0.01,
        "line crossing times differ by up to {worst} s"
    );
}

/// X-PSD (one-sided, nm^2 mm) bins of `z` in [lo, hi] per mm: (frequency, power).
fn psd_x_bins(z: &Array2<f64>, g: &Grid, lo: f64, hi: f64) -> Vec<(f64, f64)> {
    let s = Surface::new(z.clone(), Some(g.dx_mm), Some(g.dy_mm)).unwrap();
    let (x, _) = psd_xy(&s, &PsdOptions::default()).unwrap();
    x.freq_per_mm
        .iter()
        .zip(&x.psd_nm2_mm)
        .filter(|(f, _)| (lo..=hi).contains(*f))
        .map(|(&f, &p)| (f, p))
        .collect()
}

/// The fast coupling's spindle imprint (removal at 5 N minus at 0 N, X PSD over the imprint band
/// 0.26-0.46 per mm) against the exact time-domain deposition of the clean sample run (the
/// generator's, 500 Hz vibration series, seed 11):
/// (a) on the generator's motion with the generator's vibration series, so only the expansion
///     differs: the second-order expansion with a bilinear splat and pixel-mean offset kernels
///     gave 0.930 / 0.835 / 0.761 / 0.637 of the exact power at 0.30 / 0.36 / 0.40 / 0.46 per
///     mm; with the offset to fourth order, the cubic splat and point-valued offset kernels
///     1.001 / 1.011 / 1.017 / 0.997, held to 3 % in every bin;
/// (b) on the run's 50 Hz log with the coupling's own series (1 kHz, seed 1), what `compare`
///     fits: was 0.785 / 0.808 / 0.889 / 0.599 (the log's clock and the expansion), now
///     1.032 / 1.054 / 1.001 / 1.049, held to 0.9-1.08 in every bin.
#[test]
fn fast_imprint_power_tracks_exact_deposition_in_the_band() {
    let spec = recipe_runs(RECIPE_SEED)[0].clone();
    let mut cfg = synth_config(&spec);
    cfg.effects.clear();
    let (r5, r0) = forced_and_unforced(&spec, &cfg);
    let grid = Grid::of(&r5.before).unwrap();
    let tool = tool_model(&r5, Tool::True, grid.dx_mm, grid.dy_mm);
    let imprint = |path: &PathLog, o: &CouplingOptions| {
        let at = |f: f64| {
            let p = VibrationParams {
                fn_n: f,
                ..recipe_vibration()
            };
            let input = CouplingInput {
                grid,
                valid: None,
                tool: &tool,
                path,
                params: &p,
                pitch_mm: Some(r5.pitch_mm),
            };
            fast_maps(&input, spec.bonnet, o).unwrap().total()
        };
        at(5.0) - at(0.0)
    };
    let band = (0.26, 0.46);
    let truth = psd_x_bins(
        &(&r5.true_removal_nm - &r0.true_removal_nm),
        &grid,
        band.0,
        band.1,
    );
    let same_series = CouplingOptions {
        sample_hz: 500.0,
        seed: 11,
        ..Default::default()
    };
    let cases = [
        (
            "generator's motion and series",
            &r5.motion,
            same_series,
            0.97,
            1.03,
        ),
        (
            "the run's log",
            &r5.path,
            CouplingOptions::default(),
            0.9,
            1.08,
        ),
    ];
    for (what, path, o, lo, hi) in cases {
        let m = psd_x_bins(&imprint(path, &o), &grid, band.0, band.1);
        for (&(f, t), &(_, p)) in truth.iter().zip(&m) {
            let r = p / t;
            eprintln!("{what}: {f:.3} /mm: exact {t:.4e} nm^2 mm, fast / exact {r:.3}");
            assert!(
                (lo..=hi).contains(&r),
                "{what}: fast / exact imprint power {r:.3} at {f:.3} /mm"
            );
        }
    }
}
