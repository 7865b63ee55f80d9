//! What the model cannot know of a height covariate: the height under the tool where the
//! before map has no data.
//!
//! The path overruns the part by about a spot radius, and on a round aperture the tool also
//! crosses the corners the interferometer does not see, so a good share of the dwell that
//! shapes the removal near the rim sits where the height is not measured. The model fills it
//! (`model::local_height_at`: the masked smoothing's neighbours near the data, the plane
//! beyond, the border's value off the map); the true height there differs from the fill by an
//! amount the data cannot tell, and a rate that follows the height is then fitted to a
//! covariate that is wrong on those samples. That error is systematic for one run (every
//! hold-out block sees the same fill), so neither the classical nor the block-robust covariance
//! contains it.
//!
//! Its size is drawn, not assumed: a surrogate surface with the measured map's own spectrum
//! (the periodogram of the plane-removed map over its valid pixels, with random complex normal
//! deviates for phases and amplitudes; periodic, so it has a height everywhere under the path)
//! is passed through the model's own fill from its values on the valid pixels only, and the
//! difference from its true local height at every sub-step is one draw of the fill error
//! (near the data it is small, as the surface is continuous; far from it, of the surface's
//! own size). The uncertainties (`uncertainty`) carry each draw through the fit and add the
//! mean square of the parameter shifts.

use bonnetlab_process::fft::Fft2;
use bonnetlab_process::interp::bilinear_periodic;
use bonnetlab_surface::rng::Rng;
use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex;

use crate::model::{local_height_at, plane_fit, plane_removed, Problem};

/// Draws of the fill error per covariate (the systematic variance is their mean square: with
/// 16 draws its own sampling error is about 35 % of the variance, 18 % of the sigma).
pub const DRAWS: usize = 16;

/// Seed of the surrogate surfaces (fixed: the same run gives the same intervals).
const SEED: u64 = 0x6f1e_a4c3_2b97_d805;

/// `draws` errors (nm) of the local height at the problem's sub-steps with smoothing
/// `sigma_mm` (see the module note): true local height of a surrogate minus the model's fill
/// of it. Empty when the before map has too few valid pixels for a spectrum, or when the
/// fill is exact (every sub-step's smoothing window within the data).
pub fn height_fill_errors(p: &Problem, sigma_mm: f64, draws: usize) -> Vec<Vec<f64>> {
    let g = &p.grid;
    let valid = &p.before_valid;
    let nvalid = valid.iter().filter(|v| **v).count();
    if nvalid < 64 || draws == 0 {
        return Vec::new();
    }
    let flat = plane_removed(g, &p.before, valid);
    let (n0, n1) = (g.rows, g.cols);
    let ms: f64 = flat
        .iter()
        .zip(valid)
        .filter(|(_, v)| **v)
        .map(|(h, _)| h * h)
        .sum::<f64>()
        / nvalid as f64;
    let fft = Fft2::new(n0, n1);
    let mut real: Vec<f64> = flat
        .iter()
        .zip(valid)
        .map(|(h, v)| if *v { *h } else { 0.0 })
        .collect();
    let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    let mut spec = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    fft.forward(&mut real, &mut tmp, &mut spec);
    // The smoothing's transfer function, element by element of the transposed half spectrum
    // (element k1 * n0 + k0).
    let k = 2.0 * std::f64::consts::PI * std::f64::consts::PI * sigma_mm * sigma_mm;
    let nh = n1 / 2 + 1;
    let mut gain = vec![0.0; fft.spectrum_len()];
    for k1 in 0..nh {
        for k0 in 0..n0 {
            let (a, b) = crate::synth::field::freq(k0, k1, n0, n1, 1.0);
            let (fy, fx) = (a / g.dy_mm, b / g.dx_mm);
            gain[k1 * n0 + k0] = (-k * (fx * fx + fy * fy)).exp();
        }
    }
    let xs = &p.samples.x_mm;
    let ys = &p.samples.y_mm;
    let out: Vec<Vec<f64>> = (0..draws)
        .into_par_iter()
        .map(|d| {
            let mut rng = Rng::new(SEED ^ (d as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let dev: Vec<Complex<f64>> = spec
                .iter()
                .map(|z| z * Complex::new(rng.normal(), rng.normal()))
                .collect();
            let inverse = |s: &[Complex<f64>]| {
                let mut s = s.to_vec();
                let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
                let mut real = vec![0.0; n0 * n1];
                fft.inverse(&mut s, &mut tmp, &mut real);
                Array2::from_shape_vec((n0, n1), real).unwrap_or_else(|_| Array2::zeros((n0, n1)))
            };
            let mut surf = inverse(&dev);
            let smoothed: Vec<Complex<f64>> = dev.iter().zip(&gain).map(|(z, a)| z * a).collect();
            let mut surf_sm = inverse(&smoothed);
            // The surrogate at the measured map's RMS (its mean taken out of both).
            let n = (n0 * n1) as f64;
            let mean = surf.sum() / n;
            let var = surf.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            let f = if var > 0.0 { (ms / var).sqrt() } else { 0.0 };
            surf.mapv_inplace(|v| (v - mean) * f);
            surf_sm.mapv_inplace(|v| (v - mean) * f);
            // The model's fill of it from the valid pixels, and the truth at the sub-steps
            // (less the same plane the fill removes).
            let fill = local_height_at(g, &surf, valid, xs, ys, sigma_mm);
            let [pz, px, py] = plane_fit(g, &surf, valid);
            let (cx, cy) = g.centre_mm();
            xs.iter()
                .zip(ys)
                .zip(&fill)
                .map(|((&x, &y), q)| {
                    let (u, v) = g.frac_index(x, y);
                    let truth =
                        bilinear_periodic(&surf_sm, u, v) - pz - px * (x - cx) - py * (y - cy);
                    truth - q
                })
                .collect()
        })
        .collect();
    if out.iter().flatten().all(|v| v.abs() < 1e-12) {
        return Vec::new();
    }
    out
}
