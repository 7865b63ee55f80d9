//! Removal simulation, two ways that must agree:
//!
//! - **fast** ([`FastRemoval`]): the path's dwell time is splatted onto the map grid grown by
//!   the TIF half-width, split by motion (resting, along X, along Y; raster lines by their
//!   sub-pixel phase across the motion), and each part is convolved by FFT with the matching
//!   kernel of [`crate::tif::motion`] (point samples, or the TIF averaged over one pixel along
//!   the motion), summed through one inverse transform. Plans and kernel spectra are kept in
//!   the workspace. (Plain dwell maps: [`dwell_map`], [`convolve_tif`].)
//! - **exact** ([`deposit_exact`]): the instantaneous TIF, evaluated at the true offset of every
//!   pixel from the tool (a [`RateField`], analytic for models), deposited along the path in
//!   sub-steps of at most a quarter pixel and 1/80 of the footprint's half-extent (midpoint
//!   rule), in parallel. This is the reference.
//!
//! Conventions: dwell in s per pixel, removal in nm (positive = removed). The tool centre follows
//! the path log with straight lines between samples. Optional per-sample `weights` multiply the
//! removal rate (linear between samples): rate drifts, vibration modulation.

use ndarray::{Array2, ArrayView2};

use crate::error::ProcessError;
use std::sync::{Arc, Mutex};

use crate::fft::{fast_len, Complex, Convolver, MultiConvolver};
use crate::grid::Grid;
use crate::path::PathLog;
use crate::pixel::{PixelMean, PixelResponse};
use crate::tif::motion::{
    along_x_at_phase_sized, along_y_at_phase_sized, kernel_from_field, point_at_phase_sized, Motion,
};
use crate::tif::{RateField, Tif};

pub(crate) fn check_weights(path: &PathLog, weights: Option<&[f64]>) -> Result<(), ProcessError> {
    if let Some(w) = weights {
        if w.len() != path.len() {
            return Err(ProcessError::invalid(format!(
                "{} weights for {} path samples",
                w.len(),
                path.len()
            )));
        }
        if w.iter().any(|v| !v.is_finite()) {
            return Err(ProcessError::invalid("path weights must be finite"));
        }
    }
    Ok(())
}

fn weight_at(weights: Option<&[f64]>, k: usize, fr: f64) -> f64 {
    match weights {
        Some(w) => w[k] + fr * (w[k + 1] - w[k]),
        None => 1.0,
    }
}

/// How a sub-step's dwell is spread over the pixels around it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Splat {
    /// 2 x 2 bilinear weights: non-negative; keeps the mass and the centroid, but widens the
    /// dwell by f(1 - f) px^2 (f = fractional offset), which a raster line at a fixed
    /// fractional row turns into a systematic ~1 % error for a TIF of sigma = 4 px.
    Bilinear,
    /// 4 x 4 Keys cubic-convolution weights (a = -1/2): some weights are negative, but the
    /// splat also keeps the second moment, so the error falls to fourth order. Used by the fast
    /// removal.
    Cubic,
}

/// Dwell time per pixel (s) of `path` on `grid`, bilinear splat of sub-steps no longer than half
/// a pixel; time spent outside the grid (beyond its outer pixel centres) is dropped. Invalid
/// weights (wrong length, non-finite) give an all-zero map; [`FastRemoval::removal`] reports them.
pub fn dwell_map(path: &PathLog, weights: Option<&[f64]>, grid: &Grid) -> Array2<f64> {
    dwell_map_with(path, weights, grid, Splat::Bilinear)
}

/// [`dwell_map`] with a choice of splat kernel.
pub fn dwell_map_with(
    path: &PathLog,
    weights: Option<&[f64]>,
    grid: &Grid,
    kernel: Splat,
) -> Array2<f64> {
    let mut d = Array2::zeros((grid.rows, grid.cols));
    if check_weights(path, weights).is_err() {
        return d;
    }
    let step = 0.5 * grid.dx_mm.min(grid.dy_mm);
    path.for_each_substep(step, 0.0, |x, y, dt, k, fr| {
        let (u, v) = grid.frac_index(x, y);
        let w = dt * weight_at(weights, k, fr);
        match kernel {
            Splat::Bilinear => splat(&mut d, u, v, w),
            Splat::Cubic => splat_cubic(&mut d, u, v, w),
        }
    });
    d
}

/// Keys cubic-convolution weights (a = -1/2) for taps at -1, 0, 1, 2 around fraction f.
pub(crate) fn keys_weights(f: f64) -> [f64; 4] {
    let w = |t: f64| {
        let t = t.abs();
        if t <= 1.0 {
            1.5 * t * t * t - 2.5 * t * t + 1.0
        } else if t < 2.0 {
            -0.5 * t * t * t + 2.5 * t * t - 4.0 * t + 2.0
        } else {
            0.0
        }
    };
    [w(1.0 + f), w(f), w(1.0 - f), w(2.0 - f)]
}

/// Adds `w` at fractional (row u, col v) with 4 x 4 Keys cubic weights.
fn splat_cubic(d: &mut Array2<f64>, u: f64, v: f64, w: f64) {
    let (r, c) = d.dim();
    cubic_taps(r, c, u, v, |i, j, wi, wj| d[(i, j)] += w * wi * wj);
}

/// Adds `w` at fractional (row u, col v) with bilinear weights.
fn splat(d: &mut Array2<f64>, u: f64, v: f64, w: f64) {
    bilinear_taps(d.nrows(), d.ncols(), u, v, |i, j, wi, wj| {
        d[(i, j)] += w * wi * wj;
    });
}

/// The 2 x 2 bilinear splat of a point at fractional (row u, col v) on a `rows` x `cols` grid:
/// calls `f(i, j, wi, wj)` for every tap inside the grid, with the row and column weights.
/// Points beyond the outer pixel centres by a pixel or more get none. The one bilinear splat
/// (the dwell map's).
#[inline]
pub(crate) fn bilinear_taps(
    rows: usize,
    cols: usize,
    u: f64,
    v: f64,
    mut f: impl FnMut(usize, usize, f64, f64),
) {
    if !(u > -1.0 && v > -1.0 && u < rows as f64 && v < cols as f64) {
        return;
    }
    let (i0, j0) = (u.floor() as isize, v.floor() as isize);
    let (fu, fv) = (u - i0 as f64, v - j0 as f64);
    for (di, wi) in [(0isize, 1.0 - fu), (1, fu)] {
        let i = i0 + di;
        if i < 0 || i as usize >= rows {
            continue;
        }
        for (dj, wj) in [(0isize, 1.0 - fv), (1, fv)] {
            let j = j0 + dj;
            if j >= 0 && (j as usize) < cols {
                f(i as usize, j as usize, wi, wj);
            }
        }
    }
}

/// The 4 x 4 Keys cubic splat (a = -1/2) of a point at fractional (row u, col v) on a
/// `rows` x `cols` grid: calls `f(i, j, wi, wj)` for every tap inside the grid. Its weights keep
/// mass, centroid and second moment, so a ripple of f cycles per pixel along the path passes
/// with a loss of order f^4 where the bilinear splat's is 1 - sinc^2(f) (the N-channel
/// [`crate::perturb::WeightedDwell`]).
#[inline]
pub(crate) fn cubic_taps(
    rows: usize,
    cols: usize,
    u: f64,
    v: f64,
    mut f: impl FnMut(usize, usize, f64, f64),
) {
    if !(u > -2.0 && v > -2.0 && u < rows as f64 + 1.0 && v < cols as f64 + 1.0) {
        return;
    }
    let (i0, j0) = (u.floor() as isize, v.floor() as isize);
    let (wu, wv) = (keys_weights(u - i0 as f64), keys_weights(v - j0 as f64));
    for (a, &wi) in wu.iter().enumerate() {
        let i = i0 - 1 + a as isize;
        if i < 0 || i as usize >= rows {
            continue;
        }
        for (b, &wj) in wv.iter().enumerate() {
            let j = j0 - 1 + b as isize;
            if j >= 0 && (j as usize) < cols {
                f(i as usize, j as usize, wi, wj);
            }
        }
    }
}

/// Linear ("same" mode, zero-padded) convolution of a dwell map (s per pixel, on `grid`) with
/// the TIF: removal in nm on the same grid. The TIF is resampled to the grid pitch if needed.
/// Dwell outside the grid is taken as zero; see [`FastRemoval`] for the grown grid.
pub fn convolve_tif(
    dwell_s: &Array2<f64>,
    tif: &Tif,
    grid: &Grid,
) -> Result<Array2<f64>, ProcessError> {
    let t = tif_on_grid(tif, grid)?;
    let mut conv = Convolver::new(dwell_s.nrows(), dwell_s.ncols(), t.rate_nm_per_s.view());
    Ok(conv.apply(dwell_s.view()))
}

/// The TIF sampled at the grid's pitch (a copy when it already is).
pub fn tif_on_grid(tif: &Tif, grid: &Grid) -> Result<Tif, ProcessError> {
    let same = (tif.dx_mm - grid.dx_mm).abs() <= 1e-9 * grid.dx_mm
        && (tif.dy_mm - grid.dy_mm).abs() <= 1e-9 * grid.dy_mm;
    if same {
        Ok(tif.clone())
    } else {
        tif.resampled(grid.dx_mm, grid.dy_mm)
    }
}

/// Calls `f(u, v, w, dt, shares)` for every sub-step (at most half a pixel) of `path` on
/// `grid`: fractional row / column, dwell (s, times the rate weight), the path's own dwell (s,
/// no weight) and its shares `[resting, along X, along Y]` (oblique motion split by cos^2 /
/// sin^2 of its direction), then the path segment `k` and the fraction along it.
fn for_each_motion_substep(
    path: &PathLog,
    weights: Option<&[f64]>,
    grid: &Grid,
    mut f: impl FnMut(f64, f64, f64, f64, [f64; 3], usize, f64),
) {
    let step = 0.5 * grid.dx_mm.min(grid.dy_mm);
    // A segment shorter than this is a resting tool (well below any sub-pixel structure).
    let rest2 = (1e-6 * step).powi(2);
    path.for_each_substep(step, 0.0, |x, y, dt, k, fr| {
        let (u, v) = grid.frac_index(x, y);
        let w = dt * weight_at(weights, k, fr);
        let ddx = path.x_mm[k + 1] - path.x_mm[k];
        let ddy = path.y_mm[k + 1] - path.y_mm[k];
        let len2 = ddx * ddx + ddy * ddy;
        let shares = if len2 <= rest2 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, ddx * ddx / len2, ddy * ddy / len2]
        };
        f(u, v, w, dt, shares, k, fr);
    });
}

/// Dwell time per pixel (s) of `path` on `grid` (cubic splat, sub-steps of at most half a
/// pixel), split by the kind of motion it was spent in: `[resting, along X, along Y]` (see
/// [`crate::tif::motion`]); oblique motion is shared by cos^2 / sin^2 of its direction. Maps
/// that receive no dwell are `None`.
pub fn dwell_maps_by_motion(
    path: &PathLog,
    weights: Option<&[f64]>,
    grid: &Grid,
) -> Result<[Option<Array2<f64>>; 3], ProcessError> {
    check_weights(path, weights)?;
    let mut maps: [Option<Array2<f64>>; 3] = [None, None, None];
    for_each_motion_substep(path, weights, grid, |u, v, w, _, shares, _, _| {
        for (m, share) in maps.iter_mut().zip(shares) {
            if share > 0.0 {
                let d = m.get_or_insert_with(|| Array2::zeros((grid.rows, grid.cols)));
                splat_cubic(d, u, v, w * share);
            }
        }
    });
    Ok(maps)
}

