//! The forward model's linearisation channels on one map grid, for the calibration's fits and
//! the vibration coupling: the removal of a path (with per-sample rate weights) through the
//! TIF widened by a factor `s`, through its derivatives along x and y and in `s`, and the
//! matched filter (the adjoint) of each.
//!
//! Every channel is a [`FastRemoval`] of a [`Derived`] field of the run's one TIF, so a column
//! built here has the same motion kernels, line phases and splatting as the removal `simulate`
//! predicts; nothing is sampled or convolved a second way. Workspaces are built on first use.

use std::sync::{Arc, Mutex, MutexGuard};

use ndarray::{s, Array2};

use crate::error::ProcessError;
use crate::fft::{fast_len, Convolver};
use crate::grid::Grid;
use crate::interp::bilinear;
use crate::path::PathLog;
use crate::pixel::{PixelMean, PixelResponse};
use crate::removal::{FastRemoval, Fidelity, SharedSpectra};
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

/// Removal workspaces of the channels of one TIF at one widening on one grid. Callers may share
/// it across threads: a call takes an idle workspace of its channel or builds one (never
/// waiting for another caller's), and the channel's workspaces share the kernel spectra they
/// build. As many idle ones are kept as there are threads where a grid's transforms run on one
/// thread, one where they use every thread. A removal's bits do not depend on which workspace
/// made it, or on what that workspace made before (its kernels are summed in the order of the
/// path's targets, not of the slots they took).
pub struct Channels {
    base: Arc<dyn RateField + Send>,
    grid: Grid,
    scale: f64,
    step_mm: f64,
    fast: [Pool; 4],
    /// Idle matched-filter convolvers per channel (taken like the workspaces).
    adjoint: [Mutex<Vec<Adjoint>>; 4],
    /// How the map's pixels see the removal (every channel's kernels, on any grid).
    response: PixelResponse,
    /// The derivative channels' screening companion (see [`Self::screening_grid`]), built on
    /// first use; `None` where the map pixel is not fine against the footprint.
    coarse: std::sync::OnceLock<Option<Box<Channels>>>,
}

/// Coarse-pixel screening: the derivative channels' screening columns are computed on a grid
/// this many pixels per footprint radius (at least) and interpolated bilinearly onto the map.
/// The validation harness's spot (6.2 mm footprint radius) is then screened at 0.25 mm on an
/// 800^2 map of a 100 mm part (0.125 mm pixels, a quarter of the transform), and computed in
/// full on a 400^2 or 500^2 map; the paper's bonnet (4.86 mm) at 0.2 mm on a 0.1 mm map. What a
/// screening column is for is a residual's projection on it, and that survives: on the
/// paper's bonnet at 0.1 mm (test
/// `derivative_columns_screen_on_a_coarser_grid_where_the_pixel_is_fine`) the full column's
/// projection on the coarse one keeps 96.5-99.7 % of its energy at a coefficient of
/// 0.975-1.000, while point by point the columns differ by 5-19 % (the rim's steep slope, which
/// the coarse grid does not resolve). The value channel is never screened this way: its
/// screening columns are a raster's full ones, which the fits reuse.
pub const SCREENING_PIXELS_PER_RADIUS: f64 = 20.0;

/// Largest factor between the map pixel and the screening pixel.
const MAX_SCREENING_FACTOR: usize = 4;

/// Rates below this fraction of the peak are outside the footprint (see
/// [`footprint_radius_mm`]).
const FOOTPRINT_FRACTION: f64 = 1e-2;

/// The footprint's radius (mm): the farthest point from the tool centre, sampled every
/// `step_mm`, where the rate is at least [`FOOTPRINT_FRACTION`] of its peak. Not the field's
/// half-extent, which for a measured spot is the measurement's window (a 10 mm spot measured
/// on a 30 mm window would otherwise be screened at three times too coarse a pixel). The
/// paper's bonnet: its 4.86 mm contact radius; a Gaussian: 3.03 sigma.
pub fn footprint_radius_mm(field: &dyn RateField, step_mm: f64) -> Option<f64> {
    let k = Tif::sample(field, step_mm, step_mm).ok()?;
    let r = &k.rate_nm_per_s;
    let peak = r.iter().fold(0.0f64, |a, &v| a.max(v));
    if !(peak > 0.0 && peak.is_finite()) {
        return None;
    }
    let (c0, c1) = (r.nrows() / 2, r.ncols() / 2);
    let far = r
        .indexed_iter()
        .filter(|(_, &v)| v >= FOOTPRINT_FRACTION * peak)
        .map(|((i, j), _)| (i as f64 - c0 as f64).hypot(j as f64 - c1 as f64))
        .fold(0.0f64, f64::max);
    Some(far * step_mm)
}

