//! What the model cannot know of a height covariate: the height under the tool where the
//! before map has no data (the fill), and the height between and below its pixels (the
//! resolution, [`height_resolution_errors`]).
//!
//! The path overruns the part by about a spot radius, and on a round aperture the tool also
//! crosses the corners the interferometer does not see, so a good share of the dwell that
//! shapes the removal near the rim sits where the height is not measured. The model fills it
//! (`model::local_height_at`: the measured heights smoothed at a length growing with the
//! distance from them, `grid::smooth_masked_reaching`; the border's value off the map); the
//! true height there differs from the fill by an amount the data cannot tell, and a rate that
//! follows the height is then fitted to a covariate that is wrong on those samples. That error
//! is systematic for one run (every hold-out block sees the same fill), so neither the
//! classical nor the block-robust covariance contains it.
//!
//! Its size is drawn, not assumed: a surrogate surface with the measured map's own spectrum
//! (the periodogram of the plane-removed map over its valid pixels, with random complex normal
//! deviates for phases and amplitudes; periodic, so it has a height everywhere under the path)
//! is passed through the model's own fill from its values on the valid pixels only, and the
//! difference from its true local height at every sub-step is one draw of the fill error
//! (near the data it is small, as the surface is continuous; far from it, of the surface's
//! own size). The uncertainties (`uncertainty`) carry each draw through the fit and add the
//! mean square of the parameter shifts. The two terms are drawn from independent surrogates
//! and added draw by draw ([`height_errors`]). Both take the measured spectrum tapered inside
//! the part's edge (`map_spectrum`).
//!
//! The resolution term, measured against surfaces of plane waves with detail to twice the
//! map's Nyquist (tests/height_fill.rs): drawn 37.8, 23.6 and 16.3 nm RMS at the sub-steps
//! against true errors of 36.1, 21.9 and 14.6 nm (2-D spectral exponents 2.9, 3.3, 3.6; 0.625
//! mm pixels, 2 px smoothing). On the validation harness's rate_covariate runs (400^2) the
//! height coefficient's error is the same on noise-free data as with the maps' noise; it moves
//! with the generator's detail below the pixel (1x truth grid against 2x: up to 3 % of the
//! coefficient) and with the covariate's smoothing, neither of which the noise-driven
//! covariance sees.

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

/// The measured map's spectrum for the surrogates: the plane-removed before map over its valid
/// pixels, tapered to zero over 8 pixels inside the part's edge (a raised cosine of the
/// distance to it: the map's border and a round aperture's rim would otherwise leak along the
/// axes, about f^-2, flatter than a steep surface's own fall), transformed; with its mean
/// square over the valid pixels, and the smoothing over `sigma_mm`. `None` with too few valid
/// pixels.
fn map_spectrum(p: &Problem, sigma_mm: f64) -> Option<MapSpectrum> {
    let g = &p.grid;
    let valid = &p.before_valid;
    let nvalid = valid.iter().filter(|v| **v).count();
    if nvalid < 64 {
        return None;
    }
    let flat = plane_removed(g, &p.before, valid);
    let ms: f64 = flat
        .iter()
        .zip(valid)
        .filter(|(_, v)| **v)
        .map(|(h, _)| h * h)
        .sum::<f64>()
        / nvalid as f64;
    let edge = crate::grid::signed_edge_distance(valid, g.dx_mm, g.dy_mm);
    let taper = 8.0 * g.dx_mm.max(g.dy_mm);
    let fft = Fft2::new(g.rows, g.cols);
    let mut real: Vec<f64> = flat
        .iter()
        .zip(valid)
        .zip(&edge)
        .map(|((h, v), e)| {
            let t = (e / taper).clamp(0.0, 1.0);
            if *v {
                h * 0.5 * (1.0 - (std::f64::consts::PI * t).cos())
            } else {
                0.0
            }
        })
        .collect();
    let zero = Complex::new(0.0, 0.0);
    let mut tmp = vec![zero; fft.spectrum_len()];
    let mut spec = vec![zero; fft.spectrum_len()];
    fft.forward(&mut real, &mut tmp, &mut spec);
    let gain = smoothing_gain(p, &fft, sigma_mm);
    Some(MapSpectrum {
        fft,
        spec,
        ms,
        gain,
    })
}

/// What both terms draw from (see [`map_spectrum`]), computed once per calibration.
struct MapSpectrum {
    fft: Fft2,
    /// The tapered map's half spectrum (element k1 * rows + k0).
    spec: Vec<Complex<f64>>,
    /// The map's mean square over its valid pixels (nm^2).
    ms: f64,
    /// The covariate's smoothing on the map grid ([`smoothing_gain`]).
    gain: Vec<f64>,
}

