//! `Surface`: a height map in nm on a regular grid, with its validity mask, pixel size,
//! origin, the form terms already removed from it and where it came from.
//!
//! Invariant: every pixel whose mask is `false` stores 0.0, and every stored height is finite.
//! So a sum over `heights_nm` never meets a NaN, and an FFT of the raw array is safe (analyses
//! still weight by the mask).

use ndarray::{Array2, Zip};
use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::form::Term;

/// Where a map came from, as far as its file says.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// Format tag as in the CLI contract: `metropro-dat`, `metropro-asc`, `zygo-xyz`, `datx`,
    /// `csv`, `exr`, `synthetic`, ...
    pub format: String,
    /// The file the map was read from, as the user gave it.
    pub source_path: Option<String>,
    /// Instrument description (system type, serial number).
    pub instrument: Option<String>,
    /// Measurement wavelength in m.
    pub wavelength_m: Option<f64>,
    /// Objective / aperture name.
    pub objective: Option<String>,
    /// Acquisition date as the file states it.
    pub date: Option<String>,
    /// Free comment or part name.
    pub comment: Option<String>,
    /// Software and version that wrote the file.
    pub software: Option<String>,
}

/// A height map in nm with a validity mask.
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Heights in nm, shape (rows = Y, cols = X). Invalid pixels hold 0.0.
    heights_nm: Array2<f64>,
    /// `true` where the pixel holds a measured value.
    valid: Array2<bool>,
    /// Pixel pitch along X (columns) in mm; `None` when the file says it is unknown.
    pub dx_mm: Option<f64>,
    /// Pixel pitch along Y (rows) in mm; `None` when unknown.
    pub dy_mm: Option<f64>,
    /// Centre of pixel (0, 0) in mm (x0, y0).
    pub origin_mm: (f64, f64),
    /// Form terms already removed from these heights, in the order removed.
    pub removed: Vec<Term>,
    /// Where the data came from.
    pub provenance: Provenance,
}

impl Surface {
    /// Builds a surface from heights in nm; non-finite heights become invalid pixels.
    /// Pixel sizes must be positive and finite when given.
    pub fn new(
        heights_nm: Array2<f64>,
        dx_mm: Option<f64>,
        dy_mm: Option<f64>,
    ) -> Result<Self, SurfaceError> {
        let valid = heights_nm.mapv(f64::is_finite);
        Self::with_mask(heights_nm, valid, dx_mm, dy_mm)
    }

    /// Builds a surface from heights and an explicit mask; a non-finite height is invalid
    /// whatever the mask says.
    pub fn with_mask(
        mut heights_nm: Array2<f64>,
        mut valid: Array2<bool>,
        dx_mm: Option<f64>,
        dy_mm: Option<f64>,
    ) -> Result<Self, SurfaceError> {
        if heights_nm.dim() != valid.dim() {
            return Err(SurfaceError::GridMismatch(format!(
                "heights {:?} vs mask {:?}",
                heights_nm.dim(),
                valid.dim()
            )));
        }
        for (name, d) in [("dx_mm", dx_mm), ("dy_mm", dy_mm)] {
            if let Some(v) = d {
                if !(v.is_finite() && v > 0.0) {
                    return Err(SurfaceError::InvalidArgument(format!(
                        "{name} must be positive and finite, got {v}"
                    )));
                }
            }
        }
        Zip::from(&mut heights_nm).and(&mut valid).for_each(|h, v| {
            if !h.is_finite() {
                *v = false;
            }
            if !*v {
                *h = 0.0;
            }
        });
        Ok(Surface {
            heights_nm,
            valid,
            dx_mm,
            dy_mm,
            origin_mm: (0.0, 0.0),
            removed: Vec::new(),
            provenance: Provenance::default(),
        })
    }

    /// A surface with the same grid, mask, metadata and new heights (non-finite -> invalid).
    pub fn with_heights(&self, heights_nm: Array2<f64>) -> Result<Self, SurfaceError> {
        let mut s = Self::with_mask(heights_nm, self.valid.clone(), self.dx_mm, self.dy_mm)?;
        s.origin_mm = self.origin_mm;
        s.removed = self.removed.clone();
        s.provenance = self.provenance.clone();
        Ok(s)
    }

    /// A surface with the same heights and metadata and a new mask, intersected with nothing:
    /// pixels newly marked invalid are zeroed, pixels newly marked valid keep their stored value.
    pub fn with_valid(&self, valid: Array2<bool>) -> Result<Self, SurfaceError> {
        let mut s = Self::with_mask(self.heights_nm.clone(), valid, self.dx_mm, self.dy_mm)?;
        s.origin_mm = self.origin_mm;
        s.removed = self.removed.clone();
        s.provenance = self.provenance.clone();
        Ok(s)
    }

    /// Heights in nm (invalid pixels hold 0.0).
    pub fn heights_nm(&self) -> &Array2<f64> {
        &self.heights_nm
    }

    /// Validity mask.
    pub fn valid(&self) -> &Array2<bool> {
        &self.valid
    }

