//! Forcing inference and difference attribution (issue 16) against independent truth: the
//! measured runs are made by direct time-domain deposition of the instantaneous TIF under the
//! vibration (`coupling::direct_removal`, no expansion), on a textured before surface with
//! measurement noise on both maps; the inference uses the fast expansion with its own noise seed.

use bonnetlab_process::path::RasterSpec;
use bonnetlab_process::tif::GaussianTif;
use bonnetlab_process::{Grid, PathLog};
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::{Surface, Term};
use bonnetlab_vibration::coupling::{direct_removal, CouplingInput, CouplingOptions};
use bonnetlab_vibration::infer::{
    attribute_difference, counterfactual_effect, infer_forcing, shared_forcing, vibration_effects,
    CauseEffect, ForcingFit, ForcingModel, InferOptions, RunEffects,
};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use ndarray::Array2;
use std::f64::consts::PI;

const N: usize = 200;
const D: f64 = 0.25;
const PITCH: f64 = 3.0;
const RPM: f64 = 558.0;
const FEED: f64 = 30.0;

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

fn params(fn_n: f64, noise_n: f64) -> VibrationParams {
    VibrationParams {
        spindle_rpm: RPM,
        fn_n,
        noise_force_rms_n: noise_n,
        ..Default::default()
    }
}

fn opts(seed: u64) -> CouplingOptions {
    CouplingOptions {
        sample_hz: 500.0,
        seed,
        ..Default::default()
    }
}

/// Power-law texture (1-D slope about −2) down to the pixel scale from random-phase modes.
fn texture(seed: u64) -> Array2<f64> {
    let mut r = Rng::new(seed);
    let l = N as f64 * D;
    let modes: Vec<(f64, f64, f64, f64)> = (0..400)
        .map(|_| {
            let f = (1.0 / l) * (0.5 * N as f64).powf(r.uniform());
            let th = 2.0 * PI * r.uniform();
            (
                f * th.cos(),
                f * th.sin(),
                8.0 / (f * l).max(1.0),
                2.0 * PI * r.uniform(),
            )
        })
        .collect();
    Array2::from_shape_fn((N, N), |(i, j)| {
        let (x, y) = (j as f64 * D, i as f64 * D);
        modes
            .iter()
            .map(|&(fx, fy, a, ph)| a * (2.0 * PI * (fx * x + fy * y) + ph).cos())
            .sum::<f64>()
    })
}

fn noise(seed: u64, rms: f64) -> Array2<f64> {
    let mut r = Rng::new(seed);
    Array2::from_shape_fn((N, N), |_| rms * r.normal())
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
    let b = texture(77) + noise(seed, noise_nm);
    let a = &texture(77) - truth_removal + noise(seed + 1, noise_nm);
    let removal = &b - &a;
    Measured {
        before: surf(b),
        after: surf(a),
        removal: surf(removal),
    }
}

#[test]
fn explore() {
    let g = grid();
    let p = path();
    let t = tif(1.0);
    let truth = params(4.0, 0.5);
    let input = CouplingInput {
        grid: g,
        valid: None,
        base_tif: &t,
        path: &p,
        params: &truth,
        pitch_mm: Some(PITCH),
    };
    let t0 = std::time::Instant::now();
    let direct = direct_removal(&input, Bonnet::Original, &opts(11)).unwrap();
    eprintln!("direct {:?}, duration {} s", t0.elapsed(), p.duration_s());
    let m = measure(&direct, 5, 1.0);
    let t0 = std::time::Instant::now();
    let model = ForcingModel::build(&input, Bonnet::Original, &opts(2)).unwrap();
    eprintln!("model {:?}", t0.elapsed());
    let t0 = std::time::Instant::now();
    let fit = infer_forcing(&model, &m.removal, &InferOptions::default()).unwrap();
    eprintln!("fit {:?}", t0.elapsed());
    eprintln!("{}", serde_json_like(&fit));
    let mean = direct.mean().unwrap();
    eprintln!("mean removal {mean}");
}

fn serde_json_like(f: &ForcingFit) -> String {
    format!(
        "best fn {:.3} noise {:.3} {:?} scale {:.4} meas {:.3} bins {} var {:.4} dchi0 {:.2}\n{:?}",
        f.best_fn_n,
        f.noise_force_rms_n,
        f.noise_interval_n,
        f.rate_scale,
        f.meas_noise_rms_nm,
        f.bins,
        f.residual_var,
        f.delta_chi2_zero_fn,
        f.forcing
    )
}

#[allow(dead_code)]
fn unused(_: &[CauseEffect], _: RunEffects, _: Term) {
    let _ = (
        attribute_difference,
        counterfactual_effect,
        shared_forcing,
        vibration_effects,
    );
}
