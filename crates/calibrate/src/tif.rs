//! The tool influence function as the calibration uses it: the project's one TIF front end
//! (`bonnetlab_process::simulate::ToolModel`: analytic models, or a measured spot as a continuous
//! field at its own resolution), sampled onto the map's pixel pitch as a convolution kernel,
//! optionally widened by a scale factor (`T_s(r) = T(r / s)`), and its derivatives.

use std::sync::Arc;

use bonnetlab_process::pixel::{PixelResponse, PixelSampling};
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::RateField;

/// A TIF for the calibration's kernels: a shared handle on the run's [`ToolModel`], which
/// also says how the maps' pixels sample the removal (the forward model's kernels see it).
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
    /// The calibration's view of a run's tool model (seen by the maps' pixels as the tool
    /// says, [`ToolModel::response`]).
    pub fn new(tool: ToolModel) -> TifMap {
        TifMap {
            tool: Arc::new(tool),
        }
    }

    /// How the maps' pixels sample the removal.
    pub fn pixels(&self) -> PixelSampling {
        if self.tool.response().is_point() {
            PixelSampling::Point
        } else {
            PixelSampling::Area
        }
    }

    /// The maps' pixels' response (their box in mm when they are area means).
    pub fn response(&self) -> PixelResponse {
        self.tool.response()
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

    /// The tool model as a shared rate field (what the forward model's channels take).
    pub fn field(&self) -> Arc<dyn RateField + Send> {
        self.tool.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use bonnetlab_process::recipe::TifSource;
    use bonnetlab_process::tif::GaussianTif;

    #[test]
    fn the_field_is_the_tool_model() {
        let g = GaussianTif::new(1.5, 12.0, 10.0).unwrap();
        let tool = ToolModel::from_source(&TifSource::Gaussian(g), None, 0.25, 0.25).unwrap();
        let t = TifMap::new(tool);
        assert!((t.field().rate_at_mm(1.0, 0.5) - t.value_at_mm(1.0, 0.5)).abs() < 1e-15);
        assert!((t.support_radius_mm() - 6.0).abs() < 1e-12);
    }
}
