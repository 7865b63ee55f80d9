//! The instantaneous TIF under vibration and its derivative kernels for the small-displacement
//! expansion.
//!
//! Model: at an offset change δ (mm, at the contact) the contact radius is a(h0 + δ) with
//! a(h) = sqrt(2 R h − h²), the footprint keeps its shape scaled by a / a0, and the peak rate
//! scales as (h / h0)^γ (γ = `pressure_exponent`):
//! T(q; δ) = ((h0 + δ) / h0)^γ · T0(q · a0 / a(h0 + δ)).
//! A lateral displacement u along the lateral map axis moves the footprint: T(q − u e_l; δ).
//!
//! Kernels (sampled on the map pitch, centre at the middle pixel, finite differences of the
//! continuous model): K0 = T, K_l = ∂T/∂l, K_ll = ∂²T/∂l², K_h = ∂T/∂δ, K_hh = ∂²T/∂δ²,
//! K_lh = ∂²T/∂l∂δ. Lateral differences use one pixel (the natural scale of a sampled TIF);
//! offset differences use 5 % of h0 on pixel-area means (6 x 6 sub-samples), because a
//! footprint with a hard edge has an offset derivative concentrated on its rim.

use crate::params::{LateralAxis, VibrationParams};
use bonnetlab_process::tif::RateField;
use ndarray::Array2;

/// The offset- and position-dependent removal rate of the tool.
pub struct InstantTif<'a> {
    base: &'a dyn RateField,
    h0_mm: f64,
    radius_mm: f64,
    gamma: f64,
    a0_mm: f64,
}

impl<'a> InstantTif<'a> {
    pub fn new(base: &'a dyn RateField, p: &VibrationParams) -> Self {
        InstantTif {
            base,
            h0_mm: p.offset_mm,
            radius_mm: p.bonnet_radius_mm,
            gamma: p.pressure_exponent,
            a0_mm: p.contact_radius_mm(p.offset_mm),
        }
    }

    /// Footprint scale a(h0 + δ) / a0 and rate factor at offset change δ.
    fn scale(&self, delta_mm: f64) -> (f64, f64) {
        let h = (self.h0_mm + delta_mm).max(1e-9);
        let a = (2.0 * self.radius_mm * h - h * h).max(1e-18).sqrt();
        (a / self.a0_mm, (h / self.h0_mm).powf(self.gamma))
    }

    /// Rate (nm/s) at offset (dx, dy) mm from the nominal tool centre, with offset change δ.
    pub fn rate(&self, dx_mm: f64, dy_mm: f64, delta_mm: f64) -> f64 {
        let (sc, f) = self.scale(delta_mm);
        f * self.base.rate_at_mm(dx_mm / sc, dy_mm / sc)
    }

    /// Half-extent (x, y) in mm for offset changes up to |δ| = `delta_max_mm`.
    pub fn half_extent_mm(&self, delta_max_mm: f64) -> (f64, f64) {
        let (ex, ey) = self.base.half_extent_mm();
        let (sc, _) = self.scale(delta_max_mm.abs());
        (ex * sc, ey * sc)
    }
}

/// The six expansion kernels on a common (2 hy + 1) x (2 hx + 1) grid of pitch (dx, dy).
#[derive(Debug, Clone)]
pub struct Kernels {
    pub k0: Array2<f64>,
    pub kl: Array2<f64>,
    pub kll: Array2<f64>,
    pub kh: Array2<f64>,
    pub khh: Array2<f64>,
    pub klh: Array2<f64>,
    /// Half widths in pixels (rows, cols).
    pub half: (usize, usize),
}