/// The random numbers of draw `d` of a term (`salt` tells the terms apart).
fn draw_rng(salt: u64, d: usize) -> Rng {
    Rng::new(salt ^ (d as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// The Gaussian smoothing's transfer function over `sigma_mm` on the map grid, element by
/// element of `fft`'s transposed half spectrum (element k1 * rows + k0).
fn smoothing_gain(p: &Problem, fft: &Fft2, sigma_mm: f64) -> Vec<f64> {
    let g = &p.grid;
    let (n0, n1) = (g.rows, g.cols);
    let k = 2.0 * std::f64::consts::PI * std::f64::consts::PI * sigma_mm * sigma_mm;
    let mut gain = vec![0.0; fft.spectrum_len()];
    for k1 in 0..n1 / 2 + 1 {
        for k0 in 0..n0 {
            let (a, b) = crate::synth::field::freq(k0, k1, n0, n1, 1.0);
            let (fy, fx) = (a / g.dy_mm, b / g.dx_mm);
            gain[k1 * n0 + k0] = (-k * (fx * fx + fy * fy)).exp();
        }
    }
    gain
}

/// `draws` errors (nm) of the local height at the problem's sub-steps with smoothing
/// `sigma_mm` (see the module note): true local height of a surrogate minus the model's fill
/// of it. Empty when the before map has too few valid pixels for a spectrum, or when the
/// fill is exact (every sub-step's smoothing window within the data).
pub fn height_fill_errors(p: &Problem, sigma_mm: f64, draws: usize) -> Vec<Vec<f64>> {
    match map_spectrum(p, sigma_mm) {
        Some(m) => fill_draws(p, &m, sigma_mm, draws),
        None => Vec::new(),
    }
}

fn fill_draws(p: &Problem, m: &MapSpectrum, sigma_mm: f64, draws: usize) -> Vec<Vec<f64>> {
    let g = &p.grid;
    let valid = &p.before_valid;
    let (fft, spec, ms, gain) = (&m.fft, &m.spec, m.ms, m.gain.as_slice());
    let (n0, n1) = (g.rows, g.cols);
    let xs = &p.samples.x_mm;
    let ys = &p.samples.y_mm;
    let out: Vec<Vec<f64>> = (0..draws)
        .into_par_iter()
        .map(|d| {
            let mut rng = draw_rng(SEED, d);
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
            let smoothed: Vec<Complex<f64>> = dev.iter().zip(gain).map(|(z, a)| z * a).collect();
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

/// `draws` errors (nm) of the height covariate at the problem's sub-steps from the height the
/// map's pixels cannot show: the surface between and below them. A rate that follows the
/// height under the tool's centre follows detail finer than a map pixel, which a point-sampled
/// map folds into its pixels (aliased) and the covariate's smoothing takes out; the data say
/// nothing of it, and a raster's lines sample it along their own rows, so it does not average
/// out under the spot. Drawn as the fill error is: a surrogate on a grid twice as fine, with
/// the measured map's spectrum inside the map's band and, beyond it, the power law fitted to
/// that spectrum between 0.08 and 0.3 cycles per pixel (continued to twice the map's Nyquist,
/// the finest the fine grid holds); the map is its every other sample, the model's covariate
/// that map smoothed over `sigma_mm` (periodically, so the overrun's fill, the other term, is
/// left out), the truth the surrogate's own height at the sub-step. The map's pixels are taken
/// as point samples, also when a recipe says `area` (a camera's pixel means fold less of the
/// fine detail in, so the draws are then somewhat wide). Empty when the spectrum cannot be
/// fitted (too few valid pixels, or no fall with frequency).
pub fn height_resolution_errors(p: &Problem, sigma_mm: f64, draws: usize) -> Vec<Vec<f64>> {
    match map_spectrum(p, sigma_mm) {
        Some(m) => resolution_draws(p, &m, draws),
        None => Vec::new(),
    }
}

fn resolution_draws(p: &Problem, m: &MapSpectrum, draws: usize) -> Vec<Vec<f64>> {
    let g = &p.grid;
    let (n0, n1) = (g.rows, g.cols);
    if draws == 0 || n0 < 8 || n1 < 8 {
        return Vec::new();
    }
    let (fft, spec, ms, gain) = (&m.fft, &m.spec, m.ms, m.gain.as_slice());
    let zero = Complex::new(0.0, 0.0);
    // The power law |F|^2 = exp(a) f^-beta (f cycles per pixel) over the mid band.
    let nh = n1 / 2 + 1;
    let (mut sx, mut sy, mut sxx, mut sxy, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k1 in 0..nh {
        for k0 in 0..n0 {
            let (a, b) = crate::synth::field::freq(k0, k1, n0, n1, 1.0);
            let f = a.hypot(b);
            let pw = spec[k1 * n0 + k0].norm_sqr();
            // Off the axes: a map's edges leak along them (f^-2, flatter than a steep
            // surface's own fall).
            if (0.08..=0.3).contains(&f) && a.abs().min(b.abs()) > 0.03 && pw > 0.0 {
                let (x, y) = (f.ln(), pw.ln());
                sx += x;
                sy += y;
                sxx += x * x;
                sxy += x * y;
                m += 1.0;
            }
        }
    }
    let den = m * sxx - sx * sx;
    if m < 16.0 || den <= 0.0 {
        return Vec::new();
    }
    let slope = (m * sxy - sx * sy) / den;
    let icpt = (sy - slope * sx) / m;
    let beta = -slope;
    if !(beta.is_finite() && beta > 0.0) {
        return Vec::new();
    }
    // The fine grid's half spectrum: the map's own elements inside its band (an element of a
    // grid twice as fine in both directions carries 4 times the sum), the law beyond.
    let (m0, m1) = (2 * n0, 2 * n1);
    let fine = Fft2::new(m0, m1);
    let mh = m1 / 2 + 1;
    let mut amp = vec![zero; fine.spectrum_len()];
    for k1 in 0..mh {
        for k0 in 0..m0 {
            // Frequency in cycles per map pixel.
            let (a, b) = crate::synth::field::freq(k0, k1, m0, m1, 0.5);
            let inside = a.abs() < 0.5 && b.abs() < 0.5;
            amp[k1 * m0 + k0] = if inside {
                let j1 = k1;
                let j0 = (k0 as i64 - if k0 > m0 / 2 { m0 as i64 } else { 0 }).rem_euclid(n0 as i64)
                    as usize;
                4.0 * spec[j1 * n0 + j0]
            } else {
                let f = a.hypot(b);
                Complex::new(4.0 * (0.5 * (icpt - beta * f.ln())).exp(), 0.0)
            };
        }
    }
    let xs = &p.samples.x_mm;
    let ys = &p.samples.y_mm;
    let out: Vec<Vec<f64>> = (0..draws)
        .into_par_iter()
        .map(|d| {
            let mut rng = draw_rng(SEED.rotate_left(17), d);
            let mut dev: Vec<Complex<f64>> = amp
                .iter()
                .map(|z| z * Complex::new(rng.normal(), rng.normal()))
                .collect();
            let mut tmp = vec![zero; fine.spectrum_len()];
            let mut real = vec![0.0; m0 * m1];
            fine.inverse(&mut dev, &mut tmp, &mut real);
            let surf =
                Array2::from_shape_vec((m0, m1), real).unwrap_or_else(|_| Array2::zeros((m0, m1)));
            // The map: every other sample; its smoothing as the covariate's.
            let mut map: Vec<f64> = (0..n0)
                .flat_map(|i| (0..n1).map(move |j| (i, j)))
                .map(|(i, j)| surf[(2 * i, 2 * j)])
                .collect();
            let n = (n0 * n1) as f64;
            let mean = map.iter().sum::<f64>() / n;
            let var = map.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            let scale = if var > 0.0 { (ms / var).sqrt() } else { 0.0 };
            let mut s = vec![zero; fft.spectrum_len()];
            let mut t = vec![zero; fft.spectrum_len()];
            fft.forward(&mut map, &mut t, &mut s);
            for (z, a) in s.iter_mut().zip(gain) {
                *z *= *a;
            }
            let mut sm = vec![0.0; n0 * n1];
            fft.inverse(&mut s, &mut t, &mut sm);
            let sm =
                Array2::from_shape_vec((n0, n1), sm).unwrap_or_else(|_| Array2::zeros((n0, n1)));
            xs.iter()
                .zip(ys)
                .map(|(&x, &y)| {
                    let (u, v) = g.frac_index(x, y);
                    scale
                        * (bilinear_periodic(&surf, 2.0 * u, 2.0 * v)
                            - bilinear_periodic(&sm, u, v))
                })
                .collect()
        })
        .collect();
    out
}

/// The height covariate's unmeasured-height draws: the fill's and the resolution's, drawn
/// independently and added draw by draw (their variances add).
pub fn height_errors(p: &Problem, sigma_mm: f64, draws: usize) -> Vec<Vec<f64>> {
    let Some(m) = map_spectrum(p, sigma_mm) else {
        return Vec::new();
    };
    let fill = fill_draws(p, &m, sigma_mm, draws);
    let res = resolution_draws(p, &m, draws);
    match (fill.is_empty(), res.is_empty()) {
        (true, _) => res,
        (_, true) => fill,
        _ => fill
            .into_iter()
            .zip(res)
            .map(|(a, b)| a.iter().zip(&b).map(|(x, y)| x + y).collect())
            .collect(),
    }
}
