//! `Grid`: the regular pixel grid of a surface map in the shared frame (pixel (i, j) centre at
//! (x0 + j dx, y0 + i dy) mm; rows = Y = feed, columns = X = scan). The project's one grid type:
//! the process model, the calibration, the vibration coupling and the synthetic runs all use it
//! (`bonnetlab_process::Grid` is this type, re-exported).

use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::surface::Surface;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// Centre of pixel (0, 0) in mm.
    pub x0_mm: f64,
    pub y0_mm: f64,
}

impl Grid {
    /// A grid; the pixel sizes must be positive and finite and the grid non-empty.
    pub fn new(
        rows: usize,
        cols: usize,
        dx_mm: f64,
        dy_mm: f64,
        x0_mm: f64,
        y0_mm: f64,
    ) -> Result<Grid, SurfaceError> {
        let invalid = |m: String| Err(SurfaceError::InvalidArgument(m));
        if rows == 0 || cols == 0 {
            return invalid(format!("empty grid {rows} x {cols}"));
        }
        for (name, v) in [("dx_mm", dx_mm), ("dy_mm", dy_mm)] {
            if !(v.is_finite() && v > 0.0) {
                return invalid(format!("{name} must be positive, got {v}"));
            }
        }
        if !(x0_mm.is_finite() && y0_mm.is_finite()) {
            return invalid("grid origin must be finite".into());
        }
        Ok(Grid {
            rows,
            cols,
            dx_mm,
            dy_mm,
            x0_mm,
            y0_mm,
        })
    }

    /// The grid of a surface map; its pixel size must be known.
    pub fn of(s: &Surface) -> Result<Grid, SurfaceError> {
        let (dx, dy) = s.pixel_mm("process simulation")?;
        Grid::new(s.rows(), s.cols(), dx, dy, s.origin_mm.0, s.origin_mm.1)
    }

    pub fn x_mm(&self, j: usize) -> f64 {
        self.x0_mm + j as f64 * self.dx_mm
    }

    pub fn y_mm(&self, i: usize) -> f64 {
        self.y0_mm + i as f64 * self.dy_mm
    }

    /// Fractional column / row of a point in mm.
    pub fn frac_index(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        (
            (y_mm - self.y0_mm) / self.dy_mm,
            (x_mm - self.x0_mm) / self.dx_mm,
        )
    }

    /// Centre of the map (mm): the mid-point between its outer pixel centres.
    pub fn centre_mm(&self) -> (f64, f64) {
        (
            self.x0_mm + 0.5 * (self.cols as f64 - 1.0) * self.dx_mm,
            self.y0_mm + 0.5 * (self.rows as f64 - 1.0) * self.dy_mm,
        )
    }

    /// The grid grown by `grow_rows` / `grow_cols` pixels on every side (same pixel size).
    pub fn grown(&self, grow_rows: usize, grow_cols: usize) -> Grid {
        Grid {
            rows: self.rows + 2 * grow_rows,
            cols: self.cols + 2 * grow_cols,
            dx_mm: self.dx_mm,
            dy_mm: self.dy_mm,
            x0_mm: self.x0_mm - grow_cols as f64 * self.dx_mm,
            y0_mm: self.y0_mm - grow_rows as f64 * self.dy_mm,
        }
    }

    pub fn len(&self) -> usize {
        self.rows * self.cols
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grown_grid_keeps_pixel_centres() {
        let g = Grid::new(3, 4, 0.5, 0.25, 1.0, 2.0).unwrap();
        let h = g.grown(2, 1);
        assert_eq!((h.rows, h.cols), (7, 6));
        assert!((h.x_mm(1) - g.x_mm(0)).abs() < 1e-12);
        assert!((h.y_mm(2) - g.y_mm(0)).abs() < 1e-12);
        assert!(Grid::new(0, 1, 1.0, 1.0, 0.0, 0.0).is_err());
        assert!(Grid::new(1, 1, -1.0, 1.0, 0.0, 0.0).is_err());
    }
}
