//! Transitional: the exact deposition of a perturbed tool as `src/pipeline/recipe_samples.rs`
//! (the bundled recipe runs' generator) calls it. These items ([`Axis`], [`OffsetTif`],
//! [`PerturbedSample`], [`deposit_perturbed`]) remain only for recipe_samples until the lead
//! ports it to [`crate::modulated::deposit_exact_modulated`] with
//! [`crate::tif::derived::OffsetLaw`] (the vibration coupling's direct mode already runs
//! there); nothing else may use them. The expansion that used to live here (derivative kernels,
//! weighted dwell maps) is gone: the fast coupling runs the one fast removal on the TIF's
//! derived fields ([`crate::tif::derived`]).
//!
//! - [`OffsetTif`]: the instantaneous TIF at an offset change δ (mm, at the contact). The
//!   contact radius is a(h) = sqrt(2 R h − h²); the footprint keeps its shape scaled by
//!   a(h0 + δ) / a0 and the peak rate scales as ((h0 + δ) / h0)^γ:
//!   T(q; δ) = ((h0 + δ) / h0)^γ · T0(q · a0 / a(h0 + δ)), T0 any [`RateField`]. A lateral
//!   displacement u along a map axis e moves it: T(q − u e; δ).
//! - [`deposit_perturbed`]: time-domain deposition of T(q − u e; δ) sample by sample at every
//!   pixel of the footprint.
//!
//! Units: mm, s, nm/s; removal in nm.

use ndarray::Array2;
use rayon::prelude::*;

use crate::grid::Grid;
use crate::removal::deposit_one;
use crate::tif::RateField;

/// A map axis (the direction of a lateral displacement).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
}

impl Axis {
    /// Unit vector (x, y).
    pub fn unit(self) -> (f64, f64) {
        match self {
            Axis::X => (1.0, 0.0),
            Axis::Y => (0.0, 1.0),
        }
    }
}

/// The offset- and position-dependent removal rate of a bonnet whose offset changes by δ.
#[derive(Clone, Copy)]
pub struct OffsetTif<'a> {
    base: &'a dyn RateField,
    h0_mm: f64,
    radius_mm: f64,
    gamma: f64,
    a0_mm: f64,
}

impl<'a> OffsetTif<'a> {
    /// `base` is the TIF at the nominal offset `h0_mm` of a bonnet of radius `radius_mm`;
    /// `pressure_exponent` is γ.
    pub fn new(
        base: &'a dyn RateField,
        h0_mm: f64,
        radius_mm: f64,
        pressure_exponent: f64,
    ) -> OffsetTif<'a> {
        let a0 = (2.0 * radius_mm * h0_mm - h0_mm * h0_mm).max(1e-18).sqrt();
        OffsetTif {
            base,
            h0_mm,
            radius_mm,
            gamma: pressure_exponent,
            a0_mm: a0,
        }
    }

    /// Nominal offset h0, mm.
    pub fn h0_mm(&self) -> f64 {
        self.h0_mm
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

    /// The rate (nm/s) at offset change δ as a function of (dx, dy) mm (the scale factors
    /// computed once).
    pub fn at_offset(&self, delta_mm: f64) -> impl Fn(f64, f64) -> f64 + '_ {
        let (sc, f) = self.scale(delta_mm);
        let inv = 1.0 / sc;
        move |dx, dy| f * self.base.rate_at_mm(dx * inv, dy * inv)
    }

    /// Half-extent (x, y) in mm for offset changes up to |δ| = `delta_max_mm`.
    pub fn half_extent_mm(&self, delta_max_mm: f64) -> (f64, f64) {
        let (ex, ey) = self.base.half_extent_mm();
        let (sc, _) = self.scale(delta_max_mm.abs());
        (ex * sc, ey * sc)
    }
}

/// One sample of a perturbed tool: centre (x, y) mm on the commanded path, dwell dt s, lateral
/// displacement u mm along the lateral axis, offset change δ mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerturbedSample {
    pub x_mm: f64,
    pub y_mm: f64,
    pub dt_s: f64,
    pub u_mm: f64,
    pub delta_mm: f64,
}

/// Exact time-domain deposition of the perturbed TIF T(q − u e; δ): every sample adds
/// dt · T at every pixel of its footprint (no expansion, no splat), accumulated into `acc` (nm,
/// on `grid`), in parallel. `delta_max_mm` bounds |δ| for the footprint extent.
pub fn deposit_perturbed(
    acc: &mut Array2<f64>,
    grid: &Grid,
    field: &OffsetTif<'_>,
    lateral: Axis,
    delta_max_mm: f64,
    samples: &[PerturbedSample],
) {
    let (ex, ey) = field.half_extent_mm(delta_max_mm);
    let (lx, ly) = lateral.unit();
    let g = *grid;
    let chunk = (samples.len() / (4 * rayon::current_num_threads()).max(1)).max(256);
    let zero = || Array2::<f64>::zeros((g.rows, g.cols));
    let part = samples
        .par_chunks(chunk)
        .map(|c| {
            let mut a = zero();
            for s in c {
                let (cx, cy) = (s.x_mm + s.u_mm * lx, s.y_mm + s.u_mm * ly);
                deposit_one(
                    &mut a,
                    &g,
                    field.at_offset(s.delta_mm),
                    cx,
                    cy,
                    s.dt_s,
                    ex,
                    ey,
                );
            }
            a
        })
        .reduce(zero, |a, b| a + b);
    *acc += &part;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::GaussianTif;

    #[test]
    fn offset_scaling_changes_volume_as_h_to_gamma_times_area() {
        let g = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
        let (h0, r) = (0.6, 20.0);
        let t = OffsetTif::new(&g, h0, r, 0.5);
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
        let a2 = |h: f64| 2.0 * r * h - h * h;
        let expected = ((h0 + 0.03) / h0).powf(0.5) * a2(h0 + 0.03) / a2(h0);
        assert!(
            (v1 / v0 - expected).abs() < 1e-4,
            "{} vs {expected}",
            v1 / v0
        );
    }
}
