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
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::Grid;
use bonnetlab_surface::Surface;
use bonnetlab_vibration::coupling::CouplingInput;
use bonnetlab_vibration::infer::synth::white_noise;
use bonnetlab_vibration::infer::{infer_forcing, ForcingFit, ForcingModel};
use ndarray::Array2;

/// Truth of the spindle-harmonic forcing, N.
const TRUE_FN_N: f64 = 5.0;

struct Case {
    removal: Surface,
    model: ForcingModel,
}

fn case(lag_mm: Option<f64>, noise_nm: f64) -> Case {
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
    let tool = ToolModel::from_source(&TifSource::Gaussian(recipe_tif()), None, dx, dy).unwrap();
    let params = recipe_vibration();
    let input = CouplingInput {
        grid,
        valid: None,
        tool: &tool,
        path: &run.path,
        params: &params,
        pitch_mm: Some(run.pitch_mm),
    };
    let model = ForcingModel::build(&input, spec.bonnet, &Options::default().coupling).unwrap();
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
/// (about 2.9 mm period) add where the spot overlaps two lines: about +17 % imprint power in the
/// band over the clean run's. The commanded-path model cannot have that, and the interval only
/// carries the PSD's scatter; so the lagged case is held to the tolerance and not the interval
/// (`compare` builds the forcing model on the calibrated lag's path for that reason).
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
