//! A coupling case that owns what [`CouplingInput`] borrows: the raster run the pipelines,
//! the bench and the profiling example build, written once.

use super::CouplingInput;
use crate::error::VibrationError;
use crate::params::VibrationParams;
use bonnetlab_process::path::RasterSpec;
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::GaussianTif;
use bonnetlab_process::{Grid, PathLog};

/// A bidirectional raster over a square part with one tool and one set of vibration parameters.
pub struct CouplingCase {
    pub grid: Grid,
    pub tool: ToolModel,
    pub path: PathLog,
    pub params: VibrationParams,
    pub pitch_mm: f64,
}

impl CouplingCase {
    /// A raster over `[0, part_mm]^2` on a grid of `n x n` pixels of `pixel_mm` whose first
    /// pixel centre sits at `origin_mm` (both axes), pitch `pitch_mm`, feed `feed_mm_per_s`,
    /// `overtravel_mm` past the part; the tool sampled at the pixel.
    #[allow(clippy::too_many_arguments)]
    pub fn square_raster(
        source: &TifSource,
        params: VibrationParams,
        n: usize,
        pixel_mm: f64,
        origin_mm: f64,
        part_mm: f64,
        pitch_mm: f64,
        feed_mm_per_s: f64,
        overtravel_mm: f64,
    ) -> Result<CouplingCase, VibrationError> {
        let bad = |e: &dyn std::fmt::Display| VibrationError::InvalidArgument(e.to_string());
        let grid =
            Grid::new(n, n, pixel_mm, pixel_mm, origin_mm, origin_mm).map_err(|e| bad(&e))?;
        let tool = ToolModel::from_source(source, None, pixel_mm, pixel_mm).map_err(|e| bad(&e))?;
        let mut spec =
            RasterSpec::over_rect((0.0, part_mm), (0.0, part_mm), pitch_mm, feed_mm_per_s);
        spec.overtravel_mm = overtravel_mm;
        let path = spec.generate().map_err(|e| bad(&e))?;
        Ok(CouplingCase {
            grid,
            tool,
            path,
            params,
            pitch_mm,
        })
    }

    /// The bench case (reports/performance_vibration.md): 100 x 100 mm at 0.1 mm (1001^2), a
    /// Gaussian TIF (sigma 2 mm, 10 nm/s), 3 mm pitch at 1.16 mm/s with 10 mm overtravel (a
    /// 60-minute raster), the default vibration parameters.
    pub fn bench_100mm() -> Result<CouplingCase, VibrationError> {
        CouplingCase::square_raster(
            &TifSource::Gaussian(CouplingCase::bench_tif()?),
            VibrationParams::default(),
            1001,
            0.1,
            0.0,
            100.0,
            3.0,
            1.16,
            10.0,
        )
    }

    /// The bench case's TIF: Gaussian, sigma 2 mm, peak 10 nm/s, support 10 mm.
    pub fn bench_tif() -> Result<GaussianTif, VibrationError> {
        GaussianTif::new(2.0, 10.0, 10.0)
            .map_err(|e| VibrationError::InvalidArgument(e.to_string()))
    }

    /// The borrowed input of the coupling (every pixel valid).
    pub fn input(&self) -> CouplingInput<'_> {
        CouplingInput {
            grid: self.grid,
            valid: None,
            tool: &self.tool,
            path: &self.path,
            params: &self.params,
            pitch_mm: Some(self.pitch_mm),
        }
    }
}
