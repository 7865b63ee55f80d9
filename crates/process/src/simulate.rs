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
use crate::pixel::{PixelMean, PixelResponse, PixelSampling};
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

/// A TIF's shape: sampled at the map pitch, and the field exact deposition uses.
pub enum ToolShape {
    Sampled(Tif),
    /// A measured spot: the field at the spot's own pixel, and its samples at the map pitch.
    Measured(Tif, Box<MeasuredTif>),
    Gaussian(Tif, crate::tif::GaussianTif),
    Bonnet(Tif, Box<BonnetTif>),
}

/// A TIF ready for simulation: its shape, and how the maps' pixels see the removal it makes
/// (point samples, or means over the pixel's area as a camera's are). Every removal built from
/// it (the fast model, exact deposition through [`ToolModel::seen_field`], the vibration
/// coupling's kernels) is what such pixels read; [`ToolModel::field`] is the TIF itself.
pub struct ToolModel {
    shape: ToolShape,
    seen: PixelResponse,
}

impl From<ToolShape> for ToolModel {
    /// A tool seen by point samples.
    fn from(shape: ToolShape) -> ToolModel {
        ToolModel {
            shape,
            seen: PixelResponse::Point,
        }
    }
}

/// Most pixels a TIF footprint may cover at the map pitch (1001 x 1001, 8 MB per copy: a 50 mm
/// bonnet at 0.05 mm pixels). The pipelines hold several copies (sampled, anti-aliased, three
/// motion kernels averaged over sub-samples) and transform the map grown by the footprint:
/// measured on this machine, a 1991 x 1991 footprint took `simulate` 15 s and 330 MB, a
/// 9001 x 9001 one (a model of metres) aborted at 1 GiB, and a spot map whose pixel size is
/// wrong by 100x ran for minutes.
pub const MAX_TIF_PIXELS: f64 = 1001.0 * 1001.0;

fn sig4(v: f64) -> String {
    bonnetlab_surface::format::sig(v, 4)
}

/// Refuses, before anything is sampled, a footprint of more than [`MAX_TIF_PIXELS`] at pixel
/// (dx, dy) mm.
pub fn check_footprint(field: &dyn RateField, dx_mm: f64, dy_mm: f64) -> Result<(), ProcessError> {
    let (ex, ey) = field.half_extent_mm();
    let (w, h) = (
        2.0 * (ex / dx_mm + 1e-9).floor() + 1.0,
        2.0 * (ey / dy_mm + 1e-9).floor() + 1.0,
    );
    // NaN (a non-finite extent) fails this test too.
    let fits = w * h <= MAX_TIF_PIXELS;
    if !fits {
        return Err(ProcessError::invalid(format!(
            "the TIF footprint ({} x {} mm) covers {} x {} pixels of the map ({} x {} mm), \
             over the limit of 1001 x 1001 pixels: check the spot map's pixel size or the \
             model's size",
            sig4(2.0 * ex),
            sig4(2.0 * ey),
            sig4(w),
            sig4(h),
            sig4(dx_mm),
            sig4(dy_mm),
        )));
    }
    Ok(())
}

impl ToolModel {
    /// Builds the TIF of a recipe's `[tif]` at pixel (dx, dy); `spot` must be the spot map when
    /// the source is a measured spot. A footprint over [`MAX_TIF_PIXELS`] at that pixel is
    /// refused before it is sampled.
    pub fn from_source(
        src: &TifSource,
        spot: Option<&Surface>,
        dx_mm: f64,
        dy_mm: f64,
    ) -> Result<ToolModel, ProcessError> {
        ToolModel::from_source_seen(src, spot, dx_mm, dy_mm, PixelSampling::Point)
    }

    /// [`Self::from_source`] for maps of pixel (dx, dy) and a spot map whose pixels sample the
    /// removal as `pixels` says (one instrument): the spot is read that way
    /// ([`SpotOptions::pixels`]) and the tool's removal is predicted that way
    /// ([`Self::response`]).
    pub fn from_source_seen(
        src: &TifSource,
        spot: Option<&Surface>,
        dx_mm: f64,
        dy_mm: f64,
        pixels: PixelSampling,
    ) -> Result<ToolModel, ProcessError> {
        let shape = match src {
            TifSource::Spot { dwell_s, .. } => {
                let s =
                    spot.ok_or_else(|| ProcessError::invalid("a measured TIF needs its spot map"))?;
                let o = SpotOptions {
                    pixels,
                    ..SpotOptions::default()
                };
                let m = MeasuredTif::from_spot(s, *dwell_s, &o)?;
                check_footprint(&m, dx_mm, dy_mm)?;
                ToolShape::Measured(Tif::sample(&m, dx_mm, dy_mm)?, Box::new(m))
            }
            TifSource::Gaussian(g) => {
                check_footprint(g, dx_mm, dy_mm)?;
                ToolShape::Gaussian(Tif::sample_antialiased(g, dx_mm, dy_mm)?, *g)
            }
            TifSource::Bonnet(p) => {
                let m = BonnetTif::new(p)?;
                check_footprint(&m, dx_mm, dy_mm)?;
                // A footprint that falls to zero at its edge is point-sampled: that matches the
                // exact deposition at pixel centres; a hard edge (uniform pressure) is
                // anti-aliased so its area is right.
                let t = match p.pressure {
                    crate::tif::PressureProfile::Uniform => {
                        Tif::sample_antialiased(&m, dx_mm, dy_mm)?
                    }
                    _ => Tif::sample(&m, dx_mm, dy_mm)?,
                };
                ToolShape::Bonnet(t, Box::new(m))
            }
        };
        Ok(ToolModel {
            shape,
            seen: pixels.response(dx_mm, dy_mm),
        })
    }

