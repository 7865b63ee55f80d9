//! Sampled TIF kernels for the fast removal, one per kind of tool motion.
//!
//! The fast removal splats the path's dwell onto the grid and convolves it with a sampled
//! kernel K; for a tool moving along X this amounts to integrating the interpolant of K along
//! the path, so the removal of a line is the sum `dx * sum_j K(j dx, dy)` where the exact
//! deposition integrates `T(x, dy) dx`. With point samples that sum is a rectangle rule, and
//! for a footprint with a steep edge (a Hertz bonnet's sqrt(1 - r^2/a^2) pressure) its error
//! is of order (dx / a)^1.5: about 1 % of the line integral at 0.5 mm pixels, which shows as
//! several % of a removal map's RMS. Averaging the TIF over one pixel along the motion makes
//! that line integral exact, while across the motion (where the path is a point) the kernel
//! keeps point values, so raster ripple is not blurred.
//!
//! Hence three kernels: point samples (a resting tool: exact deposition evaluates the TIF at
//! pixel centres), a box average over one pixel along X (motion along X) and along Y (motion
//! along Y). Oblique motion is split between the X and Y kernels by cos^2 / sin^2 of its
//! direction. The box-averaged kernels are one pixel wider along their axis.

use ndarray::Array2;

use super::{RateField, Tif};
use crate::error::ProcessError;

/// Which kernel a piece of dwell uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Motion {
    /// The tool rests: point samples.
    Resting,
    /// Moving along X (columns): averaged over one pixel along X.
    AlongX,
    /// Moving along Y (rows): averaged over one pixel along Y.
    AlongY,
}

/// Sub-samples per pixel of the box averages of a continuous field (midpoint rule; a sqrt edge
/// inside the pixel leaves an error of order 32^-1.5 of that pixel's share).
const SUB: usize = 32;

/// The three kernels of a continuous rate field at pixel (dx, dy), in [`Motion`] order.
pub fn kernels_from_field(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
) -> Result<[Tif; 3], ProcessError> {
    let point = Tif::sample(field, dx_mm, dy_mm)?;
    let (h0, h1) = point.half_widths();
    let along = |ax: bool| {
        // One more pixel along the axis: the box reaches half a pixel beyond the footprint.
        let (g0, g1) = if ax { (h0, h1 + 1) } else { (h0 + 1, h1) };
        let rate = Array2::from_shape_fn((2 * g0 + 1, 2 * g1 + 1), |(i, j)| {
            let (cx, cy) = (
                (j as f64 - g1 as f64) * dx_mm,
                (i as f64 - g0 as f64) * dy_mm,
            );
            let mut s = 0.0;
            for k in 0..SUB {
                let f = (k as f64 + 0.5) / SUB as f64 - 0.5;
                s += if ax {
                    field.rate_at_mm(cx + f * dx_mm, cy)
                } else {
                    field.rate_at_mm(cx, cy + f * dy_mm)
                };
            }
            s / SUB as f64
        });
        Tif::new(rate, dx_mm, dy_mm)
    };
    Ok([point.clone(), along(true)?, along(false)?])
}

