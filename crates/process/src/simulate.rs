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

/// Removal (nm) of a path (a log, read with its sampled corners restored:
/// [`PathLog::with_corners`], as calibration and the vibration coupling read it) on a grid.
/// `weights` are per sample of `path` (linear in time between samples).
pub fn removal(
    tool: &ToolModel,
    path: &PathLog,
    grid: &Grid,
    weights: Option<&[f64]>,
    mode: Mode,
) -> Result<Array2<f64>, ProcessError> {
    crate::removal::check_weights(path, weights)?;
    let motion = path.with_corners();
    let weights = weights.map(|w| path.values_at(w, &motion.t_s));
    let weights = weights.as_deref();
    match mode {
        Mode::Fast => tool.fast_removal(grid)?.removal(&motion, weights),
        Mode::Exact => deposit_exact(
            &motion,
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

#[cfg(test)]
mod log_reading_tests {
    use super::*;
    use crate::tif::GaussianTif;

    /// A bidirectional raster: 20 mm lines at 5 mm/s, 2 mm pitch steps at 2 mm/s. Its vertices
    /// (t, x, y).
    fn raster_vertices() -> Vec<(f64, f64, f64)> {
        let mut v = vec![(0.0, 0.0, 0.0)];
        for k in 0..4 {
            let (t, _, y) = *v.last().unwrap();
            let xe = if k % 2 == 0 { 20.0 } else { 0.0 };
            v.push((t + 4.0, xe, y));
            if k < 3 {
                v.push((t + 5.0, xe, y + 2.0));
            }
        }
        v
    }

    fn motion_at(v: &[(f64, f64, f64)], t: f64) -> (f64, f64) {
        let k = v.iter().rposition(|p| p.0 <= t).unwrap().min(v.len() - 2);
        let (a, b) = (v[k], v[k + 1]);
        let f = ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0);
        (a.1 + f * (b.1 - a.1), a.2 + f * (b.2 - a.2))
    }

    /// `simulate` reads a log with the corners its samples cut restored: a 10 Hz log of a
    /// raster whose samples miss every turn gives the removal of the motion itself (exact
    /// deposition of the motion sampled on its corners), where the chords would not; and a
    /// rate weight given per log sample follows.
    #[test]
    fn a_sparse_log_is_read_as_the_motion_it_sampled() {
        let v = raster_vertices();
        let end = v.last().unwrap().0;
        let ts: Vec<f64> = (0..)
            .map(|k| 0.037 + 0.1 * k as f64)
            .take_while(|&t| t < end)
            .collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = ts.iter().map(|&t| motion_at(&v, t)).unzip();
        let log = PathLog::new(ts.clone(), xs, ys).unwrap();
        // The truth: the motion's own vertices and samples between them, on the log's span.
        let mut tt: Vec<f64> = (0..=((end / 0.01) as usize))
            .map(|k| k as f64 * 0.01)
            .chain(v.iter().map(|p| p.0))
            .filter(|&t| t >= ts[0] && t <= *ts.last().unwrap())
            .chain([ts[0], *ts.last().unwrap()])
            .collect();
        tt.sort_by(f64::total_cmp);
        tt.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        let (mx, my): (Vec<f64>, Vec<f64>) = tt.iter().map(|&t| motion_at(&v, t)).unzip();
        let motion = PathLog::new(tt.clone(), mx, my).unwrap();

        let src = TifSource::Gaussian(GaussianTif::new(1.0, 6.0, 10.0).unwrap());
        let tool = ToolModel::from_source(&src, None, 0.25, 0.25).unwrap();
        let grid = Grid::new(72, 120, 0.25, 0.25, -5.0, -5.0).unwrap();
        let exact = |p: &PathLog, w: Option<&[f64]>| {
            deposit_exact(p, &tool.seen_field(), &grid, w, &ExactOptions::default()).unwrap()
        };
        let truth = exact(&motion, None);
        let peak = truth.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let worst = |a: &Array2<f64>, b: &Array2<f64>| {
            (a - b).iter().fold(0.0f64, |m, v| m.max(v.abs())) / peak
        };
        let read = removal(&tool, &log, &grid, None, Mode::Exact).unwrap();
        let chords = exact(&log, None);
        let (e_read, e_chords) = (worst(&read, &truth), worst(&chords, &truth));
        let fine = ExactOptions {
            max_step_mm: Some(0.004),
            ..ExactOptions::default()
        };
        let fine_walk =
            |p: &PathLog| deposit_exact(p, &tool.seen_field(), &grid, None, &fine).unwrap();
        // Walked at 4 um the restored log is the motion to 3e-5 of the peak.
        let e_fine = worst(&fine_walk(&log.with_corners()), &fine_walk(&motion));
        assert!(e_fine < 1e-4, "fine walk {e_fine}");
        eprintln!("read {e_read:.3e}, chords {e_chords:.3e} of the peak");
        assert!(e_chords > 0.003, "chords {e_chords}");
        // What is left at the default walk is its own sub-step error (midpoints 1/16 mm apart
        // on different segments: about 3e-4 of the peak; see the finer walk above).
        assert!(
            e_read < 5e-4 && e_read < 0.1 * e_chords,
            "read {e_read} (chords {e_chords})"
        );
        // The fast model reads it the same way.
        let fast = removal(&tool, &log, &grid, None, Mode::Fast).unwrap();
        let fast_truth = removal(&tool, &motion, &grid, None, Mode::Fast).unwrap();
        assert!(
            worst(&fast, &fast_truth) < 1e-3,
            "{}",
            worst(&fast, &fast_truth)
        );
        // A weight linear in time, given per log sample, is the motion's weight at its times.
        let w = |t: &f64| 1.0 + 0.02 * t;
        let wl: Vec<f64> = ts.iter().map(w).collect();
        let wm: Vec<f64> = tt.iter().map(w).collect();
        let read_w = removal(&tool, &log, &grid, Some(&wl), Mode::Exact).unwrap();
        let truth_w = exact(&motion, Some(&wm));
        assert!(
            worst(&read_w, &truth_w) < 1e-3,
            "{}",
            worst(&read_w, &truth_w)
        );
        assert!(worst(&read_w, &read) > 0.01);
        // Weights that do not match the log are refused.
        assert!(removal(&tool, &log, &grid, Some(&wl[1..]), Mode::Fast).is_err());
    }
}