/// Adds `w` in column `j` at fractional row `u` with 4 Keys cubic weights along the column only.
fn splat_cubic_col(d: &mut Array2<f64>, u: f64, j: isize, w: f64) {
    if j >= 0 && (j as usize) < d.ncols() {
        splat_cubic_lane(d.column_mut(j as usize), u, w);
    }
}

/// Adds `w` at fractional position `u` of a lane with 4 Keys cubic weights (outside: nothing).
fn splat_cubic_lane(mut lane: ndarray::ArrayViewMut1<f64>, u: f64, w: f64) {
    let n = lane.len();
    if !(u > -2.0 && u < n as f64 + 1.0) {
        return;
    }
    let i0 = u.floor() as isize;
    for (a, wi) in keys_weights(u - i0 as f64).iter().enumerate() {
        let i = i0 - 1 + a as isize;
        if i >= 0 && (i as usize) < n {
            lane[i as usize] += w * wi;
        }
    }
}

/// Adds `w` on row `i` at fractional column `v` with 4 Keys cubic weights along the row only.
fn splat_cubic_row(d: &mut Array2<f64>, i: isize, v: f64, w: f64) {
    if i >= 0 && (i as usize) < d.nrows() {
        splat_cubic_lane(d.row_mut(i as usize), v, w);
    }
}

/// Sub-row phases of along-X dwell are histogrammed in 1 / 4096 row; a run of occupied bins
/// is one line phase (a logged path's lines wander by a little), given a kernel at its
/// dwell-weighted mean phase. Phases are keyed in 1 / 2^20 row.
const PHASE_BINS: usize = 4096;
const PHASE_KEY_STEPS: f64 = (1u32 << 20) as f64;
/// Widest run of bins taken as one line phase (1/32 row).
const MAX_PHASE_SPAN_BINS: usize = PHASE_BINS / 32;

/// The coordinate across motion `kind` (1 along X: the row `u`; 2 along Y: the column `v`).
fn across_of(kind: usize, u: f64, v: f64) -> f64 {
    if kind == 1 {
        u
    } else {
        v
    }
}

/// Row and sub-row phase (0 <= phase < 1) of fractional row `u`, and the phase's histogram bin.
fn row_phase(u: f64) -> (isize, f64, usize) {
    let n = u.floor();
    let f = (u - n).clamp(0.0, 1.0);
    let b = ((f * PHASE_BINS as f64) as usize).min(PHASE_BINS - 1);
    (n as isize, f, b)
}

/// How one motion's dwell is put on the grid.
#[derive(Default)]
enum Lines {
    /// Raster lines at a few sub-pixel phases, one kernel each.
    Phases(LinePhases),
    /// Too many phases or spread ones (a path that wanders): shared linearly between the
    /// kernels at the fixed phases `j / PHASE_NODES`.
    #[default]
    Spread,
}

/// Line phases of a path's along-X dwell: the kernel-phase of each histogram bin's run.
struct LinePhases {
    /// Cluster index of each bin (`u8::MAX`: empty).
    bin_cluster: Vec<u8>,
    /// Dwell-weighted mean phase of each cluster.
    phase: Vec<f64>,
    /// A minor motion (see [`MINOR_MOTION_SHARE`]).
    minor: bool,
}

/// The line phases of the along-X (`kind` 1: sub-row) or along-Y (`kind` 2: sub-column) dwell
/// of `steps`: [`Lines::Minor`] for a minor motion, [`Lines::Spread`] when there are more than
/// [`MAX_PHASES`] or one spreads over more than 1/32 pixel (a path that wanders rather than a
/// raster). Only sub-steps with at least [`MINOR_SHARE`] of their dwell in that motion count,
/// and phases are weighted by the path's own dwell, not the rate weights: every weighting of one
/// path has the same line phases (the same kernels, and a model linear in the weights).
fn line_phases(steps: &[SubStep], kind: usize) -> Lines {
    let mut w_sum = vec![0.0f64; PHASE_BINS];
    let mut wp_sum = vec![0.0f64; PHASE_BINS];
    let mut all = 0.0;
    for st in steps {
        all += st.dt;
        if st.shares[kind] >= MINOR_SHARE {
            let (_, f, b) = row_phase(across_of(kind, st.u, st.v));
            let a = st.dt * st.shares[kind];
            w_sum[b] += a;
            wp_sum[b] += a * f;
        }
    }
    // A line phase is a run of bins holding at least LINE_BIN_SHARE of this motion's dwell
    // each; the other bins are stray (a logged raster's corners, cut between samples, cross
    // the rows) and go to the centred kernel, unless they hold more than STRAY_SHARE of the
    // path's dwell.
    let total: f64 = w_sum.iter().sum();
    let minor = total < MINOR_MOTION_SHARE * all;
    let floor = LINE_BIN_SHARE * total;
    let hit: Vec<bool> = w_sum.iter().map(|&a| a > 0.0 && a >= floor).collect();
    let stray: f64 = w_sum
        .iter()
        .zip(&hit)
        .filter(|(_, &h)| !h)
        .map(|(a, _)| a)
        .sum();
    if stray > STRAY_SHARE * all {
        return Lines::Spread;
    }
    let mut bin_cluster = vec![u8::MAX; PHASE_BINS];
    let mut phase = Vec::new();
    let mut b = 0;
    while b < PHASE_BINS {
        if !hit[b] {
            b += 1;
            continue;
        }
        let start = b;
        while b < PHASE_BINS && hit[b] {
            b += 1;
        }
        if b - start > MAX_PHASE_SPAN_BINS || phase.len() == MAX_PHASES {
            return Lines::Spread;
        }
        let (w, wp) = (start..b).fold((0.0, 0.0), |(x, y), k| (x + w_sum[k], y + wp_sum[k]));
        bin_cluster[start..b].fill(phase.len() as u8);
        let f = wp / w;
        // A minor motion's lines (a raster's step-overs) take their kernel at the nearest
        // 1 / MINOR_PHASE_STEPS pixel, so a path moved by a little reuses its kernels.
        phase.push(if minor {
            (f * MINOR_PHASE_STEPS).round() / MINOR_PHASE_STEPS
        } else {
            f
        });
    }
    Lines::Phases(LinePhases {
        bin_cluster,
        phase,
        minor,
    })
}

/// Share of a sub-step's dwell in one motion below which it is a side-effect of motion along
/// the other axis (a logged line's jitter, a step between lines): it has no line structure of
/// its own, so it goes with the major motion (that motion's kernel and line phase; no map of
/// its own). The two one-pixel box kernels differ by about 1 % of the footprint, so the error
/// is below 1e-4 of the sub-step's removal.
const MINOR_SHARE: f64 = 1e-2;
/// Share of the path's dwell below which a motion is minor (a raster's step-overs, 1-3 %).
/// Its lines keep kernels at their own phase across them (rounded to 1 / [`MINOR_PHASE_STEPS`]
/// pixel, so a path moved by a little reuses them), but point-sampled: one field value per
/// kernel pixel instead of the 32 of a one-pixel average along the motion, which changes their
/// small removal by about 1 %. The major motion's stray dwell (off its lines) then goes onto the
/// point-sampled kernel too, so the along-X and along-Y centred kernels are not built. Measured
/// (2026-11-25) on the demo's run, whose raster turns on the part's edge: MSF band RMS of the
/// fast baseline removal minus direct deposition 0.0117 nm of 3.076 nm (with box-averaged
/// step-over kernels 0.0099 nm; splatted cubically across their columns 0.036-0.040 nm, which
/// is why they keep their phases: test
/// `raster_turning_on_the_part_edge_matches_direct_deposition_in_the_msf_band`); the truth
/// suite's worst errors unchanged in every printed digit.
const MINOR_MOTION_SHARE: f64 = 5e-2;
const MINOR_PHASE_STEPS: f64 = 64.0;
/// Least share of a motion's dwell in one sub-row phase bin for the bin to belong to a line.
const LINE_BIN_SHARE: f64 = 1e-2;
/// Most share of the path's dwell in phase bins outside the lines (splatted cubically onto the
/// centred kernel, like [`MINOR_SHARE`] dwell); beyond it the fixed phase nodes are used.
const STRAY_SHARE: f64 = 1e-2;
/// Most distinct line phases given their own kernels (a raster whose pitch is a simple multiple
/// of the pixel has one or a few); beyond it along-X dwell is splatted cubically across rows.
const MAX_PHASES: usize = 8;
/// Fixed phase nodes of the fallback (linear interpolation between their kernels).
const PHASE_NODES: usize = 8;
/// Fewest phase kernels kept between calls (at least the most one call can use: both motions
/// at [`PHASE_NODES`] nodes); beyond it the least recently used is replaced.
const MIN_CACHED_PHASES: usize = 2 * PHASE_NODES;
/// Most phase kernels kept, and the memory their spectra may take (bytes), whichever is less
/// (but at least [`MIN_CACHED_PHASES`]).
const MAX_CACHED_PHASES: usize = 48;
const PHASE_CACHE_BYTES: usize = 16 << 20;
/// Zeroed dwell maps kept for reuse between calls (fresh grown-grid maps cost page faults and
/// a memset per call): as many as a removal takes (the centred kernels' three and the phase
/// nodes of both motions), within [`POOLED_MAP_BYTES`] and at least [`MIN_POOLED_MAPS`].
const MAX_POOLED_MAPS: usize = 3 + 2 * PHASE_NODES + 2;
const MIN_POOLED_MAPS: usize = 8;
const POOLED_MAP_BYTES: usize = 48 << 20;

/// One sub-step of the path on the grown grid: fractional row / column, dwell (s, times the
/// rate weight), the path's own dwell (s) and its shares `[resting, along X, along Y]`.
#[derive(Debug, Clone, Copy)]
struct SubStep {
    u: f64,
    v: f64,
    w: f64,
    dt: f64,
    shares: [f64; 3],
}

/// A cached line-phase kernel.
#[derive(Debug, Clone, Copy)]
struct PhaseKernel {
    /// Motion kind: 1 along X, 2 along Y (box kernels); 3, 4 the same, point-sampled.
    kind: usize,
    /// Phase in 1 / 2^20 pixel.
    q: u32,
    /// Kernel index in the convolver.
    idx: usize,
    /// Call counter when last used.
    used: u64,
}