/// Most memory a [`ScaleScan`]'s transformed dwell may take (bytes); beyond it the scan is
/// refused (an error) and the caller evaluates each scale in full instead. At 800^2 a spectrum
/// is about 6.5 MB and a raster's term holds a few (one per line phase), so this is tens of
/// rate terms (a rate map's knots) there.
pub const SCALE_SCAN_BYTES: usize = 512 << 20;

/// Removals through the value channel at many widenings of one TIF, for a scan of the TIF
/// scale: the dwell of each term (path, rate weights) is walked, splatted and transformed
/// once, at the support of the widest scale, and each scale then costs its kernels'
/// transforms and an inverse transform per term (see [`crate::removal::DwellSpectra`]). Each
/// removal equals [`Channels::removal`] of a [`Channels`] at that scale up to rounding (the
/// line phases are found on the widest scale's grown grid: a phase exactly at a bin's edge
/// may fall the other way).
pub struct ScaleScan {
    base: Arc<dyn RateField + Send>,
    step_mm: f64,
    max_scale: f64,
    spectra: crate::removal::DwellSpectra,
}

impl std::fmt::Debug for ScaleScan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ScaleScan(up to {}, {:?})", self.max_scale, self.spectra)
    }
}

impl ScaleScan {
    /// The scan of `terms` on `grid` for widenings up to `max_scale` (> 0), for maps whose
    /// pixels sample the removal as `response` says.
    pub fn new(
        base: Arc<dyn RateField + Send>,
        grid: &Grid,
        max_scale: f64,
        terms: &[(&PathLog, Option<&[f64]>)],
        response: PixelResponse,
    ) -> Result<ScaleScan, ProcessError> {
        positive_scale(max_scale)?;
        let step_mm = 0.1 * grid.dx_mm.min(grid.dy_mm);
        let widest = Derived::new(base.clone(), max_scale, Channel::Value, step_mm);
        let mut w = FastRemoval::from_field_seen(&widest, grid, response)?;
        let spectra = w.dwell_spectra(terms, SCALE_SCAN_BYTES)?;
        Ok(ScaleScan {
            base,
            step_mm,
            max_scale,
            spectra,
        })
    }

    /// The removal (nm) of every term, in order, through the TIF widened by `scale` (in
    /// `(0, max_scale]`).
    pub fn removals(&self, scale: f64) -> Result<Vec<Array2<f64>>, ProcessError> {
        if !(scale.is_finite() && scale > 0.0 && scale <= self.max_scale) {
            return Err(ProcessError::invalid(format!(
                "TIF scale {scale} outside the scan's (0, {}]",
                self.max_scale
            )));
        }
        let field = Derived::new(self.base.clone(), scale, Channel::Value, self.step_mm);
        self.spectra.removals(&field)
    }
}

/// An error unless a TIF widening is finite and positive.
fn positive_scale(scale: f64) -> Result<(), ProcessError> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(ProcessError::invalid(format!(
            "TIF scale must be positive, got {scale}"
        )))
    }
}

/// A channel's workspaces: the idle ones and how many to keep.
#[derive(Default)]
struct Pool {
    state: Mutex<PoolState>,
    /// The kernels its workspaces built, for the others.
    spectra: SharedSpectra,
}

#[derive(Default)]
struct PoolState {
    idle: Vec<FastRemoval>,
    /// Most idle workspaces kept: where a workspace's transforms run in parallel, as many as
    /// callers have held at once (up to the number of threads); else the number of threads.
    keep: usize,
    /// Workspaces lent now.
    lent: usize,
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
    /// Channels of `base` widened by `scale` (> 0) on `grid`, for maps of point samples.
    pub fn new(
        base: Arc<dyn RateField + Send>,
        grid: &Grid,
        scale: f64,
    ) -> Result<Channels, ProcessError> {
        Channels::seen(base, grid, scale, PixelResponse::Point)
    }

    /// [`Self::new`] for maps whose pixels sample the removal as `response` says.
    pub fn seen(
        base: Arc<dyn RateField + Send>,
        grid: &Grid,
        scale: f64,
        response: PixelResponse,
    ) -> Result<Channels, ProcessError> {
        positive_scale(scale)?;
        let c = Channels {
            base,
            grid: *grid,
            scale,
            // A tenth of a pixel: the kernels sample the derivative, not a pixel difference.
            step_mm: 0.1 * grid.dx_mm.min(grid.dy_mm),
            fast: Default::default(),
            adjoint: Default::default(),
            coarse: Default::default(),
            response,
        };
        drop(c.workspace(Channel::Value)?);
        Ok(c)
    }

