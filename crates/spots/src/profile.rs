//! Profiles through the spot centre and their half-maximum crossings (FWHM).
//!
//! The removal map is interpolated bilinearly (a sample needs its four surrounding pixels
//! valid). From the centre, the profile is walked outward in steps of a quarter pixel until it
//! first falls below half the peak; the crossing is interpolated linearly between the last two
//! samples. FWHM along X = left + right half-widths through the centre, along Y likewise.

use bonnetlab_process::interp::bilinear_masked;
use bonnetlab_surface::Surface;

/// Bilinear interpolation of the valid map at (x, y) mm; `None` outside or next to a hole
/// (`bonnetlab_process::interp::bilinear_masked`).
pub fn bilinear(s: &Surface, x_mm: f64, y_mm: f64) -> Option<f64> {
    let fx = (x_mm - s.origin_mm.0) / s.dx_mm?;
    let fy = (y_mm - s.origin_mm.1) / s.dy_mm?;
    bilinear_masked(s.heights_nm(), s.valid(), fy, fx)
}

/// Distance (mm) from `(cx, cy)` along the unit direction `(ux, uy)` at which the interpolated
/// profile first falls below `level`; `None` if it leaves the valid data first.
pub fn crossing(
    s: &Surface,
    (cx, cy): (f64, f64),
    (ux, uy): (f64, f64),
    level: f64,
    max_mm: f64,
) -> Option<f64> {
    let step = 0.25 * s.dx_mm?.min(s.dy_mm?);
    let mut prev_t = 0.0;
    let mut prev_v = bilinear(s, cx, cy)?;
    let n = (max_mm / step).ceil() as usize;
    for k in 1..=n {
        let t = k as f64 * step;
        let v = bilinear(s, cx + t * ux, cy + t * uy)?;
        if v < level {
            let frac = if prev_v > v {
                (prev_v - level) / (prev_v - v)
            } else {
                0.0
            };
            return Some(prev_t + frac.clamp(0.0, 1.0) * (t - prev_t));
        }
        prev_t = t;
        prev_v = v;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn bilinear_is_exact_on_a_plane_and_crossing_on_a_cone() {
        let dx = 0.2;
        let plane =
            Array2::from_shape_fn((20, 30), |(i, j)| 1.0 + 2.0 * j as f64 * dx - i as f64 * dx);
        let s = Surface::new(plane, Some(dx), Some(dx)).unwrap();
        let v = bilinear(&s, 1.234, 2.345).unwrap();
        assert!((v - (1.0 + 2.0 * 1.234 - 2.345)).abs() < 1e-12);
        assert!(bilinear(&s, -0.1, 1.0).is_none());
        assert!(bilinear(&s, 5.9, 1.0).is_none());
        // A cone 100 (1 - r / 4) about (3.03, 2.97): half maximum at r = 2 exactly; linear
        // along radial lines except at the apex pixel cell, where the walk does not stop.
        let cone = Array2::from_shape_fn((41, 41), |(i, j)| {
            let r = (j as f64 * dx - 3.03).hypot(i as f64 * dx - 2.97);
            100.0 * (1.0 - r / 4.0)
        });
        let s = Surface::new(cone, Some(dx), Some(dx)).unwrap();
        let r = crossing(&s, (3.03, 2.97), (1.0, 0.0), 50.0, 4.0).unwrap();
        assert!((r - 2.0).abs() < 0.01, "{r}");
        assert!(crossing(&s, (3.03, 2.97), (1.0, 0.0), -500.0, 10.0).is_none());
    }
}