/// Fast removal workspace for one map grid and one TIF: FFT plans, the spectra of the TIF's
/// motion kernels (point samples for a resting tool, one-pixel averages along X and along Y for
/// a moving one, and along-X kernels at the sub-row offsets of raster lines: see
/// [`crate::tif::motion`]) and buffers are built once and reused for every path (weights,
/// perturbed paths, ...).
pub struct FastRemoval {
    grid: Grid,
    ext: Grid,
    h: (usize, usize),
    conv: MultiConvolver,
    field: Box<dyn RateField + Send>,
    /// Half-widths of the field's point-sampled kernel.
    half: (usize, usize),
    /// Convolver indices of the centred kernels `[resting, along X, along Y]`, built on first
    /// use (a raster along X needs only the along-Y one, for its step-overs).
    base: [Option<usize>; 3],
    /// Cached line-phase kernels (least recently used replaced first).
    phases: Vec<PhaseKernel>,
    /// Phase kernels kept at most.
    max_phases: usize,
    /// Calls so far (the phase cache's clock).
    calls: u64,
    /// Phase kernels built so far.
    phase_builds: usize,
    /// The current call's weighted sub-steps (reused buffer).
    steps: Vec<SubStep>,
    /// The last path walked (its own copy), whose unweighted walk is kept in `walk`.
    walked: Option<PathLog>,
    /// Sub-steps of `walked` with `w = dt` (no rate weight), and each one's path segment and
    /// fraction along it: a call with the same path and other weights re-applies only the
    /// weights (the calibration asks for one executed path with many rate terms).
    walk: Vec<SubStep>,
    walk_at: Vec<(usize, f64)>,
    /// Line phases of `walk` along X and along Y (they depend on the path's own dwell only, so
    /// every weighting of the walk has the same).
    walk_phases: [Lines; 2],
    /// Zeroed dwell maps of the grown grid, for reuse.
    pool: Vec<Array2<f64>>,
    /// Kernel spectra shared with the other workspaces of the same field and grid, if any.
    shared: Option<SharedSpectra>,
    /// Spectra built ahead of their first use ([`Self::prebuild`]), taken by [`Self::spectrum`].
    prebuilt: Vec<KeyedHat>,
    /// How finely the next removals resolve a motion whose lines spread.
    fidelity: Fidelity,
    /// How the map's pixels see the removal (the field is already [`PixelMean`] when they
    /// are area means; kept for the dwell spectra, which take other fields).
    response: PixelResponse,
}

/// How finely a removal resolves dwell whose raster lines spread over sub-pixel phases (a path
/// that wanders: a logged path's jitter, or a path moved by a wiggle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fidelity {
    /// Phase kernels at [`PHASE_NODES`] fixed phases, the dwell shared linearly between them:
    /// the footprint's steep rim where the line passes (what `simulate` and the calibration's
    /// fits use).
    #[default]
    Full,
    /// That dwell splatted cubically across its motion onto the motion's centred kernel: one
    /// map and one transform per motion instead of up to [`PHASE_NODES`]. The rim's sub-pixel
    /// position is then interpolated. Measured on a raster wiggled 0.3 mm at a 7 mm period
    /// (test `screening_is_the_full_model_on_a_raster_and_one_kernel_per_motion_on_a_wiggled_path`):
    /// 0.68 % of the removal RMS off exact deposition, against 0.10 % at `Full`, with 5
    /// transforms instead of 33. For screening many candidate columns, never for a reported
    /// removal. A path whose lines keep a few phases is computed as in `Full`, to the bit.
    /// Through [`crate::channels::Channels`], a derivative channel on a map whose pixel is fine
    /// against the footprint is screened on a coarser grid (see
    /// [`crate::channels::SCREENING_PIXELS_PER_RADIUS`]).
    Screening,
}

/// Kernel spectra shared by workspaces of one field on one grid (the pool of a channel, see
/// [`crate::channels::Channels`]), by kernel key: a kernel one of them built is handed to the
/// others instead of being built again. The spectra are the same whichever workspace built
/// them; at most [`SHARED_SPECTRA`] are kept, the oldest dropped first.
#[derive(Debug, Default, Clone)]
pub struct SharedSpectra(Arc<Mutex<SpectraCache>>);

#[derive(Debug, Default)]
struct SpectraCache {
    map: std::collections::HashMap<(usize, u32), Arc<Vec<Complex<f64>>>>,
    order: std::collections::VecDeque<(usize, u32)>,
}

/// Most spectra a [`SharedSpectra`] keeps (a workspace's own cache holds up to
/// [`MAX_CACHED_PHASES`] phases and the three centred kernels).
const SHARED_SPECTRA: usize = MAX_CACHED_PHASES + 3;

impl SharedSpectra {
    fn get(&self, key: (usize, u32)) -> Option<Arc<Vec<Complex<f64>>>> {
        self.0.lock().ok()?.map.get(&key).cloned()
    }

    fn put(&self, key: (usize, u32), hat: &Arc<Vec<Complex<f64>>>) {
        let Ok(mut c) = self.0.lock() else { return };
        if c.map.contains_key(&key) {
            return;
        }
        while c.map.len() >= SHARED_SPECTRA {
            let Some(old) = c.order.pop_front() else {
                break;
            };
            c.map.remove(&old);
        }
        c.map.insert(key, hat.clone());
        c.order.push_back(key);
    }
}

impl std::fmt::Debug for FastRemoval {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "FastRemoval({:?} grown to {:?}, {:?})",
            self.grid, self.ext, self.conv
        )
    }
}

/// A dwell map's spectrum with the key of its kernel (see [`kernel_key`]).
type KeyedSpectrum = ((usize, u32), Vec<Complex<f64>>);

/// A kernel's spectrum.
type KernelHat = Arc<Vec<Complex<f64>>>;

/// A kernel's key ([`kernel_key`]) and its spectrum.
type KeyedHat = ((usize, u32), KernelHat);

/// The dwell side of removals (walk, splat by kernel, forward transforms) done once, for
/// convolution with the kernels of other fields whose support is no wider than the field of
/// the workspace that made them ([`FastRemoval::dwell_spectra`]): a scan of the TIF's width
/// then costs, per width, its kernels' transforms and one inverse transform per term. A
/// removal from here equals the workspace's own removal through that field up to rounding (the
/// transform size is the widest field's).
pub struct DwellSpectra {
    grid: Grid,
    ext: Grid,
    h: (usize, usize),
    half: (usize, usize),
    fft_shape: (usize, usize),
    /// Per term, per dwell map in target order: its kernel's key and its spectrum.
    terms: Vec<Vec<KeyedSpectrum>>,
    /// The workspace's pixel response (applied to the kernels of every field).
    response: PixelResponse,
}

impl std::fmt::Debug for DwellSpectra {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "DwellSpectra({} terms on {:?} grown to {:?})",
            self.terms.len(),
            self.grid,
            self.ext
        )
    }
}

impl DwellSpectra {
    /// The removal (nm) on the map grid of every term through `field`, in the order of the
    /// terms. An error when the field's support is wider than the workspace's.
    pub fn removals(&self, field: &dyn RateField) -> Result<Vec<Array2<f64>>, ProcessError> {
        let (dx, dy) = (self.grid.dx_mm, self.grid.dy_mm);
        let (p0, p1) = Tif::sample_half_widths(field, dx, dy)?;
        if p0 > self.half.0 || p1 > self.half.1 {
            return Err(ProcessError::invalid(format!(
                "field half-widths ({p0}, {p1}) px exceed the dwell spectra's ({}, {}) px",
                self.half.0, self.half.1
            )));
        }
        let (n0, n1) = self.fft_shape;
        let mut conv = MultiConvolver::with_fft_size(self.ext.rows, self.ext.cols, &[], n0, n1);
        // Each kernel built once for every term that has dwell on it.
        let mut keys: Vec<(usize, u32)> = Vec::new();
        for &(key, _) in self.terms.iter().flatten() {
            if !keys.contains(&key) {
                keys.push(key);
            }
        }
        let seen = PixelMean::new(field, self.response);
        let hats = build_spectra(&keys, &seen, conv.fft(), &self.grid, self.half)?;
        let shape = (self.grid.rows, self.grid.cols);
        Ok(self
            .terms
            .iter()
            .map(|term| {
                let pairs: Vec<crate::fft::SpectrumPair> = term
                    .iter()
                    .map(|(key, spec)| {
                        let hat = hats
                            .iter()
                            .find(|(k, _)| k == key)
                            .map(|(_, h)| h.as_slice())
                            .expect("every key's kernel was built above");
                        (spec.as_slice(), hat)
                    })
                    .collect();
                conv.apply_spectra_window(&pairs, self.h, shape)
            })
            .collect())
    }
}

impl FastRemoval {
    /// From a sampled TIF (resampled to the grid pitch if needed); its bilinear interpolant
    /// inside the sampled window is taken as the continuous footprint, as exact deposition of a
    /// sampled TIF does.
    pub fn new(tif: &Tif, grid: &Grid) -> Result<FastRemoval, ProcessError> {
        let t = tif_on_grid(tif, grid)?;
        Self::build(Box::new(t), grid)
    }