    /// (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        self.heights_nm.dim()
    }

    pub fn rows(&self) -> usize {
        self.heights_nm.nrows()
    }

    pub fn cols(&self) -> usize {
        self.heights_nm.ncols()
    }

    /// Number of valid pixels.
    pub fn valid_count(&self) -> usize {
        self.valid.iter().filter(|&&v| v).count()
    }

    /// Height at (row, col) if valid.
    pub fn get(&self, row: usize, col: usize) -> Option<f64> {
        match self.valid.get((row, col)) {
            Some(true) => Some(self.heights_nm[(row, col)]),
            _ => None,
        }
    }

    /// Heights with NaN at invalid pixels (for writers and display only; never for analysis).
    pub fn to_nan_array(&self) -> Array2<f64> {
        let mut a = self.heights_nm.clone();
        Zip::from(&mut a).and(&self.valid).for_each(|h, &v| {
            if !v {
                *h = f64::NAN;
            }
        });
        a
    }

    /// Pixel size (dx, dy) in mm, or an error naming the use when either is unknown.
    pub fn pixel_mm(&self, purpose: &str) -> Result<(f64, f64), SurfaceError> {
        match (self.dx_mm, self.dy_mm) {
            (Some(dx), Some(dy)) => Ok((dx, dy)),
            _ => Err(SurfaceError::InvalidArgument(format!(
                "the pixel size is unknown (the file does not give one); {purpose} needs it: give it explicitly"
            ))),
        }
    }

    /// x coordinate (mm) of column `j` (pixel units when the pixel size is unknown).
    pub fn x_mm(&self, j: usize) -> f64 {
        self.origin_mm.0 + j as f64 * self.dx_mm.unwrap_or(1.0)
    }

    /// y coordinate (mm) of row `i` (pixel units when the pixel size is unknown).
    pub fn y_mm(&self, i: usize) -> f64 {
        self.origin_mm.1 + i as f64 * self.dy_mm.unwrap_or(1.0)
    }

    /// Iterator over the valid heights.
    pub fn valid_heights(&self) -> impl Iterator<Item = f64> + '_ {
        self.heights_nm
            .iter()
            .zip(self.valid.iter())
            .filter_map(|(&h, &v)| v.then_some(h))
    }

    /// Pixel-wise a - b on the common valid aperture (the grids must match).
    pub fn difference(&self, other: &Surface) -> Result<Surface, SurfaceError> {
        if self.dim() != other.dim() {
            return Err(SurfaceError::GridMismatch(format!(
                "{:?} vs {:?}",
                self.dim(),
                other.dim()
            )));
        }
        let h = &self.heights_nm - &other.heights_nm;
        let v = Zip::from(&self.valid)
            .and(&other.valid)
            .map_collect(|&a, &b| a && b);
        let mut s = Self::with_mask(h, v, self.dx_mm, self.dy_mm)?;
        s.origin_mm = self.origin_mm;
        s.provenance = Provenance {
            format: "derived".into(),
            comment: Some("difference of two maps".into()),
            ..Provenance::default()
        };
        Ok(s)
    }
}

/// Bounding box of the `true` pixels of a mask as inclusive (first row, last row, first column,
/// last column); `None` when no pixel is set.
pub fn mask_bounds(valid: &Array2<bool>) -> Option<(usize, usize, usize, usize)> {
    let (mut r0, mut r1, mut c0, mut c1) = (usize::MAX, 0, usize::MAX, 0);
    for ((i, j), &ok) in valid.indexed_iter() {
        if ok {
            r0 = r0.min(i);
            r1 = r1.max(i);
            c0 = c0.min(j);
            c1 = c1.max(j);
        }
    }
    (r0 != usize::MAX).then_some((r0, r1, c0, c1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::array;

    #[test]
    fn nan_becomes_invalid_and_zero() {
        let s = Surface::new(array![[1.0, f64::NAN], [3.0, 4.0]], Some(0.1), Some(0.1)).unwrap();
        assert_eq!(s.valid_count(), 3);
        assert_eq!(s.heights_nm()[(0, 1)], 0.0);
        assert!(s.to_nan_array()[(0, 1)].is_nan());
        assert_eq!(s.valid_heights().sum::<f64>(), 8.0);
    }

    #[test]
    fn rejects_bad_pixel_size_and_mismatched_mask() {
        assert!(Surface::new(array![[1.0]], Some(0.0), Some(0.1)).is_err());
        assert!(Surface::with_mask(array![[1.0]], array![[true, true]], None, None).is_err());
    }

    #[test]
    fn mask_bounds_box_the_set_pixels() {
        let mut v = Array2::from_elem((4, 5), false);
        assert_eq!(mask_bounds(&v), None);
        v[(1, 3)] = true;
        v[(2, 1)] = true;
        assert_eq!(mask_bounds(&v), Some((1, 2, 1, 3)));
    }

    #[test]
    fn difference_uses_common_aperture() {
        let a = Surface::new(array![[5.0, 1.0]], None, None).unwrap();
        let b = Surface::new(array![[2.0, f64::NAN]], None, None).unwrap();
        let d = a.difference(&b).unwrap();
        assert_eq!(d.valid_count(), 1);
        assert_eq!(d.get(0, 0), Some(3.0));
    }
}
