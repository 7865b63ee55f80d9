//! The forward model's linearisation channels on one map grid, for the calibration's fits and
//! the vibration coupling: the removal of a path (with per-sample rate weights) through the
//! TIF widened by a factor `s`, through its derivatives along x and y and in `s`, and the
//! matched filter (the adjoint) of each.
//!
//! Every channel is a [`FastRemoval`] of a [`Derived`] field of the run's one TIF, so a column
//! built here has the same motion kernels, line phases and splatting as the removal `simulate`
//! predicts; nothing is sampled or convolved a second way. Workspaces are built on first use.

use std::sync::Arc;

use ndarray::{s, Array2};

use crate::error::ProcessError;
use crate::fft::Convolver;
use crate::grid::Grid;
use crate::interp::bilinear;
use crate::path::PathLog;
use crate::removal::FastRemoval;
use crate::tif::derived::{Channel, Derived};
use crate::tif::{RateField, Tif};

const CHANNELS: [Channel; 4] = [Channel::Value, Channel::Dx, Channel::Dy, Channel::Ds];

fn slot(c: Channel) -> usize {
    match c {
        Channel::Value => 0,
        Channel::Dx => 1,
        Channel::Dy => 2,
        Channel::Ds => 3,
    }
}

/// Removal workspaces of the channels of one TIF at one widening on one grid.
pub struct Channels {
    base: Arc<dyn RateField + Send>,
    grid: Grid,
    scale: f64,
    step_mm: f64,
    fast: [Option<FastRemoval>; 4],
    adjoint: [Option<Adjoint>; 4],
}

/// Correlation of a map with a channel's point-sampled kernel, on the grown grid.
struct Adjoint {
    conv: Convolver,
    ext: Grid,
    offset: (usize, usize),
}

impl std::fmt::Debug for Channels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Channels({:?}, scale {})", self.grid, self.scale)
    }
}