    /// From a continuous rate field (a model): the motion kernels are its exact point values
    /// and one-pixel averages, so the fast removal matches the exact deposition of the same
    /// field even where the footprint has a steep edge.
    pub fn from_field<F: RateField + Send + Clone + 'static>(
        field: &F,
        grid: &Grid,
    ) -> Result<FastRemoval, ProcessError> {
        Self::build(Box::new(field.clone()), grid)
    }

    /// [`Self::from_field`] for maps whose pixels sample the removal as `response` says (every
    /// kernel built from the field's box means, [`PixelMean`]).
    pub fn from_field_seen<F: RateField + Send + Clone + 'static>(
        field: &F,
        grid: &Grid,
        response: PixelResponse,
    ) -> Result<FastRemoval, ProcessError> {
        let mut w = if response.is_point() {
            Self::build(Box::new(field.clone()), grid)?
        } else {
            Self::build(Box::new(PixelMean::new(field.clone(), response)), grid)?
        };
        w.response = response;
        Ok(w)
    }

    fn build(field: Box<dyn RateField + Send>, grid: &Grid) -> Result<FastRemoval, ProcessError> {
        let (p0, p1) = Tif::sample_half_widths(field.as_ref(), grid.dx_mm, grid.dy_mm)?;
        // Row and column margin of the largest kernel (phase kernels add two rows or columns).
        let (h0, h1) = (p0 + 2, p1 + 2);
        let ext = grid.grown(h0, h1);
        // The output is the grid itself, at least the largest half-width inside the grown
        // grid, so a transform of the grown size is exact there (no padding needed).
        let conv = MultiConvolver::with_fft_size(
            ext.rows,
            ext.cols,
            &[],
            fast_len(ext.rows),
            fast_len(ext.cols),
        );
        let spectrum_bytes = conv.fft().spectrum_len() * std::mem::size_of::<Complex<f64>>();
        let max_phases = (PHASE_CACHE_BYTES / spectrum_bytes.max(1))
            .clamp(MIN_CACHED_PHASES, MAX_CACHED_PHASES.max(MIN_CACHED_PHASES));
        Ok(FastRemoval {
            grid: *grid,
            ext,
            h: (h0, h1),
            conv,
            field,
            half: (p0, p1),
            base: [None; 3],
            phases: Vec::new(),
            max_phases,
            calls: 0,
            phase_builds: 0,
            steps: Vec::new(),
            walked: None,
            walk: Vec::new(),
            walk_at: Vec::new(),
            walk_phases: [Lines::Spread, Lines::Spread],
            pool: Vec::new(),
            shared: None,
            prebuilt: Vec::new(),
            fidelity: Fidelity::Full,
            response: PixelResponse::Point,
        })
    }

    /// Sets how finely the next removals resolve spread line phases (see [`Fidelity`]).
    pub fn set_fidelity(&mut self, fidelity: Fidelity) {
        self.fidelity = fidelity;
    }

    /// Whether the last path this workspace walked gives the same removal, bit for bit, at
    /// either [`Fidelity`]: none of its motions has spread lines (fidelity only decides where a
    /// spread motion's dwell goes). False before any removal.
    pub fn fidelity_free(&self) -> bool {
        self.walked.is_some()
            && self
                .walk_phases
                .iter()
                .all(|l| matches!(l, Lines::Phases(_)))
    }

    /// Shares kernel spectra with other workspaces of the same field on the same grid (each
    /// kernel is then built by one of them only).
    pub fn share_spectra(&mut self, shared: SharedSpectra) {
        self.shared = Some(shared);
    }

    /// The spectrum of kernel `key`: from the shared spectra, else built by `build` (and
    /// shared).
    fn spectrum(
        &mut self,
        key: (usize, u32),
        build: impl FnOnce(&dyn RateField, f64, f64, (usize, usize)) -> Result<Tif, ProcessError>,
    ) -> Result<Arc<Vec<Complex<f64>>>, ProcessError> {
        // A prebuilt spectrum is taken whichever source answers (another workspace may have
        // shared the same key since): none is left behind.
        let prebuilt = self
            .prebuilt
            .iter()
            .position(|(k, _)| *k == key)
            .map(|n| self.prebuilt.swap_remove(n).1);
        if let Some(hat) = self.shared.as_ref().and_then(|sh| sh.get(key)) {
            return Ok(hat);
        }
        if let Some(hat) = prebuilt {
            if let Some(sh) = &self.shared {
                sh.put(key, &hat);
            }
            return Ok(hat);
        }
        let t = build(
            self.field.as_ref(),
            self.grid.dx_mm,
            self.grid.dy_mm,
            self.half,
        )?;
        let hat = self.conv.kernel_spectrum(t.rate_nm_per_s.view());
        if let Some(sh) = &self.shared {
            sh.put(key, &hat);
        }
        Ok(hat)
    }

    /// Builds the spectra of those `keys` ([`kernel_key`]s) that the next calls will build (not
    /// held by this workspace, the shared spectra or an earlier prebuild) side by side, each a
    /// field sampling and a transform with scratch of its own: the same bits as
    /// [`Self::spectrum`] builds one at a time. The first removal of a path whose lines spread
    /// needs up to [`PHASE_NODES`] phase kernels per motion at once.
    fn prebuild(&mut self, keys: &[(usize, u32)]) -> Result<(), ProcessError> {
        let held = |k: &(usize, u32)| match *k {
            (m, 0) if m < 3 => self.base[m].is_some(),
            (kind, q) => self.phases.iter().any(|e| e.kind == kind && e.q == q),
        };
        let mut todo: Vec<(usize, u32)> = keys
            .iter()
            .copied()
            .filter(|k| {
                !held(k)
                    && !self.prebuilt.iter().any(|(p, _)| p == k)
                    && self.shared.as_ref().is_none_or(|sh| sh.get(*k).is_none())
            })
            .collect();
        todo.sort_unstable();
        todo.dedup();
        if todo.len() < 2 {
            return Ok(());
        }
        self.prebuilt.extend(build_spectra(
            &todo,
            self.field.as_ref(),
            self.conv.fft(),
            &self.grid,
            self.half,
        )?);
        Ok(())
    }

    /// Line-phase kernels built so far (each one a field sampling and a forward transform; a
    /// kernel is built once and kept while it is used).
    pub fn phase_kernel_builds(&self) -> usize {
        self.phase_builds
    }

    /// The map grid grown by the largest kernel half-width: where dwell can affect the map.
    pub fn dwell_grid(&self) -> &Grid {
        &self.ext
    }

    /// Whether this workspace's transforms run on several threads (a large grid).
    pub fn runs_parallel(&self) -> bool {
        self.conv.fft().is_parallel()
    }

    /// FFTs run so far by this workspace (kernel spectra included).
    pub fn fft_count(&self) -> usize {
        self.conv.fft().transforms()
    }

    /// Removal (nm) on the map grid from a dwell map on [`Self::dwell_grid`], the dwell taken
    /// as spent at rest at pixel centres (point-sampled TIF).
    pub fn removal_from_dwell(
        &mut self,
        dwell_ext_s: &Array2<f64>,
    ) -> Result<Array2<f64>, ProcessError> {
        if dwell_ext_s.dim() != (self.ext.rows, self.ext.cols) {
            return Err(ProcessError::invalid(
                "dwell map does not match the grown grid",
            ));
        }
        let idx = self.base_kernel(0)?;
        let mut views = vec![None; self.conv.kernel_count()];
        views[idx] = Some(dwell_ext_s.view());
        Ok(self.on_grid(&views))
    }

    /// The sum of the convolutions of `views` on the map grid (inside the grown grid).
    fn on_grid(&mut self, views: &[Option<ArrayView2<f64>>]) -> Array2<f64> {
        let shape = (self.grid.rows, self.grid.cols);
        self.conv.apply_sum_window(views, self.h, shape)
    }

    /// Convolver index of the centred kernel of motion `m` (0 resting, 1 along X, 2 along Y),
    /// built on first use ([`kernels_from_field`]'s three kernels).
    fn base_kernel(&mut self, m: usize) -> Result<usize, ProcessError> {
        if let Some(idx) = self.base[m] {
            return Ok(idx);
        }
        let hat = self.spectrum((m, 0), |f, dx, dy, half| kernel_of((m, 0), f, dx, dy, half))?;
        let idx = self.conv.push_kernel_spectrum(hat);
        self.base[m] = Some(idx);
        Ok(idx)
    }

    /// Kernel index for dwell of motion `kind` (1 along X, 2 along Y) at sub-pixel phase key
    /// `q` (in 1 / 2^20 pixel) across the motion, built on first use (phase 0 is the centred
    /// kernel of that motion). A new kernel takes a free place in the cache, or replaces the
    /// least recently used one not used in this call.
    fn phase_kernel(&mut self, kind: usize, q: u32) -> Result<usize, ProcessError> {
        if q == 0 {
            return self.base_kernel(if kind > 2 { 0 } else { kind });
        }
        let now = self.calls;
        if let Some(e) = self.phases.iter_mut().find(|e| e.kind == kind && e.q == q) {
            e.used = now;
            return Ok(e.idx);
        }
        let t = self.spectrum((kind, q), |f, dx, dy, half| {
            kernel_of((kind, q), f, dx, dy, half)
        })?;
        self.phase_builds += 1;
        let stale = self
            .phases
            .iter()
            .enumerate()
            .filter(|(_, e)| e.used < now)
            .min_by_key(|(_, e)| e.used)
            .map(|(n, _)| n);
        match stale {
            Some(n) if self.phases.len() >= self.max_phases => {
                let idx = self.phases[n].idx;
                self.conv.set_kernel_spectrum(idx, t);
                self.phases[n] = PhaseKernel {
                    kind,
                    q,
                    idx,
                    used: now,
                };
                Ok(idx)
            }
            _ => {
                let idx = self.conv.push_kernel_spectrum(t);
                self.phases.push(PhaseKernel {
                    kind,
                    q,
                    idx,
                    used: now,
                });
                Ok(idx)
            }
        }
    }

    /// Kernel indices for the phases of each motion kind (no index handed out here is
    /// replaced within the same call).
    fn phase_kernels(
        &mut self,
        wanted: [(usize, &[f64]); 2],
    ) -> Result<[Vec<usize>; 2], ProcessError> {
        self.calls += 1;
        let key = |f: f64| (f * PHASE_KEY_STEPS).round() as u32;
        // Mark the kernels this call uses first, so building a missing one never replaces them.
        let now = self.calls;
        for (kind, phases) in wanted {
            for &f in phases {
                let q = key(f);
                if let Some(e) = self.phases.iter_mut().find(|e| e.kind == kind && e.q == q) {
                    e.used = now;
                }
            }
        }
        let keys: Vec<(usize, u32)> = wanted
            .iter()
            .flat_map(|&(kind, phases)| phases.iter().map(move |&f| kernel_key(kind, key(f))))
            .collect();
        self.prebuild(&keys)?;
        let mut get = |kind: usize, phases: &[f64]| -> Result<Vec<usize>, ProcessError> {
            phases
                .iter()
                .map(|&f| self.phase_kernel(kind, key(f)))
                .collect()
        };
        let x = get(wanted[0].0, wanted[0].1)?;
        let y = get(wanted[1].0, wanted[1].1)?;
        Ok([x, y])
    }

    /// Removal (nm) on the map grid of a path (optional per-sample rate weights).
    pub fn removal(
        &mut self,
        path: &PathLog,
        weights: Option<&[f64]>,
    ) -> Result<Array2<f64>, ProcessError> {
        self.with_steps(path, weights, |w, steps, lines| {
            w.removal_of_steps(steps, lines)
        })?
    }

    /// The dwell side of the removals of `terms` (path, optional rate weights) at full
    /// fidelity, transformed once (see [`DwellSpectra`]). An error, with nothing kept, once
    /// the spectra would take more than `max_bytes` (a spectrum per dwell map with dwell: a
    /// raster's line phases, or the phase nodes of a path whose lines spread, per term).
    pub fn dwell_spectra(
        &mut self,
        terms: &[(&PathLog, Option<&[f64]>)],
        max_bytes: usize,
    ) -> Result<DwellSpectra, ProcessError> {
        let fidelity = self.fidelity;
        self.fidelity = Fidelity::Full;
        let spectrum_bytes = self.conv.fft().spectrum_len() * std::mem::size_of::<Complex<f64>>();
        let mut spectra = Vec::with_capacity(terms.len());
        let mut bytes = 0usize;
        let mut failed = None;
        for (path, weights) in terms {
            match self.with_steps(path, *weights, |w, steps, lines| {
                w.dwell_spectra_of_steps(steps, lines)
            }) {
                Ok(term) => {
                    bytes += term.len() * spectrum_bytes;
                    spectra.push(term);
                    if bytes > max_bytes {
                        failed = Some(ProcessError::invalid(format!(
                            "the dwell spectra of {} terms would take more than {} MB",
                            terms.len(),
                            max_bytes >> 20
                        )));
                        break;
                    }
                }
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            }
        }
        self.fidelity = fidelity;
        if let Some(e) = failed {
            return Err(e);
        }
        let (n0, n1) = self.conv.fft().shape();
        Ok(DwellSpectra {
            grid: self.grid,
            ext: self.ext,
            h: self.h,
            half: self.half,
            fft_shape: (n0, n1),
            terms: spectra,
            response: self.response,
        })
    }

    /// `f` of the sub-steps of `path` weighted by `weights` (the walk kept between calls, see
    /// `walk`) and their line phases.
    fn with_steps<T>(
        &mut self,
        path: &PathLog,
        weights: Option<&[f64]>,
        f: impl FnOnce(&mut Self, &[SubStep], &[Lines; 2]) -> T,
    ) -> Result<T, ProcessError> {
        check_weights(path, weights)?;
        if self.walked.as_ref() != Some(path) {
            self.walk_path(path);
        }
        let walk = std::mem::take(&mut self.walk);
        let phases = std::mem::take(&mut self.walk_phases);
        let out = match weights {
            // The walk's own dwell is `dt` times a unit weight.
            None => f(self, &walk, &phases),
            Some(_) => {
                // Sub-steps of weight zero add nothing and are left out: rate terms with
                // compact support (a raster line, a time window, a knot of a rate map) then
                // splat only their own dwell and mark only their own rows for the transforms.
                let mut steps = std::mem::take(&mut self.steps);
                steps.clear();
                steps.extend(walk.iter().zip(&self.walk_at).filter_map(|(st, &(k, fr))| {
                    let w = st.dt * weight_at(weights, k, fr);
                    (w != 0.0).then_some(SubStep { w, ..*st })
                }));
                let out = f(self, &steps, &phases);
                self.steps = steps;
                out
            }
        };
        self.walk = walk;
        self.walk_phases = phases;
        Ok(out)
    }

    /// Walks `path` on the grown grid into `walk` / `walk_at` (unweighted) and keeps a copy.
    fn walk_path(&mut self, path: &PathLog) {
        let (steps, at) = (&mut self.walk, &mut self.walk_at);
        steps.clear();
        at.clear();
        for_each_motion_substep(path, None, &self.ext, |u, v, w, dt, mut shares, k, fr| {
            at.push((k, fr));
            // A motion's minor share (a logged line's jitter across it, a step-over's drift
            // along the lines) goes with the major motion: its kernel and line phase.
            if shares[1] > 0.0 && shares[2] > 0.0 {
                if shares[1] < MINOR_SHARE {
                    shares = [0.0, 0.0, 1.0];
                } else if shares[2] < MINOR_SHARE {
                    shares = [0.0, 1.0, 0.0];
                }
            }
            steps.push(SubStep {
                u,
                v,
                w,
                dt,
                shares,
            })
        });
        self.walk_phases = [line_phases(steps, 1), line_phases(steps, 2)];
        self.walked = Some(path.clone());
    }

    /// Removal of `steps` (a weighting of the walk) whose line phases are `[px, py]`.
    fn removal_of_steps(
        &mut self,
        steps: &[SubStep],
        lines: &[Lines; 2],
    ) -> Result<Array2<f64>, ProcessError> {
        let plan = self.plan(lines);
        let [sx, sy] = self.phase_kernels([
            (plan.kind[0], &plan.wanted[0]),
            (plan.kind[1], &plan.wanted[1]),
        ])?;
        let (maps, hit) = self.splat(steps, lines, &plan);
        let base: Vec<(usize, u32)> = (0..3)
            .filter(|&t| maps[t].is_some())
            .map(|t| (t, 0))
            .collect();
        self.prebuild(&base)?;
        // Convolver index of each target with dwell.
        let mut idx = vec![usize::MAX; maps.len()];
        for (t, m) in maps.iter().enumerate() {
            if m.is_some() {
                idx[t] = match t {
                    0..3 => self.base_kernel(t)?,
                    _ if t < 3 + sx.len() => sx[t - 3],
                    _ => sy[t - 3 - sx.len()],
                };
            }
        }
        // Summed in target order, whichever convolver slots the kernels took: a removal's
        // bits do not depend on the calls before it (which phases were built, and where).
        // Only the rows a map has dwell in are read (a large fresh map's other pages are never
        // touched).
        let views: Vec<crate::fft::HintedInput> = maps
            .iter()
            .enumerate()
            .filter_map(|(t, m)| {
                m.as_ref()
                    .map(|a| (idx[t], a.view(), Some(&hit[t].rows[..])))
            })
            .collect();
        let shape = (self.grid.rows, self.grid.cols);
        let out = self.conv.apply_sum_window_hinted(&views, self.h, shape);
        self.back_to_pool(maps, &hit);
        // Every kernel this removal needed has taken its prebuilt spectrum; none is kept.
        self.prebuilt.clear();
        Ok(out)
    }

    /// The dwell maps of `steps` by kernel (see [`Plan`]), transformed: per map with dwell, the
    /// key of its kernel and its spectrum, in target order.
    fn dwell_spectra_of_steps(
        &mut self,
        steps: &[SubStep],
        lines: &[Lines; 2],
    ) -> Vec<KeyedSpectrum> {
        let plan = self.plan(lines);
        let (maps, hit) = self.splat(steps, lines, &plan);
        let nx = plan.wanted[0].len();
        let key = |f: f64| (f * PHASE_KEY_STEPS).round() as u32;
        let out = maps
            .iter()
            .enumerate()
            .filter_map(|(t, m)| {
                let m = m.as_ref()?;
                let k = match t {
                    0..3 => (t, 0),
                    _ if t < 3 + nx => kernel_key(plan.kind[0], key(plan.wanted[0][t - 3])),
                    _ => kernel_key(plan.kind[1], key(plan.wanted[1][t - 3 - nx])),
                };
                Some((
                    k,
                    self.conv.input_spectrum(m.view(), Some(&hit[t].rows[..])),
                ))
            })
            .collect();
        self.back_to_pool(maps, &hit);
        out
    }

    /// The maps back to the pool, zeroed (as many as it keeps).
    fn back_to_pool(&mut self, maps: Vec<Option<Array2<f64>>>, hit: &[RowSpan]) {
        let (rows, cols) = (self.ext.rows, self.ext.cols);
        let most =
            (POOLED_MAP_BYTES / (8 * rows * cols).max(1)).clamp(MIN_POOLED_MAPS, MAX_POOLED_MAPS);
        for (m, span) in maps.into_iter().zip(hit) {
            if let Some(mut m) = m {
                if self.pool.len() < most {
                    span.zero(&mut m);
                    self.pool.push(m);
                }
            }
        }
    }

    /// Which kernels the dwell of a walk with line phases `lines` goes to.
    fn plan(&self, lines: &[Lines; 2]) -> Plan {
        // Dwell moving along X (Y) goes to its row (column) with the kernel of its line's
        // sub-row (sub-column) phase; when a path has too many line phases, or they spread,
        // it is shared linearly between kernels at the fixed phases j / PHASE_NODES instead.
        let nodes: Vec<f64> = (0..PHASE_NODES)
            .map(|j| j as f64 / PHASE_NODES as f64)
            .collect();
        // Screening puts a spread motion on its centred kernel (see `Fidelity::Screening`).
        let centred = [0, 1]
            .map(|k| self.fidelity == Fidelity::Screening && matches!(lines[k], Lines::Spread));
        let wanted = |k: usize| -> Vec<f64> {
            match &lines[k] {
                _ if centred[k] => Vec::new(),
                Lines::Phases(lp) => lp.phase.clone(),
                Lines::Spread => nodes.clone(),
            }
        };
        // A minor motion's lines take point-sampled kernels (kinds 3 and 4).
        let kind_of = |k: usize| match &lines[k - 1] {
            Lines::Phases(lp) if lp.minor => k + 2,
            _ => k,
        };
        Plan {
            wanted: [wanted(0), wanted(1)],
            kind: [kind_of(1), kind_of(2)],
            centred,
        }
    }

    /// `steps` splatted onto the dwell maps of `plan`'s targets: 0..3 the centred kernels
    /// (resting, along X, along Y), then the phase kernels of along-X and of along-Y lines
    /// (`None` where a target has no dwell), with the rows each map has dwell in.
    fn splat(
        &mut self,
        steps: &[SubStep],
        lines: &[Lines; 2],
        plan: &Plan,
    ) -> (Vec<Option<Array2<f64>>>, Vec<RowSpan>) {
        let centred = plan.centred;
        let (nx, ny) = (plan.wanted[0].len(), plan.wanted[1].len());
        // Where each motion's stray dwell (off its lines, or a minor share of a sub-step) goes:
        // with one motion minor, onto the point-sampled kernel (see MINOR_MOTION_SHARE), else
        // onto its own motion's centred kernel.
        let minor = [
            matches!(&lines[0], Lines::Phases(lp) if lp.minor),
            matches!(&lines[1], Lines::Phases(lp) if lp.minor),
        ];
        let one_minor = minor[0] != minor[1];
        let sink = |kind: usize| -> usize {
            if one_minor {
                0
            } else {
                kind
            }
        };
        let (rows, cols) = (self.ext.rows, self.ext.cols);
        let mut maps: Vec<Option<Array2<f64>>> = vec![None; 3 + nx + ny];
        // Rows each map has dwell in (a raster's phase map holds one row per line): only these
        // are zeroed again for the pool.
        let mut hit: Vec<RowSpan> = vec![RowSpan::default(); maps.len()];
        let pool = &mut self.pool;
        // The map of target `t`, its rows from `i0` to `i1` (clamped to the grid) marked.
        macro_rules! get {
            ($t:expr, $i0:expr, $i1:expr) => {{
                let m = pooled(&mut maps[$t], &mut hit[$t], pool, (rows, cols));
                hit[$t].mark($i0, $i1, m);
                m
            }};
        }
        // A cubic splat's rows about fractional row `u`.
        let taps = |u: f64| {
            let i = u.floor() as isize;
            (i - 1, i + 2)
        };
        for st in steps {
            let (u, v, w, shares) = (st.u, st.v, st.w, st.shares);
            let (c0, c1) = taps(u);
            if shares[0] > 0.0 {
                splat_cubic(get!(0, c0, c1), u, v, w * shares[0]);
            }
            for kind in [1, 2] {
                let share = shares[kind];
                if share <= 0.0 {
                    continue;
                }
                let (n, f, b) = row_phase(across_of(kind, u, v));
                let base = if kind == 1 { 3 } else { 3 + nx };
                let along = if kind == 1 { v } else { u };
                let put = |d: &mut Array2<f64>, n: isize, w: f64| {
                    if kind == 1 {
                        splat_cubic_row(d, n, along, w);
                    } else {
                        splat_cubic_col(d, along, n, w);
                    }
                };
                // Rows a `put` on lane `n` reaches: that row (along X), or the cubic taps about
                // row `u` (along Y).
                let lane = |n: isize| if kind == 1 { (n, n) } else { (c0, c1) };
                match &lines[kind - 1] {
                    _ if centred[kind - 1] => splat_cubic(get!(kind, c0, c1), u, v, w * share),
                    _ if share < MINOR_SHARE => {
                        splat_cubic(get!(sink(kind), c0, c1), u, v, w * share)
                    }
                    Lines::Phases(lp) => match lp.bin_cluster[b] {
                        u8::MAX => splat_cubic(get!(sink(kind), c0, c1), u, v, w * share),
                        c => {
                            let (i0, i1) = lane(n);
                            put(get!(base + c as usize, i0, i1), n, w * share)
                        }
                    },
                    Lines::Spread => {
                        // Across the motion: `n` whole pixels plus phase `f`.
                        let x = f * PHASE_NODES as f64;
                        let j = (x.floor() as usize).min(PHASE_NODES - 1);
                        let t = x - j as f64;
                        let (i0, i1) = lane(n);
                        put(get!(base + j, i0, i1), n, w * share * (1.0 - t));
                        if j + 1 < PHASE_NODES {
                            put(get!(base + j + 1, i0, i1), n, w * share * t);
                        } else {
                            let (i0, i1) = lane(n + 1);
                            put(get!(base, i0, i1), n + 1, w * share * t);
                        }
                    }
                }
            }
        }
        (maps, hit)
    }
}

