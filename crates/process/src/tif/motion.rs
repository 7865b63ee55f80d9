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
//! direction. The box-averaged kernels are one pixel wider along their axis. For raster lines
//! along X that sit between pixel rows, [`along_x_at_phase`] gives the along-X kernel at the
//! lines' sub-row offset, so nothing is interpolated across the lines.

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
    let half = Tif::sample_half_widths(field, dx_mm, dy_mm)?;
    Ok([
        kernel_from_field(field, dx_mm, dy_mm, Motion::Resting, half)?,
        kernel_from_field(field, dx_mm, dy_mm, Motion::AlongX, half)?,
        kernel_from_field(field, dx_mm, dy_mm, Motion::AlongY, half)?,
    ])
}

/// The kernel of one [`Motion`] ([`kernels_from_field`]'s three), given the half-widths
/// `(h0, h1)` of the point-sampled kernel ([`Tif::sample_half_widths`]).
pub fn kernel_from_field(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    motion: Motion,
    (h0, h1): (usize, usize),
) -> Result<Tif, ProcessError> {
    match motion {
        Motion::Resting => Tif::sample(field, dx_mm, dy_mm),
        // One more pixel along the axis: the box reaches half a pixel beyond the footprint.
        Motion::AlongX => box_kernel(field, dx_mm, dy_mm, true, (h0, h1 + 1), 0.0),
        Motion::AlongY => box_kernel(field, dx_mm, dy_mm, false, (h0 + 1, h1), 0.0),
    }
}

/// The along-X kernel for a tool centre `phase` rows (0 <= phase <= 1) below the pixel row its
/// dwell is put on: `K(i, j)` is the one-pixel X average of the footprint at offset
/// `((j - c1) dx, (i - c0 - phase) dy)` from the tool. With one such kernel per line phase a
/// raster needs no interpolation across its lines, where a steep footprint edge (the Hertz
/// bonnet's line integral has a kink at |y| = a) defeats any fixed 4-tap interpolation: at
/// 0.5 mm pixels a cubic splat misses the line profile by up to 2 % of its peak there.
pub fn along_x_at_phase(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    phase: f64,
) -> Result<Tif, ProcessError> {
    let half = Tif::sample_half_widths(field, dx_mm, dy_mm)?;
    along_x_at_phase_sized(field, dx_mm, dy_mm, phase, half)
}

/// [`along_x_at_phase`] given the half-widths `(h0, h1)` of the field's point-sampled kernel
/// ([`Tif::sample_half_widths`]), for callers that build many phases.
pub fn along_x_at_phase_sized(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    phase: f64,
    (h0, h1): (usize, usize),
) -> Result<Tif, ProcessError> {
    box_kernel(
        field,
        dx_mm,
        dy_mm,
        true,
        phase_half_widths(true, (h0, h1)),
        phase,
    )
}

/// Half-widths of a line-phase kernel for motion along X (`along_x`) or Y, from those of the
/// point-sampled kernel: two more across the motion (the footprint shifted by up to a pixel
/// still fits) and one more along it (a box average reaches half a pixel beyond).
fn phase_half_widths(along_x: bool, (h0, h1): (usize, usize)) -> (usize, usize) {
    if along_x {
        (h0 + 2, h1 + 1)
    } else {
        (h0 + 1, h1 + 2)
    }
}

/// The along-Y kernel for a tool centre `phase` columns (0 <= phase <= 1) right of the pixel
/// column its dwell is put on (lines scanned along Y): [`along_x_at_phase`] with the axes
/// swapped.
pub fn along_y_at_phase(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    phase: f64,
) -> Result<Tif, ProcessError> {
    let half = Tif::sample_half_widths(field, dx_mm, dy_mm)?;
    along_y_at_phase_sized(field, dx_mm, dy_mm, phase, half)
}

/// [`along_y_at_phase`] given the half-widths of the field's point-sampled kernel.
pub fn along_y_at_phase_sized(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    phase: f64,
    (h0, h1): (usize, usize),
) -> Result<Tif, ProcessError> {
    box_kernel(
        field,
        dx_mm,
        dy_mm,
        false,
        phase_half_widths(false, (h0, h1)),
        phase,
    )
}

/// The point-sampled kernel for a tool centre `phase` pixels (0 <= phase <= 1) off the pixel
/// lane its dwell is put on, across the motion: below the row for motion along X (`along_x`),
/// right of the column for motion along Y; sized as [`along_x_at_phase_sized`] and
/// [`along_y_at_phase_sized`]. For a minor motion (a raster's step-overs), whose lines need the
/// exact phase across them but whose one-pixel average along them changes its small removal
/// by about 1 %: one field value per kernel pixel instead of 32.
pub fn point_at_phase_sized(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    phase: f64,
    along_x: bool,
    half: (usize, usize),
) -> Result<Tif, ProcessError> {
    let (g0, g1) = phase_half_widths(along_x, half);
    let (px, py) = if along_x { (0.0, phase) } else { (phase, 0.0) };
    let rate = Array2::from_shape_fn((2 * g0 + 1, 2 * g1 + 1), |(i, j)| {
        field.rate_at_mm(
            (j as f64 - g1 as f64 - px) * dx_mm,
            (i as f64 - g0 as f64 - py) * dy_mm,
        )
    });
    Tif::new(rate, dx_mm, dy_mm)
}

