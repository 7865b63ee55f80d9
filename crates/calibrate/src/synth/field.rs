//! The true initial surface of a synthetic run: a height map on a fine "truth" grid (finer than
//! the measured maps and wider than the part, so misregistered and rotated maps can be sampled
//! from it), evaluated anywhere by Catmull-Rom interpolation (`bonnetlab_process::interp`).
//!
//! Sources:
//! - [`power_law`]: a Gaussian random field whose ONE-SIDED 1-D profile PSD falls as
//!   `f^-exponent` (2-D isotropic PSD as `f^-(exponent + 1)`), flattened below one cycle per
//!   domain, with content up to the truth grid's Nyquist (finer than the map pixel);
//! - [`band_field`]: smooth content in a frequency band (the figure / MSF of the legacy runs);
//! - [`from_real_map`]: a real measured map (any format `bonnetlab_io` reads) with its invalid
//!   pixels filled, piston and tilt removed, stretched over the domain.
//!
//! All random draws come from the project's seeded [`Rng`]; transforms use the process crate's
//! FFT ([`Fft2`]). Fields are periodic over the FFT domain.

use std::path::Path;

use bonnetlab_process::fft::Fft2;
use bonnetlab_process::interp::catmull_rom;
use bonnetlab_process::Grid;
use bonnetlab_surface::fill::fill_invalid;
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::{remove_terms, Surface, Term};
use ndarray::Array2;
use rustfft::num_complex::Complex;

use crate::error::CalibrateError;

/// A sampled true surface (nm) on a fine grid.
#[derive(Debug, Clone)]
pub struct TruthSurface {
    pub heights_nm: Array2<f64>,
    pub grid: Grid,
}

impl TruthSurface {
    /// Height (nm) at (x, y) mm.
    pub fn value(&self, x_mm: f64, y_mm: f64) -> f64 {
        let (u, v) = self.grid.frac_index(x_mm, y_mm);
        catmull_rom(&self.heights_nm, u, v)
    }

    /// Gradient (nm/mm) by central differences over one truth pixel.
    pub fn gradient(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        let (hx, hy) = (self.grid.dx_mm, self.grid.dy_mm);
        (
            (self.value(x_mm + hx, y_mm) - self.value(x_mm - hx, y_mm)) / (2.0 * hx),
            (self.value(x_mm, y_mm + hy) - self.value(x_mm, y_mm - hy)) / (2.0 * hy),
        )
    }
}

/// Spatial frequencies (cycles/mm) of spectrum element (k0 row index, k1 column index) of an
/// `n0 x n1` transform ([`Fft2`]'s half spectrum) with pixel `d` mm.
pub(crate) fn freq(k0: usize, k1: usize, n0: usize, n1: usize, d: f64) -> (f64, f64) {
    let s0 = if k0 <= n0 / 2 {
        k0 as f64
    } else {
        k0 as f64 - n0 as f64
    };
    (s0 / (n0 as f64 * d), k1 as f64 / (n1 as f64 * d))
}

/// A real Gaussian random field on `grid` whose spectral amplitude at |f| (cycles/mm) is
/// `amp(|f|)` times a complex normal deviate; zero mean. Not normalised.
fn random_field(rng: &mut Rng, grid: &Grid, amp: impl Fn(f64) -> f64) -> Array2<f64> {
    let (n0, n1) = (grid.rows, grid.cols);
    let fft = Fft2::new(n0, n1);
    let nh = n1 / 2 + 1;
    let mut spec = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    // Transposed half spectrum: element k1 * n0 + k0.
    for k1 in 0..nh {
        for k0 in 0..n0 {
            let (fy, fx) = freq(k0, k1, n0, n1, grid.dx_mm);
            let f = fx.hypot(fy);
            let a = if f > 0.0 { amp(f) } else { 0.0 };
            let (re, im) = (rng.normal(), rng.normal());
            spec[k1 * n0 + k0] = Complex::new(a * re, a * im);
        }
    }
    let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    let mut real = vec![0.0; n0 * n1];
    fft.inverse(&mut spec, &mut tmp, &mut real);
    let mut a = Array2::from_shape_vec((n0, n1), real).unwrap_or_else(|_| Array2::zeros((n0, n1)));
    let m = a.mean().unwrap_or(0.0);
    a.mapv_inplace(|v| v - m);
    a
}

/// RMS about the mean of `a` over the pixels where `inside(i, j)`.
fn rms_where(a: &Array2<f64>, inside: impl Fn(usize, usize) -> bool) -> f64 {
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
    for ((i, j), &v) in a.indexed_iter() {
        if inside(i, j) {
            s += v;
            s2 += v * v;
            n += 1.0;
        }
    }
    if n < 2.0 {
        return 0.0;
    }
    let m = s / n;
    (s2 / n - m * m).max(0.0).sqrt()
}

/// Scales `a` to RMS `rms_nm` (about its mean) over the whole grid.
pub(crate) fn scale_to(a: &mut Array2<f64>, rms_nm: f64) {
    let r = rms_where(a, |_, _| true);
    if r > 0.0 {
        a.mapv_inplace(|v| v * rms_nm / r);
    }
}