    /// The same tool seen by pixels of `response` (the shape is kept as it was read).
    pub fn seen_by(self, response: PixelResponse) -> ToolModel {
        ToolModel {
            shape: self.shape,
            seen: response,
        }
    }

    /// How the maps' pixels see the removal (point samples unless a recipe says `area`).
    pub fn response(&self) -> PixelResponse {
        self.seen
    }

    /// The TIF's shape.
    pub fn shape(&self) -> &ToolShape {
        &self.shape
    }

    /// The TIF sampled at the map pitch.
    pub fn sampled(&self) -> &Tif {
        match &self.shape {
            ToolShape::Sampled(t)
            | ToolShape::Measured(t, _)
            | ToolShape::Gaussian(t, _)
            | ToolShape::Bonnet(t, _) => t,
        }
    }

    /// The fast-removal workspace on `grid`: a model's motion kernels come from the model
    /// itself (exact point values and one-pixel averages, see [`crate::tif::motion`]), a
    /// measured TIF's from its bilinear interpolant; either way they match what exact
    /// deposition of [`Self::seen_field`] evaluates. With area pixels every kernel is built
    /// from the field's pixel means ([`FastRemoval::from_field_seen`]).
    pub fn fast_removal(&self, grid: &Grid) -> Result<FastRemoval, ProcessError> {
        let r = self.seen;
        match &self.shape {
            ToolShape::Sampled(t) if r.is_point() => FastRemoval::new(t, grid),
            ToolShape::Sampled(t) => FastRemoval::from_field_seen(t, grid, r),
            ToolShape::Measured(_, m) => FastRemoval::from_field_seen(m.as_ref(), grid, r),
            ToolShape::Gaussian(_, g) => FastRemoval::from_field_seen(g, grid, r),
            ToolShape::Bonnet(_, b) => FastRemoval::from_field_seen(b.as_ref(), grid, r),
        }
    }

    /// The continuous field (analytic for models, bilinear for a measured TIF): the TIF itself.
    pub fn field(&self) -> &dyn RateField {
        match &self.shape {
            ToolShape::Sampled(t) => t,
            ToolShape::Measured(_, m) => m.as_ref(),
            ToolShape::Gaussian(_, g) => g,
            ToolShape::Bonnet(_, b) => b.as_ref(),
        }
    }

    /// The field as the maps' pixels see it: its pixel mean ([`PixelMean`]; the field itself
    /// for point samples). Exact deposition of this field is the removal those pixels read.
    pub fn seen_field(&self) -> PixelMean<&dyn RateField> {
        PixelMean::new(self.field(), self.seen)
    }
}

/// The tool model is the rate field it holds (so it can be shared as one): the TIF itself,
/// not its pixel means.
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
    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        self.field().rates_along(along_x, c, t, out)
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
        Mode::Exact => deposit_exact(
            path,
            &tool.seen_field(),
            grid,
            weights,
            &ExactOptions::default(),
        ),
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

#[cfg(test)]
mod footprint_tests {
    use super::*;
    use crate::tif::GaussianTif;

    fn gaussian(diameter_mm: f64) -> TifSource {
        TifSource::Gaussian(GaussianTif::new(diameter_mm / 6.0, diameter_mm, 10.0).unwrap())
    }

    /// Issue #18: a footprint of metres at a 1 mm pixel (9001 x 9001 pixels) used 1.5 GB and
    /// over a minute in `simulate`; it is refused before sampling, with the sizes. The bound is
    /// exact: 1001 x 1001 pixels pass, 1003 x 1003 do not.
    #[test]
    fn a_footprint_over_the_pixel_budget_is_refused_before_sampling() {
        let e = ToolModel::from_source(&gaussian(9000.0), None, 1.0, 1.0)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("the TIF footprint (9000 x 9000 mm)"), "{e}");
        assert!(e.contains("9001 x 9001 pixels"), "{e}");
        assert!(!e.contains('\n'), "{e}");
        assert!(ToolModel::from_source(&gaussian(1000.0), None, 1.0, 1.0).is_ok());
        assert!(ToolModel::from_source(&gaussian(1002.0), None, 1.0, 1.0).is_err());
        // An ordinary tool at a fine pixel is untouched.
        assert!(ToolModel::from_source(&gaussian(20.0), None, 0.05, 0.05).is_ok());
    }
}