/// Which kernels a walk's dwell goes to: per motion (along X, along Y), the line phases that
/// get a kernel of their own, the kernel kind (1, 2 box kernels; 3, 4 point-sampled for a
/// minor motion), and whether the motion goes onto its centred kernel only (screening).
struct Plan {
    wanted: [Vec<f64>; 2],
    kind: [usize; 2],
    centred: [bool; 2],
}

/// The spectra of the kernels `keys` ([`kernel_key`]) of `field` on `grid`'s pixel with
/// point-sampled half-widths `half`, for transforms of `fft`'s size: side by side, each with
/// scratch of its own (the same bits as building them one at a time), in the order of `keys`.
fn build_spectra(
    keys: &[(usize, u32)],
    field: &dyn RateField,
    fft: &crate::fft::Fft2,
    grid: &Grid,
    half: (usize, usize),
) -> Result<Vec<KeyedHat>, ProcessError> {
    use rayon::prelude::*;
    keys.par_iter()
        .map(|&key| {
            let t = kernel_of(key, field, grid.dx_mm, grid.dy_mm, half)?;
            Ok((
                key,
                Arc::new(crate::fft::kernel_hat(fft, t.rate_nm_per_s.view())),
            ))
        })
        .collect()
}

/// The key of the kernel of motion `kind` at phase key `q` (phase 0 is the centred kernel of
/// the motion: resting for the point-sampled kinds).
fn kernel_key(kind: usize, q: u32) -> (usize, u32) {
    if q == 0 {
        (if kind > 2 { 0 } else { kind }, 0)
    } else {
        (kind, q)
    }
}