    /// The grid the derivative channels' screening columns are computed on, when it is coarser
    /// than the map's: pixels `b` times the map's, with `b` the largest integer (at most 4)
    /// that keeps [`SCREENING_PIXELS_PER_RADIUS`] pixels across the widened footprint's radius
    /// (see [`footprint_radius_mm`]), and one coarse pixel beyond the map on every side (so
    /// every map pixel centre is interpolated between four coarse ones). `None` when `b` is 1.
    pub fn screening_grid(&self) -> Option<Grid> {
        let pix = self.grid.dx_mm.max(self.grid.dy_mm);
        let radius = footprint_radius_mm(&self.field(Channel::Value), 0.25 * pix)?;
        let b = (radius / (SCREENING_PIXELS_PER_RADIUS * pix)).floor();
        if b.is_nan() || b < 2.0 {
            return None;
        }
        let b = (b as usize).min(MAX_SCREENING_FACTOR);
        let g = &self.grid;
        let (dx, dy) = (b as f64 * g.dx_mm, b as f64 * g.dy_mm);
        Grid::new(
            (g.rows - 1).div_ceil(b) + 3,
            (g.cols - 1).div_ceil(b) + 3,
            dx,
            dy,
            g.x0_mm - dx,
            g.y0_mm - dy,
        )
        .ok()
    }

    /// The screening companion on [`Self::screening_grid`], if there is one.
    fn coarse(&self) -> Option<&Channels> {
        self.coarse
            .get_or_init(|| {
                let grid = self.screening_grid()?;
                Channels::seen(self.base.clone(), &grid, self.scale, self.response)
                    .ok()
                    .map(Box::new)
            })
            .as_deref()
    }

    /// Where this grid's pixel centres fall on the companion's grid: per row and per column,
    /// the lower coarse index and the fraction towards the next.
    fn on_coarse(&self, coarse: &Grid) -> [Vec<(usize, f64)>; 2] {
        let at = |n: usize, o: f64, d: f64, o_c: f64, d_c: f64, len_c: usize| {
            (0..n)
                .map(|i| {
                    let u = (o + i as f64 * d - o_c) / d_c;
                    let i0 = (u.floor().max(0.0) as usize).min(len_c.saturating_sub(2));
                    (i0, (u - i0 as f64).clamp(0.0, 1.0))
                })
                .collect::<Vec<_>>()
        };
        let g = &self.grid;
        [
            at(
                g.rows,
                g.y0_mm,
                g.dy_mm,
                coarse.y0_mm,
                coarse.dy_mm,
                coarse.rows,
            ),
            at(
                g.cols,
                g.x0_mm,
                g.dx_mm,
                coarse.x0_mm,
                coarse.dx_mm,
                coarse.cols,
            ),
        ]
    }

    /// `m` on the companion's grid interpolated bilinearly at this grid's pixel centres.
    fn refine_to_grid(&self, coarse: &Grid, m: &Array2<f64>) -> Array2<f64> {
        let [rows, cols] = self.on_coarse(coarse);
        let mut out = Array2::zeros((self.grid.rows, self.grid.cols));
        for (mut row, &(i0, fu)) in out.rows_mut().into_iter().zip(&rows) {
            let (a, b) = (m.row(i0), m.row(i0 + 1));
            for (o, &(j0, fv)) in row.iter_mut().zip(&cols) {
                let top = a[j0] + fv * (a[j0 + 1] - a[j0]);
                let bot = b[j0] + fv * (b[j0 + 1] - b[j0]);
                *o = top + fu * (bot - top);
            }
        }
        out
    }

    /// The adjoint of [`Self::refine_to_grid`]: each pixel of `r` spread onto the four coarse
    /// pixels it is interpolated from, with the same weights (so a matched filter of the
    /// spread map on the coarse grid is the matched filter of `r` through the interpolation).
    fn spread_to_coarse(&self, coarse: &Grid, r: &Array2<f64>) -> Array2<f64> {
        let [rows, cols] = self.on_coarse(coarse);
        let mut out = Array2::zeros((coarse.rows, coarse.cols));
        for (row, &(i0, fu)) in r.rows().into_iter().zip(&rows) {
            for (&v, &(j0, fv)) in row.iter().zip(&cols) {
                let (top, bot) = ((1.0 - fu) * v, fu * v);
                out[(i0, j0)] += (1.0 - fv) * top;
                out[(i0, j0 + 1)] += fv * top;
                out[(i0 + 1, j0)] += (1.0 - fv) * bot;
                out[(i0 + 1, j0 + 1)] += fv * bot;
            }
        }
        out
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

    /// A workspace of the channel, for this caller alone until it is dropped: an idle one,
    /// else a new one. A caller never waits for another's: a thread that holds a workspace
    /// while its transforms run in parallel may take up another task of the same calibration
    /// that asks for one (waiting would then wait for itself).
    fn workspace(&self, ch: Channel) -> Result<Workspace<'_>, ProcessError> {
        let pool = &self.fast[slot(ch)];
        {
            let mut st = lock(&pool.state)?;
            if let Some(w) = st.idle.pop() {
                st.lent += 1;
                return Ok(Workspace { pool, w: Some(w) });
            }
        }
        let mut w = FastRemoval::from_field_seen(&self.field(ch), &self.grid, self.response)?;
        w.share_spectra(pool.spectra.clone());
        let mut st = lock(&pool.state)?;
        st.lent += 1;
        let most = rayon::current_num_threads().clamp(1, MAX_WORKSPACES);
        // A workspace whose transforms use the pool serves one caller at a time well, so one
        // is kept until callers have held more at once: then as many as they held. Keeping
        // one only, a calibration whose candidates ask for columns side by side dropped the
        // second (tens of MB at 800^2) whenever both came back, and built it again, faulted
        // in page by page, at the next side-by-side request (builds were 0.5 % of an 800^2
        // calibration's samples, and page faults in fresh transform buffers fell from 124 to
        // 77 of about 4000 with this change).
        st.keep = if w.runs_parallel() {
            st.keep.max(st.lent).min(most)
        } else {
            most
        };
        Ok(Workspace { pool, w: Some(w) })
    }