impl Channels {
    /// Channels of `base` widened by `scale` (> 0) on `grid`.
    pub fn new(
        base: Arc<dyn RateField + Send>,
        grid: &Grid,
        scale: f64,
    ) -> Result<Channels, ProcessError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(ProcessError::invalid(format!(
                "TIF scale must be positive, got {scale}"
            )));
        }
        let mut c = Channels {
            base,
            grid: *grid,
            scale,
            // A tenth of a pixel: the kernels sample the derivative, not a pixel difference.
            step_mm: 0.1 * grid.dx_mm.min(grid.dy_mm),
            fast: [None, None, None, None],
            adjoint: [None, None, None, None],
        };
        c.workspace(Channel::Value)?;
        Ok(c)
    }

    /// The widening factor.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    fn field(&self, ch: Channel) -> Derived {
        let step = match ch {
            Channel::Ds => 1e-3,
            _ => self.step_mm,
        };
        Derived::new(self.base.clone(), self.scale, ch, step)
    }

    fn workspace(&mut self, ch: Channel) -> Result<&mut FastRemoval, ProcessError> {
        let k = slot(ch);
        if self.fast[k].is_none() {
            self.fast[k] = Some(FastRemoval::from_field(&self.field(ch), &self.grid)?);
        }
        Ok(self.fast[k].as_mut().expect("built above"))
    }

    /// Removal (nm, or nm per unit of the channel's variable) on the grid of `path` with
    /// optional per-sample rate weights, through channel `ch`.
    pub fn removal(
        &mut self,
        ch: Channel,
        path: &PathLog,
        weights: Option<&[f64]>,
    ) -> Result<Array2<f64>, ProcessError> {
        self.workspace(ch)?.removal(path, weights)
    }

    /// Sum of several channels' removals of the same path, each with its own weights.
    pub fn removal_sum(
        &mut self,
        path: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Array2<f64>, ProcessError> {
        let mut out = Array2::zeros((self.grid.rows, self.grid.cols));
        for (ch, w) in terms {
            out += &self.removal(*ch, path, *w)?;
        }
        Ok(out)
    }

    /// Matched filter of a map on the grid (0 off its aperture) through channel `ch`: at every
    /// sample `k` of `path`, `sum_x r(x) K(x - p_k)` with the channel's point-sampled kernel,
    /// interpolated bilinearly between pixel positions (0 off the grown grid). It is the
    /// adjoint of resting dwell at the samples, the projection of `r` on a unit rate (or
    /// displacement) impulse there.
    pub fn matched(
        &mut self,
        ch: Channel,
        r: &Array2<f64>,
        path: &PathLog,
    ) -> Result<Vec<f64>, ProcessError> {
        if r.dim() != (self.grid.rows, self.grid.cols) {
            return Err(ProcessError::invalid(
                "matched filter map does not match the grid",
            ));
        }
        let k = slot(ch);
        if self.adjoint[k].is_none() {
            let ext = *self.workspace(Channel::Value)?.dwell_grid();
            let kern = Tif::sample(&self.field(ch), self.grid.dx_mm, self.grid.dy_mm)?;
            let offset = (
                ((self.grid.y0_mm - ext.y0_mm) / ext.dy_mm).round() as usize,
                ((self.grid.x0_mm - ext.x0_mm) / ext.dx_mm).round() as usize,
            );
            let conv = Convolver::new(ext.rows, ext.cols, kern.rate_nm_per_s.view());
            self.adjoint[k] = Some(Adjoint { conv, ext, offset });
        }
        let a = self.adjoint[k].as_mut().expect("built above");
        let mut big = Array2::zeros((a.ext.rows, a.ext.cols));
        let (o0, o1) = a.offset;
        big.slice_mut(s![o0..o0 + r.nrows(), o1..o1 + r.ncols()])
            .assign(r);
        let c = a.conv.apply_adjoint(big.view());
        Ok((0..path.len())
            .map(|i| {
                let (u, v) = a.ext.frac_index(path.x_mm[i], path.y_mm[i]);
                bilinear(&c, u, v)
            })
            .collect())
    }

    /// Builds every channel's workspace now (so later calls do not pay for it).
    pub fn build_all(&mut self) -> Result<(), ProcessError> {
        for ch in CHANNELS {
            self.workspace(ch)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::GaussianTif;

    fn setup() -> (Arc<dyn RateField + Send>, Grid, PathLog) {
        let g = Arc::new(GaussianTif::new(1.0, 8.0, 10.0).unwrap());
        let grid = Grid::new(60, 70, 0.25, 0.25, 0.0, 0.0).unwrap();
        // A raster of three lines along X at 2.1 mm pitch, 5 mm/s.
        let (mut t, mut x, mut y) = (vec![], vec![], vec![]);
        let mut time = 0.0;
        for line in 0..3 {
            let yy = 4.0 + 2.1 * line as f64;
            for k in 0..=80 {
                let xx = if line % 2 == 0 {
                    2.0 + 0.2 * k as f64
                } else {
                    18.0 - 0.2 * k as f64
                };
                t.push(time);
                x.push(xx);
                y.push(yy);
                time += 0.04;
            }
            time += 0.5;
        }
        (g, grid, PathLog::new(t, x, y).unwrap())
    }

    #[test]
    fn derivative_channels_are_the_removal_of_a_displaced_path() {
        let (g, grid, path) = setup();
        let mut c = Channels::new(g, &grid, 1.0).unwrap();
        let e = 0.01;
        let shift = |dx: f64, dy: f64| {
            PathLog::new(
                path.t_s.clone(),
                path.x_mm.iter().map(|v| v + dx).collect(),
                path.y_mm.iter().map(|v| v + dy).collect(),
            )
            .unwrap()
        };
        let r0 = c.removal(Channel::Value, &path, None).unwrap();
        let peak = r0.iter().cloned().fold(0.0, f64::max);
        for (ch, dx, dy) in [(Channel::Dx, e, 0.0), (Channel::Dy, 0.0, e)] {
            let rp = c.removal(Channel::Value, &shift(dx, dy), None).unwrap();
            let d = c.removal(ch, &path, None).unwrap();
            // R(p + e) - R(p) ~ -e dK/dx * D.
            let worst = rp
                .iter()
                .zip(r0.iter())
                .zip(d.iter())
                .map(|((a, b), k)| (a - b + e * k).abs())
                .fold(0.0, f64::max);
            assert!(worst < 2e-3 * peak, "{ch:?}: {worst} vs peak {peak}");
        }
        // Widening: R(s + ds) - R(s) ~ ds dR/ds.
        let ds = 1e-3;
        let mut c2 = Channels::new(c.base.clone(), &grid, 1.0 + ds).unwrap();
        let r1 = c2.removal(Channel::Value, &path, None).unwrap();
        let d = c.removal(Channel::Ds, &path, None).unwrap();
        let worst = r1
            .iter()
            .zip(r0.iter())
            .zip(d.iter())
            .map(|((a, b), k)| (a - b - ds * k).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2e-3 * peak * ds * 100.0, "{worst}");
    }

    #[test]
    fn matched_filter_is_the_adjoint_of_resting_dwell() {
        let (g, grid, _) = setup();
        let mut c = Channels::new(g.clone(), &grid, 1.0).unwrap();
        // A tool resting at pixel centres: <R(dwell), r> = sum_k dwell_k h_k.
        let pts = [(5.0, 5.0), (10.25, 7.5), (3.0, 12.0)];
        let r = Array2::from_shape_fn((60, 70), |(i, j)| ((i * 7 + j * 3) % 11) as f64 - 5.0);
        let t: Vec<f64> = (0..pts.len()).map(|k| k as f64).collect();
        let path = PathLog::new(
            t,
            pts.iter().map(|p| p.0).collect(),
            pts.iter().map(|p| p.1).collect(),
        )
        .unwrap();
        let h = c.matched(Channel::Value, &r, &path).unwrap();
        for (k, (x, y)) in pts.iter().enumerate() {
            let mut direct = 0.0;
            for ((i, j), v) in r.indexed_iter() {
                direct += v * g.rate_at_mm(grid.x_mm(j) - x, grid.y_mm(i) - y);
            }
            assert!(
                (h[k] - direct).abs() < 1e-9 * direct.abs().max(1.0),
                "{k}: {} vs {direct}",
                h[k]
            );
        }
    }
}