/// The kernel of `key` ([`kernel_key`]) of `field` on a pixel `dx` x `dy` with half-widths
/// `half`: the centred kernels `(m, 0)` of motion m (resting, along X, along Y), the along-X and
/// along-Y line kernels `(1, q)`, `(2, q)` and the point-sampled ones `(3, q)`, `(4, q)` at
/// phase `q / PHASE_KEY_STEPS` of a pixel.
fn kernel_of(
    key: (usize, u32),
    f: &dyn RateField,
    dx: f64,
    dy: f64,
    half: (usize, usize),
) -> Result<Tif, ProcessError> {
    let ph = key.1 as f64 / PHASE_KEY_STEPS;
    match key {
        (m, 0) if m < 3 => {
            let motion = [Motion::Resting, Motion::AlongX, Motion::AlongY][m];
            kernel_from_field(f, dx, dy, motion, half)
        }
        (1, _) => along_x_at_phase_sized(f, dx, dy, ph, half),
        (2, _) => along_y_at_phase_sized(f, dx, dy, ph, half),
        (kind, _) => point_at_phase_sized(f, dx, dy, ph, kind == 3, half),
    }
}

/// The rows of a dwell map that may hold dwell (a bitmap, sized on first mark), and whether the
/// map is fresh memory whose rows are written with zeros as they are first marked.
#[derive(Debug, Clone, Default)]
struct RowSpan {
    rows: Vec<bool>,
    fresh: bool,
}

impl RowSpan {
    /// Marks rows `i0..=i1` of `m` (those inside it). On a fresh map a row's zeros are written
    /// when it is first marked: its pages are then faulted in once, by a write. Left to the
    /// splat, which adds (reads before it writes), a page would first map the shared zero page
    /// and then be copied on the write, which flushes the TLB of every thread of the process
    /// (at 800^2 that double fault was 8 % of a calibration's samples).
    #[inline]
    fn mark(&mut self, i0: isize, i1: isize, m: &mut Array2<f64>) {
        let rows = m.nrows();
        if self.rows.is_empty() {
            self.rows.resize(rows, false);
        }
        let lo = i0.max(0) as usize;
        let hi = (i1 + 1).clamp(0, rows as isize) as usize;
        for r in lo..hi {
            if !self.rows[r] {
                self.rows[r] = true;
                if self.fresh {
                    m.row_mut(r).fill(0.0);
                }
            }
        }
    }

    /// Zeroes the marked rows of `m` (the others hold no dwell).
    fn zero(&self, m: &mut Array2<f64>) {
        for (i, _) in self.rows.iter().enumerate().filter(|(_, h)| **h) {
            m.row_mut(i).fill(0.0);
        }
    }
}

/// The map in `slot`, taken from `pool` (zeroed) or allocated on first use. A small new map's
/// zeros are written, not left to fresh pages: the splat adds to a map (reads before it
/// writes), and a page first read is the shared zero page, whose copy on the first write
/// flushes the TLB of every thread of the process. A large one (beyond
/// [`WRITTEN_ZEROS_BYTES`]) keeps its fresh pages and is marked fresh in `span`: its rows'
/// zeros are written as the splat first reaches them ([`RowSpan::mark`]); a raster touches a
/// few rows of a phase map, and writing the rest would cost more than it saves.
fn pooled<'a>(
    slot: &'a mut Option<Array2<f64>>,
    span: &mut RowSpan,
    pool: &mut Vec<Array2<f64>>,
    dim: (usize, usize),
) -> &'a mut Array2<f64> {
    slot.get_or_insert_with(|| {
        pool.pop().unwrap_or_else(|| {
            let n = dim.0 * dim.1;
            if 8 * n > WRITTEN_ZEROS_BYTES {
                span.fresh = true;
                return Array2::zeros(dim);
            }
            let mut v: Vec<f64> = Vec::with_capacity(n);
            v.resize(n, 0.0);
            Array2::from_shape_vec(dim, v).expect("the length is rows x cols")
        })
    })
}

/// Largest new dwell map whose zeros are written at allocation (bytes; see [`pooled`]).
const WRITTEN_ZEROS_BYTES: usize = 2 << 20;

/// Options of the exact deposition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExactOptions {
    /// Longest sub-step in mm (default: a quarter of the smaller pixel side, and at most 1/80 of
    /// the footprint's smaller half-extent). Why the second bound: along the path the midpoint
    /// rule meets the footprint's edge, where a Hertz-like sqrt(1 - r^2/a^2) profile makes its
    /// error scale as (step / a)^1.5 rather than step^2. On a 100 mm raster with the paper's
    /// bonnet (a = 4.86 mm) at 0.5 mm pixels, quarter-pixel steps leave 0.43 % of the removal
    /// RMS against a 0.025 mm reference, a/80 leaves about 0.1 %.
    pub max_step_mm: Option<f64>,
    /// Longest sub-step in s (so a tool resting in place is still sub-stepped in time).
    pub max_dt_s: f64,
}

impl Default for ExactOptions {
    fn default() -> Self {
        ExactOptions {
            max_step_mm: None,
            max_dt_s: 1.0,
        }
    }
}

/// Most sub-steps [`deposit_exact`] walks (about a second of walking).
const EXACT_MAX_SUBSTEPS: f64 = 1e9;
/// Most pixel updates (sub-steps on the grid times footprint pixels) [`deposit_exact`] does
/// (a few seconds on two cores).
const EXACT_MAX_PIXEL_UPDATES: f64 = 4e9;

/// Exact time-domain deposition: removal (nm) on `grid` of the rate field moved along the path,
/// the rate times `weights` (linear between samples). The one exact deposition,
/// [`crate::modulated::deposit_exact_modulated`], with the weight as its rate factor.
/// Refused, before anything is allocated, when the walk would exceed the limits above.
pub fn deposit_exact(
    path: &PathLog,
    field: &dyn RateField,
    grid: &Grid,
    weights: Option<&[f64]>,
    opts: &ExactOptions,
) -> Result<Array2<f64>, ProcessError> {
    check_weights(path, weights)?;
    crate::modulated::deposit_exact_modulated(path, field, grid, opts, |s| {
        crate::modulated::Modulation {
            rate: weight_at(weights, s.segment, s.fraction),
            ..Default::default()
        }
    })
}

/// The exact deposition's sub-step (mm): `opts.max_step_mm`, else a quarter pixel and 1/80 of
/// the footprint's smaller half-extent.
pub fn exact_step(
    field: &dyn RateField,
    grid: &Grid,
    opts: &ExactOptions,
) -> Result<f64, ProcessError> {
    let (ex, ey) = field.half_extent_mm();
    let step = opts.max_step_mm.unwrap_or_else(|| {
        let pixel = 0.25 * grid.dx_mm.min(grid.dy_mm);
        let edge = ex.min(ey) / 80.0;
        if edge > 0.0 {
            pixel.min(edge)
        } else {
            pixel
        }
    });
    if !(step > 0.0 && step.is_finite()) {
        return Err(ProcessError::invalid("exact sub-step must be positive"));
    }
    Ok(step)
}

/// Refuses, before anything is allocated, an exact deposition that would walk too many
/// sub-steps or update too many pixels (footprint half-extents `(ex, ey)` mm).
pub fn check_exact_budget(
    path: &PathLog,
    grid: &Grid,
    step: f64,
    opts: &ExactOptions,
    (ex, ey): (f64, f64),
) -> Result<(), ProcessError> {
    let (xlo, xhi) = (grid.x0_mm - ex, grid.x_mm(grid.cols - 1) + ex);
    let (ylo, yhi) = (grid.y0_mm - ey, grid.y_mm(grid.rows - 1) + ey);
    // Count before allocating or depositing: every sub-step the walk visits, and (an upper
    // bound) those on segments whose box meets the grid plus the footprint, each of which
    // touches one footprint of pixels. A log resting for days or a footprint of millions of
    // pixels is refused here, in microseconds, instead of exhausting memory or time.
    let (mut walked, mut inside) = (0.0_f64, 0.0_f64);
    for k in 0..path.len().saturating_sub(1) {
        let (x0, y0, x1, y1) = (
            path.x_mm[k],
            path.y_mm[k],
            path.x_mm[k + 1],
            path.y_mm[k + 1],
        );
        let m = crate::path::substeps(
            (x1 - x0).hypot(y1 - y0),
            path.t_s[k + 1] - path.t_s[k],
            step,
            opts.max_dt_s,
        ) as f64;
        walked += m;
        if x0.max(x1) >= xlo && x0.min(x1) <= xhi && y0.max(y1) >= ylo && y0.min(y1) <= yhi {
            inside += m;
        }
    }
    let footprint =
        ((2.0 * ex / grid.dx_mm).floor() + 1.0) * ((2.0 * ey / grid.dy_mm).floor() + 1.0);
    if walked > EXACT_MAX_SUBSTEPS || inside * footprint > EXACT_MAX_PIXEL_UPDATES {
        return Err(ProcessError::invalid(format!(
            "exact deposition would need {walked:.3e} sub-steps of at most {step:.3e} mm and \
             {max_dt:.3e} s, {:.3e} pixel updates (limits {EXACT_MAX_SUBSTEPS:.0e} and \
             {EXACT_MAX_PIXEL_UPDATES:.0e}): the path rests or runs too long for the exact \
             method; use the fast method",
            inside * footprint,
            max_dt = opts.max_dt_s,
        )));
    }
    Ok(())
}