    /// Removal (nm, or nm per unit of the channel's variable) on the grid of `path` with
    /// optional per-sample rate weights, through channel `ch`.
    pub fn removal(
        &self,
        ch: Channel,
        path: &PathLog,
        weights: Option<&[f64]>,
    ) -> Result<Array2<f64>, ProcessError> {
        self.removal_at(Fidelity::Full, ch, path, weights)
    }

    /// [`Self::removal`] at a given [`Fidelity`] (`Screening` for candidate columns only).
    pub fn removal_at(
        &self,
        fidelity: Fidelity,
        ch: Channel,
        path: &PathLog,
        weights: Option<&[f64]>,
    ) -> Result<Array2<f64>, ProcessError> {
        self.removal_checked(fidelity, ch, path, weights)
            .map(|(out, _)| out)
    }

    /// [`Self::removal_at`] and whether its result is the same at either [`Fidelity`] (the
    /// path has no motion whose lines spread: see [`FastRemoval::fidelity_free`]).
    pub fn removal_checked(
        &self,
        fidelity: Fidelity,
        ch: Channel,
        path: &PathLog,
        weights: Option<&[f64]>,
    ) -> Result<(Array2<f64>, bool), ProcessError> {
        // A derivative channel screened on the coarse companion (never the same as `Full`).
        if fidelity == Fidelity::Screening && ch != Channel::Value {
            if let Some(c) = self.coarse() {
                let (m, _) = c.removal_checked(fidelity, ch, path, weights)?;
                return Ok((self.refine_to_grid(&c.grid, &m), false));
            }
        }
        let mut ws = self.workspace(ch)?;
        let w = ws.get();
        w.set_fidelity(fidelity);
        let out = w.removal(path, weights);
        w.set_fidelity(Fidelity::Full);
        out.map(|o| (o, w.fidelity_free()))
    }

