//! Synthetic measured runs for checking the inference against independent truth (tests,
//! samples): a power-law textured surface down to the pixel scale and white measurement noise,
//! both seeded (deterministic). The removal itself comes from the caller (for truth, the direct
//! time-domain deposition `coupling::direct_removal`).

use bonnetlab_surface::rng::Rng;
use ndarray::Array2;
use std::f64::consts::PI;

/// Power-law texture (1-D PSD slope about −2) on a `rows` x `cols` grid of pixel `pixel_mm`,
/// from 400 random-phase plane waves with frequencies log-uniform between one cycle over the
/// larger side and the Nyquist frequency; a mode of frequency f has amplitude
/// `8 / max(f L, 1)` nm (L = the larger side in mm). Heights in nm.
pub fn power_law_texture(rows: usize, cols: usize, pixel_mm: f64, seed: u64) -> Array2<f64> {
    let mut r = Rng::new(seed);
    let n = rows.max(cols) as f64;
    let l = n * pixel_mm;
    let modes: Vec<(f64, f64, f64, f64)> = (0..400)
        .map(|_| {
            let f = (1.0 / l) * (0.5 * n).powf(r.uniform());
            let th = 2.0 * PI * r.uniform();
            (
                f * th.cos(),
                f * th.sin(),
                8.0 / (f * l).max(1.0),
                2.0 * PI * r.uniform(),
            )
        })
        .collect();
    Array2::from_shape_fn((rows, cols), |(i, j)| {
        let (x, y) = (j as f64 * pixel_mm, i as f64 * pixel_mm);
        modes
            .iter()
            .map(|&(fx, fy, a, ph)| a * (2.0 * PI * (fx * x + fy * y) + ph).cos())
            .sum::<f64>()
    })
}

/// White Gaussian noise of RMS `rms_nm` (nm), seeded.
pub fn white_noise(rows: usize, cols: usize, rms_nm: f64, seed: u64) -> Array2<f64> {
    let mut r = Rng::new(seed);
    Array2::from_shape_fn((rows, cols), |_| rms_nm * r.normal())
}

/// Before and after maps (nm) of a measured run: the same textured part (`texture_seed`),
/// measured before and after removing `removal_nm`, each measurement with its own white noise
/// of `noise_nm` RMS (seeds `noise_seed` and `noise_seed + 1`).
pub fn measured_pair(
    removal_nm: &Array2<f64>,
    pixel_mm: f64,
    texture_seed: u64,
    noise_seed: u64,
    noise_nm: f64,
) -> (Array2<f64>, Array2<f64>) {
    let (rows, cols) = removal_nm.dim();
    let t = power_law_texture(rows, cols, pixel_mm, texture_seed);
    let before = &t + &white_noise(rows, cols, noise_nm, noise_seed);
    let after = &t - removal_nm + white_noise(rows, cols, noise_nm, noise_seed + 1);
    (before, after)
}