/// Adds `w` times the rate at every pixel within (ex, ey) mm of the tool centre (x, y);
/// `rate(dx, dy)` is evaluated at the pixel's offset from the centre. Shared by the exact
/// depositions (here and [`crate::modulated::deposit_exact_modulated`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn deposit_one(
    acc: &mut Array2<f64>,
    g: &Grid,
    rate: impl Fn(f64, f64) -> f64,
    x: f64,
    y: f64,
    w: f64,
    ex: f64,
    ey: f64,
) {
    let j0 = ((x - ex - g.x0_mm) / g.dx_mm).ceil().max(0.0) as usize;
    let j1 = ((x + ex - g.x0_mm) / g.dx_mm)
        .floor()
        .min(g.cols as f64 - 1.0);
    let i0 = ((y - ey - g.y0_mm) / g.dy_mm).ceil().max(0.0) as usize;
    let i1 = ((y + ey - g.y0_mm) / g.dy_mm)
        .floor()
        .min(g.rows as f64 - 1.0);
    if j1 < 0.0 || i1 < 0.0 {
        return;
    }
    for i in i0..=i1 as usize {
        let oy = g.y_mm(i) - y;
        let mut row = acc.row_mut(i);
        for j in j0..=j1 as usize {
            row[j] += w * rate(g.x_mm(j) - x, oy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::path::RasterSpec;
    use crate::tif::GaussianTif;

    #[test]
    fn dwell_map_conserves_time_and_centroid() {
        let grid = Grid::new(40, 50, 0.5, 0.5, 0.0, 0.0).unwrap();
        let p = PathLog::new(
            vec![0.0, 3.0, 4.0],
            vec![5.0, 15.0, 15.0],
            vec![5.0, 7.0, 12.0],
        )
        .unwrap();
        let d = dwell_map(&p, None, &grid);
        assert!((d.sum() - 4.0).abs() < 1e-12);
        let w = [1.0, 3.0, 3.0];
        let dw = dwell_map(&p, Some(&w), &grid);
        // First segment averages weight 2 over 3 s, second weight 3 over 1 s.
        assert!((dw.sum() - 9.0).abs() < 1e-9);
        // The cubic splat keeps mass, centroid and second moment of a point.
        let q = PathLog::new(vec![0.0, 1.0], vec![7.3, 7.3], vec![4.15, 4.15]).unwrap();
        let c = dwell_map_with(&q, None, &grid, Splat::Cubic);
        let (mut m0, mut m1, mut m2) = (0.0, 0.0, 0.0);
        for ((i, _), &v) in c.indexed_iter() {
            let y = grid.y_mm(i);
            m0 += v;
            m1 += v * y;
            m2 += v * (y - 4.15).powi(2);
        }
        assert!((m0 - 1.0).abs() < 1e-12 && (m1 - 4.15).abs() < 1e-12 && m2.abs() < 1e-12);
    }

    #[test]
    fn resting_tool_removes_one_tif_times_dwell() {
        let grid = Grid::new(61, 61, 0.25, 0.25, -7.5, -7.5).unwrap();
        let g = GaussianTif::new(1.5, 10.0, 2.0).unwrap();
        let tif = Tif::sample(&g, 0.25, 0.25).unwrap();
        let p = PathLog::new(vec![0.0, 10.0], vec![0.0, 0.0], vec![0.0, 0.0]).unwrap();
        let fast = FastRemoval::new(&tif, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        let exact = deposit_exact(&p, &g, &grid, None, &ExactOptions::default()).unwrap();
        assert!((fast[(30, 30)] - 20.0).abs() < 1e-9);
        assert!((exact[(30, 30)] - 20.0).abs() < 1e-9);
        assert!((exact[(30, 36)] - 20.0 * (-1.5f64 * 1.5 / 4.5).exp()).abs() < 1e-9);
        let dmax = (&fast - &exact).iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(dmax < 1e-9);
    }

    /// A 60 x 80 grid at 0.5 mm, a Gaussian truncated at 3 sigma, and a raster (lines every
    /// 1.7 mm along X) whose feed realises a dwell bump: the grid, the TIF, the dwell grid, the
    /// dwell density, the kinematic limits and the path.
    fn bump_raster() -> (
        Grid,
        GaussianTif,
        Grid,
        Array2<f64>,
        crate::path::kinematics::Limits,
        PathLog,
    ) {
        let grid = Grid::new(60, 80, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let dgrid = grid.grown(20, 20);
        let dens = Array2::from_shape_fn((dgrid.rows, dgrid.cols), |(i, j)| {
            let (x, y) = (dgrid.x_mm(j) - 20.0, dgrid.y_mm(i) - 15.0);
            0.3 * (1.0 + 0.6 * (-(x * x + y * y) / 50.0).exp())
        });
        let r = RasterSpec::over_rect((-6.0, 46.0), (-6.0, 36.0), 1.7, 2.0);
        let lim = crate::path::kinematics::Limits::default();
        let (p, _) = crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2).unwrap();
        (grid, g, dgrid, dens, lim, p)
    }

    #[test]
    fn area_pixels_match_the_pixel_means_of_exact_deposition() {
        // The paper's bonnet (square-root rim, 2.8 mm contact radius) on 0.25 mm pixels, a
        // raster at a 1.7 mm pitch: exact deposition on a grid six times finer, averaged over
        // each map pixel's 6 x 6 sub-pixels, is what a camera pixel reports. The fast removal
        // with the area response must match it far better than the point-sampled one does.
        let p = crate::tif::BonnetTifParams::paper(10.0);
        let b = crate::tif::bonnet::BonnetTif::new(&p).unwrap();
        let (dx, k) = (0.25, 6usize);
        let (rows, cols) = (48, 56);
        let grid = Grid::new(rows, cols, dx, dx, 0.0, 0.0).unwrap();
        let fine = Grid::new(
            rows * k,
            cols * k,
            dx / k as f64,
            dx / k as f64,
            -0.5 * dx + 0.5 * dx / k as f64,
            -0.5 * dx + 0.5 * dx / k as f64,
        )
        .unwrap();
        let r = RasterSpec::over_rect((-4.0, 18.0), (-4.0, 16.0), 1.7, 2.0);
        let path = r.generate().unwrap();
        let exact_fine = deposit_exact(&path, &b, &fine, None, &ExactOptions::default()).unwrap();
        let means = Array2::from_shape_fn((rows, cols), |(i, j)| {
            exact_fine
                .slice(ndarray::s![i * k..(i + 1) * k, j * k..(j + 1) * k])
                .mean()
                .unwrap()
        });
        let at_centres = deposit_exact(&path, &b, &grid, None, &ExactOptions::default()).unwrap();
        let area = FastRemoval::from_field_seen(&b, &grid, PixelResponse::area(dx, dx))
            .unwrap()
            .removal(&path, None)
            .unwrap();
        let point = FastRemoval::from_field(&b, &grid)
            .unwrap()
            .removal(&path, None)
            .unwrap();
        let drms = |a: &Array2<f64>, b: &Array2<f64>| {
            ((a - b).iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt()
        };
        // The box matters here: pixel means and centre values differ.
        let effect = drms(&means, &at_centres);
        let mean = means.mean().unwrap();
        assert!(effect > 5e-4 * mean, "box effect {effect} vs mean {mean}");
        let d_area = drms(&area, &means);
        let d_point = drms(&point, &means);
        // Measured: box effect 0.107 nm RMS (of a 153 nm mean), area 0.010, point 0.106.
        assert!(
            d_area < 0.15 * effect && d_area < 0.15 * d_point,
            "area {d_area}, point {d_point}, box effect {effect}"
        );
        // The area model is as close to the camera's pixels as the point model is to the
        // centre values (0.021 nm: the fast model's own discretisation).
        let d_centres = drms(&point, &at_centres);
        assert!(
            d_area < d_centres,
            "area {d_area}, point at centres {d_centres}"
        );
    }

    #[test]
    fn fast_and_exact_agree_on_a_raster() {
        // A raster whose feed realises a dwell bump, so the removal has a shape (RMS ~ 10 %
        // of its mean); a Gaussian truncated at 3 sigma, so the hard edge is exercised.
        let (grid, g, dgrid, dens, lim, p) = bump_raster();
        let tif = Tif::sample_antialiased(&g, 0.5, 0.5).unwrap();
        // Lines every 1.7 mm on 0.5 mm pixels: five sub-row phases, each with its own kernel.
        let fast = FastRemoval::from_field(&g, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        let exact = deposit_exact(&p, &g, &grid, None, &ExactOptions::default()).unwrap();
        let mean = exact.mean().unwrap();
        let rms =
            (exact.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / exact.len() as f64).sqrt();
        let drms = |a: &Array2<f64>, b: &Array2<f64>| {
            ((a - b).iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt()
        };
        assert!(rms > 0.05 * mean, "{rms} {mean}");
        let d = drms(&fast, &exact);
        assert!(d < 0.002 * rms, "diff {d} vs removal rms {rms}");
        // A sampled TIF against exact deposition of that same sampled TIF (bilinear inside
        // its window), as for a measured spot.
        let fast_t = FastRemoval::new(&tif, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        let exact_t = deposit_exact(&p, &tif, &grid, None, &ExactOptions::default()).unwrap();
        let d = drms(&fast_t, &exact_t);
        assert!(d < 0.002 * rms, "sampled: diff {d} vs removal rms {rms}");
        // A logged path whose lines wander by a few um: every sample has its own sub-row
        // phase, so phases are grouped in bins (here 1/256 row = 2 um).
        let mut rng = bonnetlab_surface::rng::Rng::new(11);
        let mut q = p.clone();
        q.y_mm
            .iter_mut()
            .for_each(|y| *y += 0.003 * (rng.uniform() - 0.5));
        let fast_q = FastRemoval::from_field(&g, &grid)
            .unwrap()
            .removal(&q, None)
            .unwrap();
        let exact_q = deposit_exact(&q, &g, &grid, None, &ExactOptions::default()).unwrap();
        let d = drms(&fast_q, &exact_q);
        assert!(
            d < 0.002 * rms,
            "wandering lines: diff {d} vs removal rms {rms}"
        );
        // Lines every 1.55 mm on 0.5 mm pixels: ten sub-row phases, more than get their own
        // kernels, so the dwell is shared linearly between the fixed phase kernels.
        let r = RasterSpec::over_rect((-6.0, 46.0), (-6.0, 36.0), 1.55, 2.0);
        let (p, _) = crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2).unwrap();
        let fast_n = FastRemoval::from_field(&g, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        let exact_n = deposit_exact(&p, &g, &grid, None, &ExactOptions::default()).unwrap();
        let mean_n = exact_n.mean().unwrap();
        let rms_n = drms(&exact_n, &Array2::from_elem(exact_n.dim(), mean_n));
        let d = drms(&fast_n, &exact_n);
        assert!(
            d < 0.005 * rms_n,
            "many phases: diff {d} vs removal rms {rms_n}"
        );
        // Scanned along Y, lines every 1.7 mm between pixel columns: per-column-phase kernels.
        let mut r = RasterSpec::over_rect((-6.0, 46.0), (-6.0, 36.0), 1.7, 2.0);
        r.axis = crate::path::ScanAxis::Y;
        r.scan_range_mm = (-6.0, 36.0);
        r.step_range_mm = (-6.0, 46.0);
        let (p, _) = crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2).unwrap();
        let fast_y = FastRemoval::from_field(&g, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        let exact_y = deposit_exact(&p, &g, &grid, None, &ExactOptions::default()).unwrap();
        let mean_y = exact_y.mean().unwrap();
        let rms_y = drms(&exact_y, &Array2::from_elem(exact_y.dim(), mean_y));
        let d = drms(&fast_y, &exact_y);
        assert!(rms_y > 0.05 * mean_y);
        assert!(
            d < 0.002 * rms_y,
            "along Y: diff {d} vs removal rms {rms_y}"
        );
    }

    #[test]
    fn screening_is_the_full_model_on_a_raster_and_one_kernel_per_motion_on_a_wiggled_path() {
        // A raster with five line phases (1.7 mm pitch on 0.5 mm pixels): screening gives the
        // full model's bits. The same raster wiggled across its lines (0.3 mm at a 7 mm period
        // along x): its phases spread, the full model shares the dwell between the fixed phase
        // nodes, screening splats it onto the centred kernels. Both against exact deposition.
        let (grid, g, _, _, _, p) = bump_raster();
        let run = |path: &PathLog, fidelity: Fidelity| {
            let mut f = FastRemoval::from_field(&g, &grid).unwrap();
            f.set_fidelity(fidelity);
            assert!(!f.fidelity_free(), "nothing walked yet");
            let out = f.removal(path, None).unwrap();
            (
                out,
                f.fft_count(),
                f.phase_kernel_builds(),
                f.fidelity_free(),
            )
        };
        let (full, _, builds, free) = run(&p, Fidelity::Full);
        let (screen, _, _, _) = run(&p, Fidelity::Screening);
        assert!(builds >= 3, "{builds}");
        assert!(free, "a raster's lines keep their phases");
        assert_eq!(full, screen);
        let mut q = p.clone();
        for (y, x) in q.y_mm.iter_mut().zip(&p.x_mm) {
            *y += 0.3 * (2.0 * std::f64::consts::PI * x / 7.0).sin();
        }
        let (full, full_ffts, _, free) = run(&q, Fidelity::Full);
        let (screen, screen_ffts, _, _) = run(&q, Fidelity::Screening);
        assert!(!free, "the wiggled raster's lines spread");
        let exact = deposit_exact(&q, &g, &grid, None, &ExactOptions::default()).unwrap();
        let mean = exact.mean().unwrap();
        let drms = |a: &Array2<f64>, b: &Array2<f64>| {
            ((a - b).iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt()
        };
        let rms = drms(&exact, &Array2::from_elem(exact.dim(), mean));
        let (d_full, d_screen) = (drms(&full, &exact), drms(&screen, &exact));
        eprintln!(
            "wiggled: removal rms {rms:.4}, full {d_full:.2e} ({full_ffts} FFTs), screening \
             {d_screen:.2e} ({screen_ffts} FFTs)"
        );
        assert!(d_full < 0.005 * rms, "full: {d_full} vs {rms}");
        assert!(d_screen < 0.015 * rms, "screening: {d_screen} vs {rms}");
        assert!(2 * screen_ffts < full_ffts, "{screen_ffts} vs {full_ffts}");
    }

    /// A raster at a 1.7 mm pitch over `grid` and `margin_mm` beyond it (uniform dwell density
    /// on the grid grown by `grow` pixels), wiggled 0.3 mm across its lines at a 7 mm period:
    /// its lines' phases spread.
    fn wiggled_raster(grid: &Grid, grow: usize, margin_mm: f64) -> PathLog {
        let dgrid = grid.grown(grow, grow);
        let dens = Array2::from_elem((dgrid.rows, dgrid.cols), 0.3);
        let (w, h) = (
            (grid.cols - 1) as f64 * grid.dx_mm,
            (grid.rows - 1) as f64 * grid.dy_mm,
        );
        let r = RasterSpec::over_rect(
            (grid.x0_mm - margin_mm, grid.x0_mm + w + margin_mm),
            (grid.y0_mm - margin_mm, grid.y0_mm + h + margin_mm),
            1.7,
            2.0,
        );
        let lim = crate::path::kinematics::Limits::default();
        let (mut p, _) =
            crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2).unwrap();
        let x = p.x_mm.clone();
        for (y, x) in p.y_mm.iter_mut().zip(&x) {
            *y += 0.3 * (2.0 * std::f64::consts::PI * x / 7.0).sin();
        }
        p
    }

    #[test]
    fn fresh_large_dwell_maps_give_the_bits_of_pooled_ones() {
        // Dwell maps beyond WRITTEN_ZEROS_BYTES come from fresh memory, their rows zeroed as the
        // splat first reaches them; the second call takes them from the pool. A wiggled raster
        // (phases spread: 19 maps) on 0.1 mm pixels (grown grid about 2.4 MB a map).
        let grid = Grid::new(400, 560, 0.1, 0.1, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let p = wiggled_raster(&grid, 70, 3.0);
        let mut f = FastRemoval::from_field(&g, &grid).unwrap();
        assert!(8 * f.dwell_grid().rows * f.dwell_grid().cols > WRITTEN_ZEROS_BYTES);
        let first = f.removal(&p, None).unwrap();
        let second = f.removal(&p, None).unwrap();
        assert!(first.iter().any(|v| *v > 0.0));
        assert_eq!(first, second);
    }

    #[test]
    fn kernels_built_side_by_side_are_the_ones_built_one_at_a_time() {
        // `build_spectra` (the first removal of a path whose lines spread, the TIF-scale scan)
        // against the convolver's own one-at-a-time build, whose scratch a wiggled raster's
        // removal has just filled: every kind of kernel, bit for bit.
        let grid = Grid::new(40, 50, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let p = wiggled_raster(&grid, 16, 6.0);
        let mut f = FastRemoval::from_field(&g, &grid).unwrap();
        assert!(f.removal(&p, None).unwrap().iter().any(|v| *v > 0.0));
        let q = |ph: f64| (ph * PHASE_KEY_STEPS).round() as u32;
        let keys = [
            (0, 0),
            (1, 0),
            (2, 0),
            (1, q(0.25)),
            (2, q(0.375)),
            (3, q(0.5)),
            (4, q(0.875)),
        ];
        let side = build_spectra(&keys, f.field.as_ref(), f.conv.fft(), &f.grid, f.half).unwrap();
        assert_eq!(side.len(), keys.len());
        for ((key, hat), want) in side.iter().zip(keys) {
            assert_eq!(*key, want);
            let t = kernel_of(want, f.field.as_ref(), 0.5, 0.5, f.half).unwrap();
            let one = f.conv.kernel_spectrum(t.rate_nm_per_s.view());
            assert_eq!(hat.len(), one.len());
            let same = hat
                .iter()
                .zip(one.iter())
                .all(|(a, b)| a.re.to_bits() == b.re.to_bits() && a.im.to_bits() == b.im.to_bits());
            assert!(same, "kernel {want:?} differs");
        }
        // A fresh workspace (its phase kernels built side by side) gives the removal of one
        // whose kernels were already there.
        let again = f.removal(&p, None).unwrap();
        let fresh = FastRemoval::from_field(&g, &grid)
            .unwrap()
            .removal(&p, None)
            .unwrap();
        assert_eq!(again, fresh);
    }

    #[test]
    fn no_prebuilt_spectrum_outlives_its_removal() {
        // Two workspaces sharing spectra: the second builds its kernels ahead, then the first
        // shares the same keys before the second takes them (as two callers side by side can).
        // The second's removal takes the shared ones, gives the same bits, and keeps nothing.
        let grid = Grid::new(40, 50, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let p = wiggled_raster(&grid, 16, 6.0);
        let shared = SharedSpectra::default();
        let mut a = FastRemoval::from_field(&g, &grid).unwrap();
        let mut b = FastRemoval::from_field(&g, &grid).unwrap();
        a.share_spectra(shared.clone());
        b.share_spectra(shared);
        let q = |ph: f64| (ph * PHASE_KEY_STEPS).round() as u32;
        let keys: Vec<(usize, u32)> = (1..PHASE_NODES)
            .map(|j| (1, q(j as f64 / PHASE_NODES as f64)))
            .collect();
        b.prebuild(&keys).unwrap();
        assert_eq!(b.prebuilt.len(), keys.len());
        let first = a.removal(&p, None).unwrap();
        let second = b.removal(&p, None).unwrap();
        assert!(b.prebuilt.is_empty(), "{} left", b.prebuilt.len());
        assert_eq!(first, second);
    }

    #[test]
    fn phase_kernels_are_kept_across_paths_and_calls() {
        // Two rasters whose line phases differ (1.7 mm pitch: five sub-row phases; 1.55 mm:
        // the fixed phase nodes) through one workspace, alternately: the kernels are built in
        // the first round only, and every result is the one a fresh workspace gives.
        let grid = Grid::new(40, 50, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let lim = crate::path::kinematics::Limits::default();
        let dgrid = grid.grown(16, 16);
        let dens = Array2::from_elem((dgrid.rows, dgrid.cols), 0.3);
        let paths: Vec<PathLog> = [1.7, 1.55]
            .iter()
            .map(|&pitch| {
                let r = RasterSpec::over_rect((-6.0, 31.0), (-6.0, 26.0), pitch, 2.0);
                crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2)
                    .unwrap()
                    .0
            })
            .collect();
        let mut fast = FastRemoval::from_field(&g, &grid).unwrap();
        let mut builds = Vec::new();
        for round in 0..3 {
            for p in &paths {
                let got = fast.removal(p, None).unwrap();
                let want = FastRemoval::from_field(&g, &grid)
                    .unwrap()
                    .removal(p, None)
                    .unwrap();
                let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let d = (&got - &want).iter().fold(0.0f64, |m, v| m.max(v.abs()));
                assert!(d <= 1e-12 * peak, "round {round}: {d} vs {peak}");
            }
            builds.push(fast.phase_kernel_builds());
        }
        assert!(builds[0] > 5, "{builds:?}");
        assert_eq!(builds[0], builds[2], "{builds:?}");
    }

    #[test]
    fn a_kept_walk_takes_new_weights_and_a_moved_path_is_walked_again() {
        // One workspace asked for a path with weights, without, with other weights, then for
        // the same path moved by 0.3 mm (same sample count and times): every answer is the one
        // a fresh workspace (which walks the path itself) gives, to the bit.
        let grid = Grid::new(40, 50, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(2.0, 12.0, 3.0).unwrap();
        let lim = crate::path::kinematics::Limits::default();
        let dgrid = grid.grown(16, 16);
        let dens = Array2::from_elem((dgrid.rows, dgrid.cols), 0.3);
        let r = RasterSpec::over_rect((-6.0, 31.0), (-6.0, 26.0), 1.7, 2.0);
        let p = crate::path::kinematics::dwell_raster(&r, &dens, &dgrid, &lim, 0.2)
            .unwrap()
            .0;
        let n = p.len();
        let g1: Vec<f64> = (0..n)
            .map(|k| 1.0 + 0.3 * (k as f64 * 0.01).sin())
            .collect();
        let g2: Vec<f64> = (0..n).map(|k| k as f64 / n as f64 - 0.5).collect();
        let mut moved = p.clone();
        moved.x_mm.iter_mut().for_each(|x| *x += 0.3);
        let mut fast = FastRemoval::from_field(&g, &grid).unwrap();
        for (path, w) in [
            (&p, Some(&g1[..])),
            (&p, None),
            (&p, Some(&g2[..])),
            (&moved, Some(&g2[..])),
            (&p, Some(&g1[..])),
        ] {
            let got = fast.removal(path, w).unwrap();
            let want = FastRemoval::from_field(&g, &grid)
                .unwrap()
                .removal(path, w)
                .unwrap();
            assert!(want.iter().any(|v| v.abs() > 1e-3));
            assert_eq!(got, want);
        }
    }

    #[test]
    fn convolve_tif_is_linear_conv() {
        let grid = Grid::new(9, 9, 1.0, 1.0, 0.0, 0.0).unwrap();
        let tif = Tif::gaussian(1.0, 4.0, 1.0, 1.0, 1.0).unwrap();
        let mut d = Array2::zeros((9, 9));
        d[(0, 4)] = 2.0;
        let r = convolve_tif(&d, &tif, &grid).unwrap();
        assert!((r[(0, 4)] - 2.0).abs() < 1e-12);
        assert!((r[(1, 4)] - 2.0 * (-0.5f64).exp()).abs() < 1e-12);
        assert!(r[(8, 4)].abs() < 1e-12);
    }
}
