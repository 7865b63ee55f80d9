//! Predicting a run: the removal of a path with a TIF on the before map's grid, and the
//! predicted after map (after = before - removal, on the before map's valid pixels).
//!
//! The TIF comes from a recipe's `[tif]`: a measured spot (resampled to the map pitch) or a
//! model. The fast path builds its kernels from the model itself (point values for a resting
//! tool, one-pixel averages along the motion for a moving one); exact deposition evaluates the
//! model analytically. `sampled()` (anti-aliased for hard edges) is the TIF shown in reports.

use bonnetlab_surface::Surface;
use ndarray::Array2;

use crate::error::ProcessError;
use crate::grid::Grid;
use crate::path::PathLog;
use crate::recipe::TifSource;
use crate::removal::{deposit_exact, ExactOptions, FastRemoval};
use crate::tif::bonnet::BonnetTif;
use crate::tif::measured::{MeasuredTif, SpotOptions};
use crate::tif::{RateField, Tif};

/// How the removal is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Dwell map convolved with the TIF by FFT.
    Fast,
    /// Time-domain deposition of the instantaneous TIF (the reference; slower).
    Exact,
}

/// A TIF ready for simulation: sampled at the map pitch, and the field exact deposition uses.
pub enum ToolModel {
    Sampled(Tif),
    /// A measured spot: the field at the spot's own pixel, and its samples at the map pitch.
    Measured(Tif, Box<MeasuredTif>),
    Gaussian(Tif, crate::tif::GaussianTif),
    Bonnet(Tif, Box<BonnetTif>),
}

impl ToolModel {
    /// Builds the TIF of a recipe's `[tif]` at pixel (dx, dy); `spot` must be the spot map when
    /// the source is a measured spot.
    pub fn from_source(
        src: &TifSource,
        spot: Option<&Surface>,
        dx_mm: f64,
        dy_mm: f64,
    ) -> Result<ToolModel, ProcessError> {
        Ok(match src {
            TifSource::Spot { dwell_s, .. } => {
                let s =
                    spot.ok_or_else(|| ProcessError::invalid("a measured TIF needs its spot map"))?;
                let m = MeasuredTif::from_spot(s, *dwell_s, &SpotOptions::default())?;
                ToolModel::Measured(Tif::sample(&m, dx_mm, dy_mm)?, Box::new(m))
            }
            TifSource::Gaussian(g) => {
                ToolModel::Gaussian(Tif::sample_antialiased(g, dx_mm, dy_mm)?, *g)
            }
            TifSource::Bonnet(p) => {
                let m = BonnetTif::new(p)?;
                // A footprint that falls to zero at its edge is point-sampled: that matches the
                // exact deposition at pixel centres; a hard edge (uniform pressure) is
                // anti-aliased so its area is right.
                let t = match p.pressure {
                    crate::tif::PressureProfile::Uniform => {
                        Tif::sample_antialiased(&m, dx_mm, dy_mm)?
                    }
                    _ => Tif::sample(&m, dx_mm, dy_mm)?,
                };
                ToolModel::Bonnet(t, Box::new(m))
            }
        })
    }

    /// The TIF sampled at the map pitch.
    pub fn sampled(&self) -> &Tif {
        match self {
            ToolModel::Sampled(t)
            | ToolModel::Measured(t, _)
            | ToolModel::Gaussian(t, _)
            | ToolModel::Bonnet(t, _) => t,
        }
    }

    /// The fast-removal workspace on `grid`: a model's motion kernels come from the model
    /// itself (exact point values and one-pixel averages, see [`crate::tif::motion`]), a
    /// measured TIF's from its bilinear interpolant; either way they match what exact
    /// deposition evaluates.
    pub fn fast_removal(&self, grid: &Grid) -> Result<FastRemoval, ProcessError> {
        match self {
            ToolModel::Sampled(t) => FastRemoval::new(t, grid),
            ToolModel::Measured(_, m) => FastRemoval::from_field(m.as_ref(), grid),
            ToolModel::Gaussian(_, g) => FastRemoval::from_field(g, grid),
            ToolModel::Bonnet(_, b) => FastRemoval::from_field(b.as_ref(), grid),
        }
    }

    /// The continuous field (analytic for models, bilinear for a measured TIF).
    pub fn field(&self) -> &dyn RateField {
        match self {
            ToolModel::Sampled(t) => t,
            ToolModel::Measured(_, m) => m.as_ref(),
            ToolModel::Gaussian(_, g) => g,
            ToolModel::Bonnet(_, b) => b.as_ref(),
        }
    }
}

/// The tool model is the rate field it holds (so it can be shared as one).
impl RateField for ToolModel {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.field().rate_at_mm(dx_mm, dy_mm)
    }
    fn half_extent_mm(&self) -> (f64, f64) {
        self.field().half_extent_mm()
    }
    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        self.field().volume_rate_nm_mm2_per_s()
    }
}

/// A predicted run.
#[derive(Debug, Clone)]
pub struct Prediction {
    /// Removal (nm) on the before map's grid and mask.
    pub removal: Surface,
    /// Predicted after map = before - removal.
    pub after: Surface,
}

/// Removal (nm) of a path on a grid.
pub fn removal(
    tool: &ToolModel,
    path: &PathLog,
    grid: &Grid,
    weights: Option<&[f64]>,
    mode: Mode,
) -> Result<Array2<f64>, ProcessError> {
    match mode {
        Mode::Fast => tool.fast_removal(grid)?.removal(path, weights),
        Mode::Exact => deposit_exact(path, tool.field(), grid, weights, &ExactOptions::default()),
    }
}

/// Predicts the after map of a run from its before map.
pub fn predict(
    before: &Surface,
    tool: &ToolModel,
    path: &PathLog,
    weights: Option<&[f64]>,
    mode: Mode,
) -> Result<Prediction, ProcessError> {
    let grid = Grid::of(before)?;
    let r = removal(tool, path, &grid, weights, mode)?;
    let removal = before.with_heights(r.clone())?;
    let after = before.with_heights(before.heights_nm() - &r)?;
    let mut removal = removal;
    removal.removed.clear();
    removal.provenance.format = "synthetic".into();
    removal.provenance.comment = Some("predicted removal (nm, positive = removed)".into());
    let mut after = after;
    after.provenance.format = "synthetic".into();
    after.provenance.comment = Some("predicted after map".into());
    Ok(Prediction { removal, after })
}
