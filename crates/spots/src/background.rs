//! The background of a spot map: piston and tilt fitted on a ring around the spot, and the
//! removal map it leaves.
//!
//! Convention: removal = -(height - background) for a height map of a dip (positive = material
//! removed, spec/interfaces.md); a map that already holds removal keeps its sign. The ring is the
//! annulus `ring_inner_mm <= r <= ring_outer_mm` about the spot centre; by default
//! `ring_inner = 1.4 R5` and `ring_outer = 1.9 R5`, where `R5` is the equivalent radius
//! (sqrt(area / pi)) of the pixels removed by more than 5 % of the peak. The ring may run off the
//! map: only its valid pixels are used, and at least `MIN_RING_PIXELS` are required.
//!
//! The fit itself is the process TIF front end's (`bonnetlab_process::tif::measured`:
//! `plane_background`, and `border_ring` for the rough first background); only the ring differs:
//! the front end uses the map's border ring, the spot metrics the annulus about the spot that the
//! manifest can set (`ring_inner_mm`, `ring_outer_mm`).

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use bonnetlab_process::tif::measured::SpotOptions as ProcessSpotOptions;
use bonnetlab_process::tif::measured::{border_ring, plane_background};
use bonnetlab_process::ProcessError;
use bonnetlab_surface::{Surface, Term};

use crate::error::SpotsError;

/// Fewest valid pixels a background ring may have.
pub const MIN_RING_PIXELS: usize = 30;
/// Default ring radii as multiples of R5.
pub const RING_INNER_PER_R5: f64 = 1.4;
pub const RING_OUTER_PER_R5: f64 = 1.9;

/// What the map's values mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MapKind {
    /// A height map of the polished spot (a dip): removal = -(height - background).
    #[default]
    Height,
    /// A removal map (positive = removed).
    Removal,
}

/// The annulus used for the background fit, in mm about a centre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Ring {
    pub centre_x_mm: f64,
    pub centre_y_mm: f64,
    pub inner_mm: f64,
    pub outer_mm: f64,
}

/// Result of the ring fit.
#[derive(Debug, Clone)]
pub struct Background {
    /// Removal in nm on the map's grid (invalid pixels hold 0 and are invalid in the Surface).
    pub removal: Surface,
    pub ring: Ring,
    pub ring_pixels: usize,
    /// RMS of the heights on the ring after piston and tilt: the measurement noise estimate.
    pub ring_residual_rms_nm: f64,
}

/// Signed removal from raw values (no background removed).
pub(crate) fn signed(values: f64, kind: MapKind) -> f64 {
    match kind {
        MapKind::Height => -values,
        MapKind::Removal => values,
    }
}

/// Mask of valid pixels whose centre lies in the given annulus.
pub fn ring_mask(s: &Surface, ring: &Ring) -> Array2<bool> {
    let valid = s.valid();
    Array2::from_shape_fn(s.dim(), |(i, j)| {
        if !valid[(i, j)] {
            return false;
        }
        let r = (s.x_mm(j) - ring.centre_x_mm).hypot(s.y_mm(i) - ring.centre_y_mm);
        r >= ring.inner_mm && r <= ring.outer_mm
    })
}

/// Fits piston + tilt on `mask` and returns the removal map (signed by `kind`) and the RMS
/// of the fit residual on the mask: the process TIF front end's background
/// (`bonnetlab_process::tif::measured::plane_background`) on this crate's ring.
pub fn removal_after_plane(
    s: &Surface,
    mask: Array2<bool>,
    kind: MapKind,
) -> Result<(Surface, usize, f64), SpotsError> {
    let n = mask.iter().filter(|&&v| v).count();
    if n < MIN_RING_PIXELS {
        return Err(SpotsError::Spot(format!(
            "only {n} valid pixels in the background ring ({MIN_RING_PIXELS} needed): \
             the map is too small around the spot or the ring radii are wrong"
        )));
    }
    let bg = plane_background(s, &mask).map_err(|e| match e {
        ProcessError::Surface(e) => SpotsError::Surface(e),
        e => SpotsError::Spot(e.to_string()),
    })?;
    let mut out = bg
        .residual
        .with_heights(bg.residual.heights_nm().mapv(|v| signed(v, kind)))?;
    out.removed = vec![Term::Piston, Term::Tilt];
    Ok((out, bg.pixels, bg.rms_nm))
}

/// Fits the background on `ring` and returns the removal map.
pub fn fit_background(s: &Surface, ring: Ring, kind: MapKind) -> Result<Background, SpotsError> {
    let mask = ring_mask(s, &ring);
    let (removal, ring_pixels, rms) = removal_after_plane(s, mask, kind)?;
    Ok(Background {
        removal,
        ring,
        ring_pixels,
        ring_residual_rms_nm: rms,
    })
}

/// Mask of the outer frame of the map: the first, rough background before the spot is located,
/// the process TIF front end's border ring (`bonnetlab_process::tif::measured::border_ring`,
/// with its default width of a tenth of the smaller side).
pub fn frame_mask(s: &Surface) -> Array2<bool> {
    border_ring(s.valid(), ProcessSpotOptions::default().ring_fraction)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_fit_removes_an_exact_plane_under_a_dip() {
        let (rows, cols, dx) = (81, 81, 0.25);
        let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let (x, y) = (j as f64 * dx, i as f64 * dx);
            let r2 = (x - 10.0).powi(2) + (y - 10.0).powi(2);
            let dip = if r2 < 16.0 {
                -100.0 * (1.0 - r2 / 16.0)
            } else {
                0.0
            };
            5.0 + 2.0 * x - 3.0 * y + dip
        });
        let s = Surface::new(z, Some(dx), Some(dx)).unwrap();
        let ring = Ring {
            centre_x_mm: 10.0,
            centre_y_mm: 10.0,
            inner_mm: 5.0,
            outer_mm: 9.0,
        };
        let bg = fit_background(&s, ring, MapKind::Height).unwrap();
        assert!(bg.ring_residual_rms_nm < 1e-9);
        let centre = bg.removal.get(40, 40).unwrap();
        assert!((centre - 100.0).abs() < 1e-8, "{centre}");
        assert!(bg.removal.get(0, 0).unwrap().abs() < 1e-8);
        let tiny = Ring {
            inner_mm: 5.0,
            outer_mm: 5.005,
            ..ring
        };
        assert!(fit_background(&s, tiny, MapKind::Height).is_err());
    }
}