impl Kernels {
    pub fn sample(t: &InstantTif<'_>, dx_mm: f64, dy_mm: f64, lateral: LateralAxis) -> Kernels {
        let eh = OFFSET_STEP * t.h0_mm;
        let (ex, ey) = t.half_extent_mm(eh);
        let hx = (ex / dx_mm).ceil() as usize + 2;
        let hy = (ey / dy_mm).ceil() as usize + 2;
        let shape = (2 * hy + 1, 2 * hx + 1);
        let (el, (lx, ly)) = match lateral {
            LateralAxis::X => (dx_mm, (1.0, 0.0)),
            LateralAxis::Y => (dy_mm, (0.0, 1.0)),
        };
        let mut k = Kernels {
            k0: Array2::zeros(shape),
            kl: Array2::zeros(shape),
            kll: Array2::zeros(shape),
            kh: Array2::zeros(shape),
            khh: Array2::zeros(shape),
            klh: Array2::zeros(shape),
            half: (hy, hx),
        };
        let n = SUPERSAMPLE;
        for i in 0..shape.0 {
            let y = (i as f64 - hy as f64) * dy_mm;
            for j in 0..shape.1 {
                let x = (j as f64 - hx as f64) * dx_mm;
                let at = |s: f64, d: f64| t.rate(x + s * lx * el, y + s * ly * el, d);
                // Pixel-area mean: the footprint edge moves continuously with δ, so the offset
                // derivatives of a footprint with a hard edge stay bounded.
                let avg = |s: f64, d: f64| {
                    let mut acc = 0.0;
                    for a in 0..n {
                        let oy = ((a as f64 + 0.5) / n as f64 - 0.5) * dy_mm;
                        for b in 0..n {
                            let ox = ((b as f64 + 0.5) / n as f64 - 0.5) * dx_mm;
                            acc += t.rate(x + ox + s * lx * el, y + oy + s * ly * el, d);
                        }
                    }
                    acc / (n * n) as f64
                };
                let c = at(0.0, 0.0);
                let (p, m) = (at(1.0, 0.0), at(-1.0, 0.0));
                k.k0[(i, j)] = c;
                k.kl[(i, j)] = (p - m) / (2.0 * el);
                k.kll[(i, j)] = (p - 2.0 * c + m) / (el * el);
                let (ac, hp, hm) = (avg(0.0, 0.0), avg(0.0, eh), avg(0.0, -eh));
                k.kh[(i, j)] = (hp - hm) / (2.0 * eh);
                k.khh[(i, j)] = (hp - 2.0 * ac + hm) / (eh * eh);
                let dh = |s: f64| (avg(s, eh) - avg(s, -eh)) / (2.0 * eh);
                k.klh[(i, j)] = (dh(1.0) - dh(-1.0)) / (2.0 * el);
            }
        }
        k
    }
}

/// Offset step of the finite differences, as a fraction of h0 (the second-difference error is
/// O(step²) relative: 0.25 % at 5 %).
const OFFSET_STEP: f64 = 0.05;
/// Sub-samples per pixel side for the offset kernels.
const SUPERSAMPLE: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_process::tif::GaussianTif;

    #[test]
    fn offset_scaling_changes_volume_as_h_to_gamma_times_area() {
        let g = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
        let p = VibrationParams::default();
        let t = InstantTif::new(&g, &p);
        let vol = |d: f64| {
            let mut s = 0.0;
            for i in -200..=200 {
                for j in -200..=200 {
                    s += t.rate(i as f64 * 0.025, j as f64 * 0.025, d) * 0.025 * 0.025;
                }
            }
            s
        };
        let (v0, v1) = (vol(0.0), vol(0.03));
        let h0 = p.offset_mm;
        let a2 = |h: f64| 2.0 * p.bonnet_radius_mm * h - h * h;
        let expected = ((h0 + 0.03) / h0).powf(0.5) * a2(h0 + 0.03) / a2(h0);
        assert!(
            (v1 / v0 - expected).abs() < 1e-4,
            "{} vs {expected}",
            v1 / v0
        );
    }

    #[test]
    fn kernels_match_analytic_derivatives_of_a_gaussian() {
        // Pure shift derivatives of a Gaussian: ∂x T = −x/σ² T, ∂²x T = (x²/σ⁴ − 1/σ²) T.
        let sigma = 1.0;
        let g = GaussianTif::new(sigma, 12.0, 5.0).unwrap();
        let p = VibrationParams::default();
        let t = InstantTif::new(&g, &p);
        let dx = 0.05;
        let k = Kernels::sample(&t, dx, dx, LateralAxis::X);
        let (hy, hx) = k.half;
        for &(i, j) in &[(0isize, 10isize), (5, -20), (-7, 3)] {
            let (x, y) = (j as f64 * dx, i as f64 * dx);
            let tv = 5.0 * (-(x * x + y * y) / (2.0 * sigma * sigma)).exp();
            let idx = ((hy as isize + i) as usize, (hx as isize + j) as usize);
            assert!(
                (k.kl[idx] - (-x * tv)).abs() < 2e-3 * 5.0,
                "{} vs {}",
                k.kl[idx],
                -x * tv
            );
            assert!((k.kll[idx] - (x * x - 1.0) * tv).abs() < 5e-3 * 5.0);
            // Offset derivative from the chain rule: T(q; δ) = f(δ) T0(q / s(δ)).
            let h0 = p.offset_mm;
            let r = p.bonnet_radius_mm;
            let ds = (r - h0) / (2.0 * r * h0 - h0 * h0); // d ln a / dh
            let df = 0.5 / h0; // d ln f / dh
            let dlnt = df + (x * x + y * y) / (sigma * sigma) * ds;
            assert!(
                (k.kh[idx] - dlnt * tv).abs() < 1e-2 * (dlnt * tv).abs().max(1e-2),
                "{} vs {}",
                k.kh[idx],
                dlnt * tv
            );
        }
    }
}