/// A (2 g0 + 1) x (2 g1 + 1) kernel: the field averaged over one pixel along X (`along_x`) or
/// Y, shifted across that axis by `phase` pixels (rows for along X, columns for along Y).
fn box_kernel(
    field: &dyn RateField,
    dx_mm: f64,
    dy_mm: f64,
    along_x: bool,
    (g0, g1): (usize, usize),
    phase: f64,
) -> Result<Tif, ProcessError> {
    let (rows, cols) = (2 * g0 + 1, 2 * g1 + 1);
    let (px, py) = if along_x { (0.0, phase) } else { (phase, 0.0) };
    let x_of = |j: usize| (j as f64 - g1 as f64 - px) * dx_mm;
    let y_of = |i: usize| (i as f64 - g0 as f64 - py) * dy_mm;
    // One line of the kernel (a row moving along X, a column along Y) at a time: its SUB
    // midpoints per pixel in one call of the field.
    let (lines, len, h) = if along_x {
        (rows, cols, dx_mm)
    } else {
        (cols, rows, dy_mm)
    };
    // The field is 0 beyond its half-extent: lines across the motion farther out, and the
    // pixels along a line whose box lies wholly beyond it, stay 0 without asking the field (a
    // kernel sized for a wider footprint, as a scan of the TIF's width builds, is mostly such
    // lines).
    let (ex, ey) = field.half_extent_mm();
    let (e_along, e_across) = if along_x { (ex, ey) } else { (ey, ex) };
    let mut t = Vec::with_capacity(len * SUB);
    let mut v = vec![0.0; len * SUB];
    let mut rate = Array2::zeros((rows, cols));
    for l in 0..lines {
        let c = if along_x { y_of(l) } else { x_of(l) };
        // With a relative margin: a sampled TIF's bilinear interpolant reaches its last row
        // within 1e-12 beyond its extent, and a widened field divides by the scale.
        if c.abs() > e_across * (1.0 + 1e-9) {
            continue;
        }
        let inside = |p: usize| {
            let centre = if along_x { x_of(p) } else { y_of(p) };
            centre.abs() - 0.5 * h <= e_along
        };
        let Some(first) = (0..len).find(|&p| inside(p)) else {
            continue;
        };
        let last = (0..len).rev().find(|&p| inside(p)).unwrap_or(first);
        t.clear();
        for p in first..=last {
            let centre = if along_x { x_of(p) } else { y_of(p) };
            t.extend((0..SUB).map(|k| centre + ((k as f64 + 0.5) / SUB as f64 - 0.5) * h));
        }
        let v = &mut v[..t.len()];
        field.rates_along(along_x, c, &t, v);
        for (p, chunk) in (first..).zip(v.chunks_exact(SUB)) {
            let mean = chunk.iter().sum::<f64>() / SUB as f64;
            if along_x {
                rate[(l, p)] = mean;
            } else {
                rate[(p, l)] = mean;
            }
        }
    }
    Tif::new(rate, dx_mm, dy_mm)
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
    fn phase_kernel_rows_are_the_line_integrals_at_shifted_offsets() {
        let m = BonnetTif::new(&BonnetTifParams::paper(10.0)).unwrap();
        let dx = 0.5;
        let phase = 0.4;
        let k = along_x_at_phase(&m, dx, dx, phase).unwrap();
        let (c0, _) = k.half_widths();
        let peak = line_integral(&m, 0.0);
        let mut worst = 0.0f64;
        for i in 0..k.rate_nm_per_s.nrows() {
            let y = (i as f64 - c0 as f64 - phase) * dx;
            let got = k.rate_nm_per_s.row(i).sum() * dx;
            worst = worst.max((got - line_integral(&m, y)).abs() / peak);
        }
        assert!(worst < 1e-4, "{worst}");
        // Phase 0 is the centred along-X kernel with two zero rows more on each side.
        let [_, ax, _] = kernels_from_field(&m, dx, dx).unwrap();
        let k0 = along_x_at_phase(&m, dx, dx, 0.0).unwrap();
        let (r, _) = ax.rate_nm_per_s.dim();
        let d = (&k0.rate_nm_per_s.slice(ndarray::s![2..r + 2, ..]) - &ax.rate_nm_per_s)
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(d < 1e-12);
        // Along Y is along X with the axes swapped (the four-step footprint is symmetric).
        let ky = along_y_at_phase(&m, dx, dx, phase).unwrap();
        let d = (&ky.rate_nm_per_s - &k.rate_nm_per_s.t())
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(d < 1e-9 * k.peak_rate_nm_per_s(), "{d}");
    }
}