/// The three kernels of a sampled TIF (already at the grid pitch), taking its bilinear
/// interpolant, zero-extended beyond the window, as the continuous footprint (what exact
/// deposition of a sampled TIF uses; measured spots end in a ring of zeros): the one-pixel box
/// average of a linear interpolant is the stencil (1/8, 3/4, 1/8).
pub fn kernels_from_sampled(t: &Tif) -> [Tif; 3] {
    let a = &t.rate_nm_per_s;
    let (r, c) = a.dim();
    let at = |i: isize, j: isize| {
        if i >= 0 && j >= 0 && (i as usize) < r && (j as usize) < c {
            a[(i as usize, j as usize)]
        } else {
            0.0
        }
    };
    let stencil = |ax: bool| {
        let (g0, g1) = if ax { (r, c + 2) } else { (r + 2, c) };
        let rate = Array2::from_shape_fn((g0, g1), |(i, j)| {
            let (i, j) = if ax {
                (i as isize, j as isize - 1)
            } else {
                (i as isize - 1, j as isize)
            };
            let (p, n) = if ax {
                (at(i, j - 1), at(i, j + 1))
            } else {
                (at(i - 1, j), at(i + 1, j))
            };
            0.75 * at(i, j) + 0.125 * (p + n)
        });
        Tif {
            rate_nm_per_s: rate,
            dx_mm: t.dx_mm,
            dy_mm: t.dy_mm,
        }
    };
    [t.clone(), stencil(true), stencil(false)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::bonnet::{BonnetTif, BonnetTifParams};

    /// Line integral of a field along X at offset y by a fine midpoint rule (the reference).
    fn line_integral(f: &dyn RateField, y: f64) -> f64 {
        let (ex, _) = f.half_extent_mm();
        let n = 200_000;
        let h = 2.0 * ex / n as f64;
        (0..n)
            .map(|k| f.rate_at_mm(-ex + (k as f64 + 0.5) * h, y))
            .sum::<f64>()
            * h
    }

    #[test]
    fn along_x_kernel_carries_the_line_integrals_of_a_hertz_bonnet() {
        let m = BonnetTif::new(&BonnetTifParams::paper(10.0)).unwrap();
        let dx = 0.5;
        let [point, ax, ay] = kernels_from_field(&m, dx, dx).unwrap();
        let (h0, _) = ax.half_widths();
        let (mut worst_point, mut worst_box) = (0.0f64, 0.0f64);
        for i in 0..=h0 {
            let y = i as f64 * dx;
            let exact = line_integral(&m, y);
            if exact < 0.05 * line_integral(&m, 0.0) {
                continue;
            }
            let row = |t: &Tif| {
                let (c0, _) = t.half_widths();
                t.rate_nm_per_s.row(c0 + i).sum() * dx
            };
            worst_point = worst_point.max((row(&point) / exact - 1.0).abs());
            worst_box = worst_box.max((row(&ax) / exact - 1.0).abs());
        }
        // Point samples miss the line integrals by up to ~1 %; the box average is exact up to
        // its own 32-point sub-sampling.
        assert!(worst_point > 2e-3, "{worst_point}");
        assert!(worst_box < 2e-4, "{worst_box}");
        // The Y kernel is the X kernel transposed for this symmetric footprint.
        let d = (&ay.rate_nm_per_s - &ax.rate_nm_per_s.t())
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(d < 1e-9 * point.peak_rate_nm_per_s());
    }

    #[test]
    fn sampled_stencil_is_the_box_average_of_the_bilinear_interpolant() {
        // A sampled TIF with a zero outer ring (like a measured spot after background removal),
        // so the interpolant inside the window is the zero-extended one.
        let g = crate::tif::GaussianTif::new(1.0, 5.0, 2.0).unwrap();
        let s = Tif::sample(&g, 0.5, 0.5).unwrap().rate_nm_per_s;
        let (r, c) = s.dim();
        let mut padded = Array2::zeros((r + 2, c + 2));
        padded.slice_mut(ndarray::s![1..r + 1, 1..c + 1]).assign(&s);
        let t = Tif::new(padded, 0.5, 0.5).unwrap();
        let [_, ax, ay] = kernels_from_sampled(&t);
        let [_, fx, fy] = kernels_from_field(&t, 0.5, 0.5).unwrap();
        for (a, b) in [(&ax, &fx), (&ay, &fy)] {
            assert_eq!(a.rate_nm_per_s.dim(), b.rate_nm_per_s.dim());
            let d = (&a.rate_nm_per_s - &b.rate_nm_per_s)
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(d < 1e-12, "{d}");
        }
        // Volume is kept.
        assert!((ax.volume_rate_nm_mm2_per_s() / t.volume_rate_nm_mm2_per_s() - 1.0).abs() < 1e-12);
    }
}