/// Power-law random field: ONE-SIDED 1-D profile PSD proportional to `f^-exponent` above
/// `1 / domain` (2-D PSD `(f^2 + f_c^2)^(-(exponent + 1) / 2)`, f_c = 1 / domain size), RMS
/// `rms_nm` over the grid, content up to the grid's Nyquist frequency.
pub fn power_law(rng: &mut Rng, grid: &Grid, exponent: f64, rms_nm: f64) -> Array2<f64> {
    let size = (grid.rows.max(grid.cols) as f64) * grid.dx_mm;
    let fc = 1.0 / size;
    let mut a = random_field(rng, grid, |f| {
        (f * f + fc * fc).powf(-(exponent + 1.0) / 4.0)
    });
    scale_to(&mut a, rms_nm);
    a
}

/// Smooth content in the band `f1..f2` cycles/mm (amplitude falling as 1/|f|), RMS `rms_nm`.
pub fn band_field(rng: &mut Rng, grid: &Grid, f1: f64, f2: f64, rms_nm: f64) -> Array2<f64> {
    let mut a = random_field(
        rng,
        grid,
        |f| {
            if f >= f1 && f <= f2 {
                1.0 / f
            } else {
                0.0
            }
        },
    );
    scale_to(&mut a, rms_nm);
    a
}

/// Gaussian low-pass of `a` (sigma `sigma_mm`), periodic over the grid, by FFT.
pub fn smooth(a: &Array2<f64>, grid: &Grid, sigma_mm: f64) -> Array2<f64> {
    let (n0, n1) = a.dim();
    let fft = Fft2::new(n0, n1);
    let nh = n1 / 2 + 1;
    let mut real: Vec<f64> = a.iter().copied().collect();
    let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    let mut spec = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
    fft.forward(&mut real, &mut tmp, &mut spec);
    let k = 2.0 * std::f64::consts::PI * std::f64::consts::PI * sigma_mm * sigma_mm;
    for k1 in 0..nh {
        for k0 in 0..n0 {
            let (fy, fx) = freq(k0, k1, n0, n1, grid.dx_mm);
            spec[k1 * n0 + k0] *= (-k * (fx * fx + fy * fy)).exp();
        }
    }
    fft.inverse(&mut spec, &mut tmp, &mut real);
    Array2::from_shape_vec((n0, n1), real).unwrap_or_else(|_| Array2::zeros((n0, n1)))
}

/// A smooth random map of unit RMS (Gaussian correlation of length `correlation_mm`).
pub fn smooth_random(rng: &mut Rng, grid: &Grid, correlation_mm: f64) -> Array2<f64> {
    let k = std::f64::consts::PI * std::f64::consts::PI * correlation_mm * correlation_mm;
    let mut a = random_field(rng, grid, |f| (-k * f * f).exp());
    scale_to(&mut a, 1.0);
    a
}

/// A real map as an initial surface: read with `bonnetlab_io`, invalid pixels filled, piston
/// and tilt removed, its largest centred square stretched over `grid` (Catmull-Rom), scaled to
/// RMS `rms_nm`.
pub fn from_real_map(path: &Path, grid: &Grid, rms_nm: f64) -> Result<Array2<f64>, CalibrateError> {
    let s = bonnetlab_io::read_surface(path)
        .map_err(|e| CalibrateError::InvalidInput(format!("{}: {e}", path.display())))?;
    // A Surface's heights are finite everywhere and its mask says which are data.
    let valid = s.valid();
    if s.valid_count() == 0 {
        return Err(CalibrateError::InvalidInput(format!(
            "{}: no valid pixel",
            path.display()
        )));
    }
    // Piston and tilt by least squares over the (filled) map.
    let filled = Surface::new(fill_invalid(s.heights_nm(), valid), s.dx_mm, s.dy_mm)?;
    let (flat, _) = remove_terms(&filled, &[Term::Piston, Term::Tilt])?;
    let h = flat.heights_nm();
    let (r, c) = h.dim();
    let (cy, cx) = ((r as f64 - 1.0) / 2.0, (c as f64 - 1.0) / 2.0);
    let side = r.min(c) as f64 - 1.0;
    let (i0, j0) = (cy - side / 2.0, cx - side / 2.0);
    let mut out = Array2::from_shape_fn((grid.rows, grid.cols), |(i, j)| {
        let u = i0 + side * i as f64 / (grid.rows.max(2) - 1) as f64;
        let v = j0 + side * j as f64 / (grid.cols.max(2) - 1) as f64;
        catmull_rom(h, u, v)
    });
    let mean = out.mean().unwrap_or(0.0);
    out.mapv_inplace(|v| v - mean);
    scale_to(&mut out, rms_nm);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_keeps_the_mean_and_lowers_the_rms() {
        let g = Grid::new(64, 64, 0.5, 0.5, 0.0, 0.0).unwrap();
        let mut rng = Rng::new(4);
        let a = power_law(&mut rng, &g, 2.0, 10.0);
        let s = smooth(&a, &g, 2.0);
        assert!(s.mean().unwrap().abs() < 1e-9);
        assert!(rms_where(&s, |_, _| true) < 0.9 * rms_where(&a, |_, _| true));
        assert!((rms_where(&a, |_, _| true) - 10.0).abs() < 1e-9);
    }
}