    /// Sum of several channels' removals of the same path, each with its own weights.
    pub fn removal_sum(
        &self,
        path: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Array2<f64>, ProcessError> {
        self.removal_sum_at(Fidelity::Full, path, terms)
    }

    /// [`Self::removal_sum`] at a given [`Fidelity`].
    pub fn removal_sum_at(
        &self,
        fidelity: Fidelity,
        path: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Array2<f64>, ProcessError> {
        self.removal_sum_checked(fidelity, path, terms)
            .map(|(out, _)| out)
    }

    /// [`Self::removal_sum_at`] and whether its result is the same at either [`Fidelity`].
    pub fn removal_sum_checked(
        &self,
        fidelity: Fidelity,
        path: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<(Array2<f64>, bool), ProcessError> {
        let mut out = Array2::zeros((self.grid.rows, self.grid.cols));
        let mut free = true;
        for (ch, w) in terms {
            let (r, f) = self.removal_checked(fidelity, *ch, path, *w)?;
            out += &r;
            free &= f;
        }
        Ok((out, free))
    }

    /// Matched filter of a map on the grid (0 off its aperture) through channel `ch`: at every
    /// sample `k` of `path`, `sum_x r(x) K(x - p_k)` with the channel's point-sampled kernel,
    /// interpolated bilinearly between pixel positions (0 off the grown grid). It is the
    /// adjoint of resting dwell at the samples, the projection of `r` on a unit rate (or
    /// displacement) impulse there. Where the map pixel is fine against the footprint it is
    /// computed on the screening companion (see [`SCREENING_PIXELS_PER_RADIUS`]) from `r`
    /// spread by the adjoint of the interpolation: 0.27 % off the map grid's own through the
    /// value channel, 12-14 % through the derivatives on a map textured to the pixel (test
    /// `derivative_columns_screen_on_a_coarser_grid_where_the_pixel_is_fine`).
    pub fn matched(
        &self,
        ch: Channel,
        r: &Array2<f64>,
        path: &PathLog,
    ) -> Result<Vec<f64>, ProcessError> {
        if r.dim() != (self.grid.rows, self.grid.cols) {
            return Err(ProcessError::invalid(
                "matched filter map does not match the grid",
            ));
        }
        // On the screening companion where there is one: the matched filter only seeds
        // searches (periods, step times, the fallback's prescreen), never a fit.
        if let Some(c) = self.coarse() {
            return c.matched(ch, &self.spread_to_coarse(&c.grid, r), path);
        }
        self.matched_here(ch, r, path)
    }

    /// [`Self::matched`] on this grid itself.
    fn matched_here(
        &self,
        ch: Channel,
        r: &Array2<f64>,
        path: &PathLog,
    ) -> Result<Vec<f64>, ProcessError> {
        let idle = lock(&self.adjoint[slot(ch)])?.pop();
        let mut a = match idle {
            Some(a) => a,
            None => {
                let ext = *self.workspace(Channel::Value)?.get().dwell_grid();
                let kern = Tif::sample(
                    &PixelMean::new(self.field(ch), self.response),
                    self.grid.dx_mm,
                    self.grid.dy_mm,
                )?;
                let offset = (
                    ((self.grid.y0_mm - ext.y0_mm) / ext.dy_mm).round() as usize,
                    ((self.grid.x0_mm - ext.x0_mm) / ext.dx_mm).round() as usize,
                );
                // The map is zero outside the grid, which lies `offset` inside the grown grid,
                // and the correlation is read on the whole grown grid: a circular one of length
                // n is exact there when n >= max(offset + grid, grown - offset) + the kernel's
                // half-width, on each axis (the linear one's grown + kernel is not needed: at
                // 400^2 that was a 588^2 transform, 2^2 3 7^2, instead of 490^2).
                let (k0, k1) = kern.rate_nm_per_s.dim();
                let (o0, o1) = offset;
                // At least the grown grid itself (the convolver takes no less), rounded up to a
                // smooth length: the bound alone can fall a pixel or two short of the grown
                // grid, which the convolver would then transform at its own, possibly prime,
                // length.
                let need0 = (o0 + self.grid.rows).max(ext.rows - o0) + k0 / 2;
                let need1 = (o1 + self.grid.cols).max(ext.cols - o1) + k1 / 2;
                let n0 = fast_len(need0.max(ext.rows));
                let n1 = fast_len(need1.max(ext.cols));
                let conv =
                    Convolver::with_fft_size(ext.rows, ext.cols, kern.rate_nm_per_s.view(), n0, n1);
                Adjoint { conv, ext, offset }
            }
        };
        let mut big = Array2::zeros((a.ext.rows, a.ext.cols));
        let (o0, o1) = a.offset;
        big.slice_mut(s![o0..o0 + r.nrows(), o1..o1 + r.ncols()])
            .assign(r);
        let c = a.conv.apply_adjoint(big.view());
        let h = (0..path.len())
            .map(|i| {
                let (u, v) = a.ext.frac_index(path.x_mm[i], path.y_mm[i]);
                bilinear(&c, u, v)
            })
            .collect();
        let mut idle = lock(&self.adjoint[slot(ch)])?;
        if idle.len() < MAX_WORKSPACES {
            idle.push(a);
        }
        Ok(h)
    }

    /// Builds every channel's workspace now (so later calls do not pay for it).
    pub fn build_all(&self) -> Result<(), ProcessError> {
        for ch in CHANNELS {
            self.workspace(ch)?;
        }
        Ok(())
    }
}

/// Most idle workspaces a channel keeps on a grid whose transforms run on one thread.
const MAX_WORKSPACES: usize = 4;

/// A channel's workspace, lent to one caller; back to its pool when dropped.
struct Workspace<'a> {
    pool: &'a Pool,
    w: Option<FastRemoval>,
}

impl Workspace<'_> {
    fn get(&mut self) -> &mut FastRemoval {
        self.w
            .as_mut()
            .expect("a workspace is lent until it is dropped")
    }
}

impl Drop for Workspace<'_> {
    fn drop(&mut self) {
        if let (Some(w), Ok(mut st)) = (self.w.take(), self.pool.state.lock()) {
            st.lent = st.lent.saturating_sub(1);
            if st.idle.len() < st.keep.max(1) {
                st.idle.push(w);
            }
        }
    }
}

fn poisoned() -> ProcessError {
    ProcessError::Processing("a forward-model workspace was poisoned by a panic".into())
}

