//! The tool influence function as the calibration uses it: the project's one TIF front end
//! (`bonnetlab_process::simulate::ToolModel`: analytic models, or a measured spot as a continuous
//! field at its own resolution), sampled onto the map's pixel pitch as a convolution kernel,
//! optionally widened by a scale factor (`T_s(r) = T(r / s)`), and its derivatives.

use std::sync::Arc;

use bonnetlab_process::simulate::ToolModel;
use ndarray::Array2;

/// A TIF for the calibration's kernels: a shared handle on the run's [`ToolModel`].
#[derive(Clone)]
pub struct TifMap {
    tool: Arc<ToolModel>,
}

impl std::fmt::Debug for TifMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (ex, ey) = self.tool.field().half_extent_mm();
        write!(f, "TifMap(half extent {ex} x {ey} mm)")
    }
}

impl TifMap {
    /// The calibration's view of a run's tool model.
    pub fn new(tool: ToolModel) -> TifMap {
        TifMap {
            tool: Arc::new(tool),
        }
    }

    /// The tool model.
    pub fn tool(&self) -> &ToolModel {
        &self.tool
    }

    /// Rate (nm/s) at an offset (mm) from the tool centre; 0 outside the footprint.
    pub fn value_at_mm(&self, x_mm: f64, y_mm: f64) -> f64 {
        self.tool.field().rate_at_mm(x_mm, y_mm)
    }

    /// Radius (mm) outside which the rate is 0 (the larger half-extent of the footprint).
    pub fn support_radius_mm(&self) -> f64 {
        let (ex, ey) = self.tool.field().half_extent_mm();
        ex.max(ey)
    }

    /// Kernel `(2 hr + 1) x (2 hc + 1)` on pitch (dx, dy), of the spot widened by `scale`:
    /// `K(x) = T(x / scale)`.
    pub fn kernel(&self, dx_mm: f64, dy_mm: f64, hr: usize, hc: usize, scale: f64) -> Array2<f64> {
        Array2::from_shape_fn((2 * hr + 1, 2 * hc + 1), |(a, b)| {
            let y = (a as f64 - hr as f64) * dy_mm / scale;
            let x = (b as f64 - hc as f64) * dx_mm / scale;
            self.value_at_mm(x, y)
        })
    }
}

/// Central-difference derivatives (per mm) of a kernel along x (columns) and y (rows).
pub fn kernel_gradient(k: &Array2<f64>, dx_mm: f64, dy_mm: f64) -> (Array2<f64>, Array2<f64>) {
    let (r, c) = k.dim();
    let at = |i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i as usize >= r || j as usize >= c {
            0.0
        } else {
            k[(i as usize, j as usize)]
        }
    };
    let gx = Array2::from_shape_fn((r, c), |(i, j)| {
        (at(i as isize, j as isize + 1) - at(i as isize, j as isize - 1)) / (2.0 * dx_mm)
    });
    let gy = Array2::from_shape_fn((r, c), |(i, j)| {
        (at(i as isize + 1, j as isize) - at(i as isize - 1, j as isize)) / (2.0 * dy_mm)
    });
    (gx, gy)
}

#[cfg(test)]
mod tests {
    use super::*;

    use bonnetlab_process::recipe::TifSource;
    use bonnetlab_process::tif::GaussianTif;

    #[test]
    fn kernel_widening() {
        let g = GaussianTif::new(1.5, 12.0, 10.0).unwrap();
        let tool = ToolModel::from_source(&TifSource::Gaussian(g), None, 0.25, 0.25).unwrap();
        let t = TifMap::new(tool);
        // scale 2: value at 2 mm equals the original's value at 1 mm
        let k = t.kernel(0.25, 0.25, 12, 12, 2.0);
        assert!((k[(12, 20)] - t.value_at_mm(1.0, 0.0)).abs() < 1e-12);
        assert!((t.support_radius_mm() - 6.0).abs() < 1e-12);
    }

    #[test]
    fn gradient_of_a_linear_ramp_is_its_slope() {
        let k = Array2::from_shape_fn((5, 5), |(i, j)| 2.0 * j as f64 - 3.0 * i as f64);
        let (gx, gy) = kernel_gradient(&k, 0.5, 0.25);
        assert!((gx[(2, 2)] - 4.0).abs() < 1e-12);
        assert!((gy[(2, 2)] + 12.0).abs() < 1e-12);
    }
}