fn lock<T>(m: &Mutex<T>) -> Result<MutexGuard<'_, T>, ProcessError> {
    m.lock().map_err(|_| poisoned())
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

    /// The scale scan's removals are the channels' own at each scale (only the transform size
    /// differs: rounding), on a raster, the raster with rate weights, and a wiggled raster whose
    /// lines spread over the phase nodes; a scale beyond the scan's is refused.
    #[test]
    fn a_scale_scan_gives_the_channels_removal_at_every_scale() {
        let (g, grid, path) = setup();
        let weights: Vec<f64> = (0..path.len())
            .map(|k| 1.0 + 0.3 * (k as f64 * 0.05).sin())
            .collect();
        let wiggled = PathLog::new(
            path.t_s.clone(),
            path.x_mm.clone(),
            path.y_mm
                .iter()
                .zip(&path.x_mm)
                .map(|(y, x)| y + 0.3 * (x * 0.9).sin())
                .collect(),
        )
        .unwrap();
        let terms: Vec<(&PathLog, Option<&[f64]>)> =
            vec![(&path, None), (&path, Some(&weights)), (&wiggled, None)];
        let scan = ScaleScan::new(g.clone(), &grid, 1.45, &terms, PixelResponse::Point).unwrap();
        for scale in [0.6, 1.0, 1.37, 1.45] {
            let got = scan.removals(scale).unwrap();
            let c = Channels::new(g.clone(), &grid, scale).unwrap();
            for ((p, w), r) in terms.iter().zip(&got) {
                let want = c.removal(Channel::Value, p, *w).unwrap();
                let peak = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                let diff = (r - &want).iter().fold(0.0f64, |a, v| a.max(v.abs()));
                assert!(peak > 1.0, "scale {scale}: a removal to compare");
                assert!(diff <= 1e-9 * peak, "scale {scale}: {diff} of {peak}");
            }
        }
        assert!(scan.removals(1.5).is_err());
        assert!(scan.removals(0.0).is_err());
        // Over its memory budget the dwell's transform is refused, whole.
        let widest = Derived::new(g.clone(), 1.45, Channel::Value, 0.025);
        let mut w = FastRemoval::from_field(&widest, &grid).unwrap();
        assert!(w.dwell_spectra(&terms, 1 << 10).is_err());
        assert!(w.dwell_spectra(&terms, 1 << 30).is_ok());
    }

    /// Workspaces whose transforms run on the pool: one is kept while callers take one at a
    /// time; once two callers have held one at once, both are kept (a calibration's columns
    /// are computed side by side; dropping the second rebuilt it for most columns).
    #[test]
    fn parallel_workspaces_held_at_once_are_kept() {
        let g = Arc::new(GaussianTif::new(1.0, 8.0, 10.0).unwrap());
        // 520^2 pixels: the grown grid's transform is above PARALLEL_MIN_LEN.
        let grid = Grid::new(520, 520, 0.25, 0.25, 0.0, 0.0).unwrap();
        let c = Channels::new(g, &grid, 1.0).unwrap();
        let idle = |c: &Channels| {
            lock(&c.fast[slot(Channel::Value)].state)
                .unwrap()
                .idle
                .len()
        };
        {
            let mut w = c.workspace(Channel::Value).unwrap();
            assert!(
                w.get().runs_parallel(),
                "the test needs a parallel workspace"
            );
        }
        drop(c.workspace(Channel::Value).unwrap());
        assert_eq!(idle(&c), 1, "one caller at a time keeps one");
        let (a, b) = (
            c.workspace(Channel::Value).unwrap(),
            c.workspace(Channel::Value).unwrap(),
        );
        drop((a, b));
        let most = rayon::current_num_threads().clamp(1, MAX_WORKSPACES);
        assert_eq!(idle(&c), 2.min(most), "two held at once are both kept");
    }

    /// On a map pixel fine against the footprint (the paper's bonnet, 4.86 mm contact radius,
    /// on a 0.1 mm grid), the derivative channels' screening columns come from a grid twice as
    /// coarse and project a residual as the full columns do, with rate weights and on a
    /// wiggled path; the value channel's screening is untouched (the raster's full model, to
    /// the bit); the matched filters through the coarse grid agree with the map grid's own;
    /// and a 0.25 mm map has no coarse companion.
    #[test]
    fn derivative_columns_screen_on_a_coarser_grid_where_the_pixel_is_fine() {
        use crate::tif::bonnet::{BonnetTif, BonnetTifParams};
        let g: Arc<dyn RateField + Send> =
            Arc::new(BonnetTif::new(&BonnetTifParams::paper(100.0)).unwrap());
        let radius = footprint_radius_mm(g.as_ref(), 0.01).unwrap();
        assert!((radius - 4.86).abs() < 0.02, "contact radius {radius}");
        let gauss = GaussianTif::new(1.5, 20.0, 1.0).unwrap();
        let r_g = footprint_radius_mm(&gauss, 0.01).unwrap();
        assert!((r_g - 1.5 * 3.035).abs() < 0.02, "Gaussian footprint {r_g}");
        let grid = Grid::new(220, 260, 0.1, 0.1, 0.0, 0.0).unwrap();
        let c = Channels::new(g.clone(), &grid, 1.0).unwrap();
        let coarse = c.screening_grid().expect("a coarse companion at 0.1 mm");
        assert!((coarse.dx_mm - 0.2).abs() < 1e-12 && (coarse.dy_mm - 0.2).abs() < 1e-12);
        let wide =
            Channels::new(g, &Grid::new(88, 104, 0.25, 0.25, 0.0, 0.0).unwrap(), 1.0).unwrap();
        assert!(wide.screening_grid().is_none());
        // Raster lines along x at a 2.3 mm pitch, 20 mm/s, 100 Hz; the second path wiggles
        // 0.3 mm in y at a 7 mm period along x (its lines spread: screening's own kernels).
        let raster = |wiggle: f64| {
            let (mut t, mut x, mut y) = (vec![], vec![], vec![]);
            let mut time = 0.0;
            for line in 0..9 {
                let yy = 1.5 + 2.3 * line as f64;
                for k in 0..=130 {
                    let u = 0.2 * k as f64;
                    let xx = if line % 2 == 0 { u } else { 26.0 - u };
                    t.push(time);
                    x.push(xx);
                    y.push(yy + wiggle * (std::f64::consts::TAU * xx / 7.0).sin());
                    time += 0.01;
                }
                time += 0.3;
            }
            PathLog::new(t, x, y).unwrap()
        };
        let rel = |a: &Array2<f64>, b: &Array2<f64>| {
            let d: f64 = a.iter().zip(b).map(|(u, v)| (u - v) * (u - v)).sum();
            let n: f64 = b.iter().map(|v| v * v).sum();
            (d / n).sqrt()
        };
        for wiggle in [0.0, 0.3] {
            let path = raster(wiggle);
            let w: Vec<f64> = path
                .t_s
                .iter()
                .map(|t| 1.0 + 0.5 * (0.4 * t).sin())
                .collect();
            for ch in [Channel::Dx, Channel::Dy, Channel::Ds] {
                for weights in [None, Some(&w[..])] {
                    let (full, _) = c
                        .removal_checked(Fidelity::Full, ch, &path, weights)
                        .unwrap();
                    let (screen, free) = c
                        .removal_checked(Fidelity::Screening, ch, &path, weights)
                        .unwrap();
                    assert!(!free, "a coarse column is never the full one");
                    // What screening uses a column for: the projection of a residual on it.
                    // The full column projected on the screening one keeps 96.5-99.7 % of its
                    // energy at a coefficient of 0.975-1.000 (measured); point by point the
                    // derivative columns differ by 5-19 % of their norm (the rim's steep
                    // slope, which a 0.2 mm grid does not resolve).
                    let dot = |a: &Array2<f64>, b: &Array2<f64>| {
                        a.iter().zip(b).map(|(u, v)| u * v).sum::<f64>()
                    };
                    let (fs, ss, ff) = (
                        dot(&full, &screen),
                        dot(&screen, &screen),
                        dot(&full, &full),
                    );
                    let (coef, kept) = (fs / ss, fs * fs / (ss * ff));
                    let e = rel(&screen, &full);
                    let at = format!("{ch:?}, wiggle {wiggle}, weights {}", weights.is_some());
                    assert!((coef - 1.0).abs() < 0.04, "{at}: coefficient {coef:.4}");
                    assert!(kept > 0.95, "{at}: projection keeps {kept:.4}");
                    assert!(e < 0.25, "{at}: {e:.4} of the column");
                }
            }
            let (full, _) = c
                .removal_checked(Fidelity::Full, Channel::Value, &path, None)
                .unwrap();
            let (screen, _) = c
                .removal_checked(Fidelity::Screening, Channel::Value, &path, None)
                .unwrap();
            if wiggle == 0.0 {
                assert_eq!(
                    full, screen,
                    "the value channel screens on the map's own grid"
                );
            }
            // The matched filters (the adjoint) through the companion: a textured map's
            // correlation with each channel along the path, against this grid's own.
            let r = Array2::from_shape_fn((grid.rows, grid.cols), |(i, j)| {
                let (x, y) = (0.1 * j as f64, 0.1 * i as f64);
                (0.9 * x + 0.4 * y).sin() + 0.5 * (2.3 * x - 1.7 * y).cos() + 0.01 * (i % 7) as f64
            });
            for ch in [Channel::Value, Channel::Dx, Channel::Dy] {
                let here = c.matched_here(ch, &r, &path).unwrap();
                let via = c.matched(ch, &r, &path).unwrap();
                let d: f64 = here.iter().zip(&via).map(|(a, b)| (a - b) * (a - b)).sum();
                let n: f64 = here.iter().map(|a| a * a).sum();
                let e = (d / n).sqrt();
                // Measured: 0.27 % through the value channel; 12-14 % through the derivative
                // ones on this map, whose texture reaches the pixel.
                let most = if ch == Channel::Value { 0.01 } else { 0.2 };
                assert!(e < most, "{ch:?} matched filter, wiggle {wiggle}: {e:.4}");
            }
        }
    }

    #[test]
    fn derivative_channels_are_the_removal_of_a_displaced_path() {
        let (g, grid, path) = setup();
        let c = Channels::new(g, &grid, 1.0).unwrap();
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
        let c2 = Channels::new(c.base.clone(), &grid, 1.0 + ds).unwrap();
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
    fn removals_from_several_threads_are_the_bits_of_one_workspace_in_order() {
        // Paths shifted by sub-pixel amounts (each with line phases of its own, so the
        // workspaces build and replace phase kernels in whatever order the threads reach
        // them), with and without rate weights, through every channel.
        let (g, grid, path) = setup();
        let shifted: Vec<PathLog> = (0..24)
            .map(|k| {
                let d = 0.013 * k as f64;
                PathLog::new(
                    path.t_s.clone(),
                    path.x_mm.iter().map(|v| v + 0.7 * d).collect(),
                    path.y_mm.iter().map(|v| v + d).collect(),
                )
                .unwrap()
            })
            .collect();
        let w: Vec<f64> = (0..path.len())
            .map(|k| 1.0 + 0.3 * (k as f64 * 0.1).sin())
            .collect();
        let jobs: Vec<(usize, Channel, bool)> = (0..shifted.len())
            .flat_map(|k| {
                CHANNELS
                    .into_iter()
                    .flat_map(move |c| [(k, c, false), (k, c, true)])
            })
            .collect();
        let one = |c: &Channels, &(k, ch, weighted): &(usize, Channel, bool)| {
            c.removal(ch, &shifted[k], weighted.then_some(w.as_slice()))
                .unwrap()
        };
        let alone = Channels::new(g.clone(), &grid, 1.0).unwrap();
        let want: Vec<Array2<f64>> = jobs.iter().map(|j| one(&alone, j)).collect();
        let shared = Channels::new(g, &grid, 1.0).unwrap();
        let got: Vec<Array2<f64>> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..3)
                .map(|t| {
                    let (shared, jobs, one) = (&shared, &jobs, &one);
                    // Each thread takes the jobs in its own order.
                    s.spawn(move || {
                        let mut order: Vec<usize> = (0..jobs.len()).collect();
                        order.rotate_left(t * jobs.len() / 3);
                        if t == 1 {
                            order.reverse();
                        }
                        order
                            .into_iter()
                            .map(|i| (i, one(shared, &jobs[i])))
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            let mut all: Vec<Option<Array2<f64>>> = vec![None; jobs.len()];
            for h in hs {
                for (i, a) in h.join().unwrap() {
                    if let Some(prev) = &all[i] {
                        assert!(prev
                            .iter()
                            .zip(a.iter())
                            .all(|(x, y)| x.to_bits() == y.to_bits()));
                    }
                    all[i] = Some(a);
                }
            }
            all.into_iter().map(|a| a.unwrap()).collect()
        });
        for (j, (a, b)) in jobs.iter().zip(want.iter().zip(&got)) {
            assert!(
                a.iter()
                    .zip(b.iter())
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{j:?} differs from the one-workspace result"
            );
        }
    }

    #[test]
    fn a_caller_holding_a_workspace_gets_another_without_waiting() {
        // A rayon thread that holds a workspace while its transforms run in parallel may take
        // up another task asking for the same channel; that task must get a workspace of its
        // own (waiting for the held one would wait for itself). Run on another thread so a
        // regression shows as a failure, not a hang.
        let (g, grid, path) = setup();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let c = Channels::new(g, &grid, 1.0).unwrap();
            let held = c.workspace(Channel::Value).unwrap();
            let inner = c.removal(Channel::Value, &path, None).unwrap();
            drop(held);
            let after = c.removal(Channel::Value, &path, None).unwrap();
            tx.send(inner == after).unwrap();
        });
        let same = rx
            .recv_timeout(std::time::Duration::from_secs(120))
            .expect("a nested request for a workspace must not wait for the held one");
        assert!(same);
    }

    #[test]
    fn matched_filter_is_the_adjoint_of_resting_dwell() {
        let (g, grid, _) = setup();
        let c = Channels::new(g.clone(), &grid, 1.0).unwrap();
        // A tool resting at pixel centres: <R(dwell), r> = sum_k dwell_k h_k. The last three
        // rest off the map, near the grown grid's corners (its margin is 42 pixels, 10.5 mm),
        // where a circular correlation too short would wrap the far side of the map in.
        let pts = [
            (5.0, 5.0),
            (10.25, 7.5),
            (3.0, 12.0),
            (-10.25, -10.0),
            (27.5, 25.0),
            (-9.75, 24.75),
        ];
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
