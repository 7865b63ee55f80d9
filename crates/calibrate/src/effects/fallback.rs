//! Fallback kinds for effects the library does not name, built on the run's own structure
//! (issue #15): the removal rate per travel direction along the raster (`rate_per_direction`),
//! per raster line (`rate_per_line`), per time window (`rate_per_window`), as a smooth map
//! over the part (`rate_map`) and, once that map is accepted, its refinement at half the knot
//! spacing (`rate_map_fine`). Each is a set of rate-weight bases `g_j` over the commanded
//! path's samples, exactly linear through the forward model (columns `K * D_{g_j}`, the same
//! as every rate effect; see `model`), so fitting one is a linear least-squares problem.
//!
//! What each localises is in its reported parameters: the rate of every line (with the lines
//! that deviate), of every time window (with the windows that deviate), of every knot of the
//! map (with where it is highest and lowest), or the two travel directions' rates; the
//! `summary` parameter says it in words.
//!
//! Regularisation: a fallback has up to ~50 parameters, so it is offered to the selection only
//! when its own held-out score (the selection's two-fold checkerboard test, `selection`) clears
//! a stricter bar than the named kinds': `z >= FALLBACK_Z` and a held-out reduction of at least
//! `FALLBACK_FRACTION * sqrt(parameters)` of the held-out sum of squares. It then competes in
//! the same round as the named kinds, where fewer parameters win near-ties and unknown kinds
//! sort last, so a named kind that explains the residual as well is preferred.

use rayon::prelude::*;
use std::sync::Arc;

use crate::effects::{Candidate, Current};
use crate::grid::sample;
use crate::model::{Channel, Effect, Linear, Param, Problem};
use crate::selection::Score;

/// Held-out z a fallback must reach before it is offered.
pub const FALLBACK_Z: f64 = 5.0;
/// Held-out reduction (fraction of the held-out sum of squares) per square root of the number
/// of parameters that a fallback must reach before it is offered.
pub const FALLBACK_FRACTION: f64 = 0.01;
/// Time windows of `rate_per_window`.
pub const WINDOWS: usize = 12;
/// Largest number of knots per axis of `rate_map`.
pub const MAP_KNOTS: usize = 6;
/// Least dwell over the measured part of a unit, relative to the median unit's.
const MIN_SUPPORT: f64 = 0.25;
/// Fewest raster lines for the line and direction kinds.
const MIN_LINES: usize = 4;
/// |travel direction component| above which a sample runs along the raster axis.
const ON_LINE: f64 = 0.7;

/// The fallback bases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Basis {
    Direction,
    Line,
    Window,
    Map,
    /// The map's hierarchical refinement: hats at half its knot spacing on the new knots only
    /// (with the map's own hats they span the bilinear map on the halved grid), offered once
    /// `rate_map` is accepted.
    MapFine,
}

impl Basis {
    pub const ALL: [Basis; 5] = [
        Basis::Direction,
        Basis::Line,
        Basis::Window,
        Basis::Map,
        Basis::MapFine,
    ];

    pub fn kind(self) -> &'static str {
        match self {
            Basis::Direction => "rate_per_direction",
            Basis::Line => "rate_per_line",
            Basis::Window => "rate_per_window",
            Basis::Map => "rate_map",
            Basis::MapFine => "rate_map_fine",
        }
    }
}

/// The raster structure of the commanded path.
#[derive(Debug, Clone)]
pub struct Raster {
    /// Lines run along x (else along y).
    pub axis_x: bool,
    /// Cross coordinate of each line (mm), ascending.
    pub line_mm: Vec<f64>,
    /// Per sample: index of the nearest line by its cross coordinate.
    pub line_of: Vec<usize>,
    /// Per sample: +1 / -1 when travelling along the raster axis in + / -, else 0.
    pub dir: Vec<f64>,
}

impl Raster {
    /// The raster of `p`'s path: the axis most of the dwell travels along, the lines as runs of
    /// samples along it (merged when their cross coordinates are within a pixel). `None` when
    /// fewer than `MIN_LINES` lines or less than half the dwell is on lines (not a raster).
    pub fn of(p: &Problem) -> Option<Raster> {
        let s = &p.samples;
        let n = s.len();
        let total: f64 = s.dt_s.iter().sum();
        let share = |u: &[f64]| -> f64 {
            u.iter()
                .zip(&s.dt_s)
                .filter(|(v, _)| v.abs() > ON_LINE)
                .map(|(_, d)| d)
                .sum::<f64>()
        };
        let (sx, sy) = (share(&s.ux), share(&s.uy));
        let axis_x = sx >= sy;
        if sx.max(sy) < 0.5 * total || total <= 0.0 {
            return None;
        }
        let (u, cross, along) = if axis_x {
            (&s.ux, &s.y_mm, &s.x_mm)
        } else {
            (&s.uy, &s.x_mm, &s.y_mm)
        };
        let dir: Vec<f64> = u
            .iter()
            .map(|v| if v.abs() > ON_LINE { v.signum() } else { 0.0 })
            .collect();
        // Runs of samples along the axis in one direction: (dwell-weighted cross, length).
        let mut segs: Vec<(f64, f64)> = Vec::new();
        let mut k = 0;
        while k < n {
            if dir[k] == 0.0 {
                k += 1;
                continue;
            }
            let (mut c, mut w, start) = (0.0, 0.0, k);
            while k < n && dir[k] == dir[start] {
                c += cross[k] * s.dt_s[k];
                w += s.dt_s[k];
                k += 1;
            }
            let len = (along[k - 1] - along[start]).abs();
            if w > 0.0 {
                segs.push((c / w, len));
            }
        }
        let mut lens: Vec<f64> = segs.iter().map(|v| v.1).collect();
        lens.sort_by(|a, b| a.total_cmp(b));
        let med = lens.get(lens.len() / 2).copied().unwrap_or(0.0);
        let pix = p.grid.dx_mm.max(p.grid.dy_mm);
        let mut pos: Vec<f64> = segs
            .iter()
            .filter(|(_, l)| *l >= 0.2 * med && *l >= 4.0 * pix)
            .map(|v| v.0)
            .collect();
        pos.sort_by(|a, b| a.total_cmp(b));
        let mut lines: Vec<(f64, f64)> = Vec::new(); // (sum, count)
        for c in pos {
            match lines.last_mut() {
                Some((sum, cnt)) if c - *sum / *cnt <= pix => {
                    *sum += c;
                    *cnt += 1.0;
                }
                _ => lines.push((c, 1.0)),
            }
        }
        let line_mm: Vec<f64> = lines.iter().map(|(s, c)| s / c).collect();
        if line_mm.len() < MIN_LINES {
            return None;
        }
        let line_of = cross.iter().map(|&c| nearest(&line_mm, c)).collect();
        Some(Raster {
            axis_x,
            line_mm,
            line_of,
            dir,
        })
    }

    fn axis(&self) -> &'static str {
        if self.axis_x {
            "x"
        } else {
            "y"
        }
    }

    fn cross(&self) -> &'static str {
        if self.axis_x {
            "y"
        } else {
            "x"
        }
    }
}

/// Index of the value of ascending `v` nearest to `c`.
fn nearest(v: &[f64], c: f64) -> usize {
    let i = v.partition_point(|&a| a < c);
    if i == 0 {
        0
    } else if i >= v.len() {
        v.len() - 1
    } else if c - v[i - 1] <= v[i] - c {
        i - 1
    } else {
        i
    }
}

/// A fallback's bases over the samples and what each unit (line, window, knot) is.
#[derive(Debug)]
pub struct Shape {
    pub basis: Basis,
    /// Rate weights per column (the first unit is the reference and has no column, except for
    /// `Direction`, whose one column is the travel sign).
    pub cols: Vec<(String, Vec<f64>)>,
    /// Dwell (s) of each unit (weights summed over samples), unit 0 the reference.
    pub dwell: Vec<f64>,
    /// Per unit: its position (line cross coordinate, window start s, knot (x, y)).
    pub at: Vec<(f64, f64)>,
    /// Window length (s) or map knot spacing (mm, x and y).
    pub step: (f64, f64),
    pub raster: Option<Arc<Raster>>,
}

impl Shape {
    /// Units' indicator or hat weights; column j+1 of unit j+1 (unit 0 is the reference).
    ///
    /// Units with little dwell over the measured part (less than `MIN_SUPPORT` of the median
    /// unit's: a line or knot beyond a round aperture) cannot be told apart and are merged
    /// into the nearest unit that has enough.
    fn units(basis: Basis, units: Vec<Vec<f64>>, at: Vec<(f64, f64)>, p: &Problem) -> Shape {
        let keep = supported(&units, p);
        let (units, at) = if keep.is_empty() || keep.len() == units.len() {
            (units, at)
        } else {
            let mut merged: Vec<Vec<f64>> = keep.iter().map(|&j| units[j].clone()).collect();
            for (j, g) in units.iter().enumerate() {
                if keep.contains(&j) {
                    continue;
                }
                let d = |i: usize| {
                    let (a, b) = (at[keep[i]], at[j]);
                    (a.0 - b.0).hypot(a.1 - b.1)
                };
                let best = (0..keep.len())
                    .min_by(|&a, &b| d(a).total_cmp(&d(b)))
                    .unwrap_or(0);
                for (m, v) in merged[best].iter_mut().zip(g) {
                    *m += v;
                }
            }
            (merged, keep.iter().map(|&j| at[j]).collect())
        };
        let dwell = units
            .iter()
            .map(|g| g.iter().zip(&p.samples.dt_s).map(|(a, b)| a * b).sum())
            .collect();
        let cols = units
            .into_iter()
            .enumerate()
            .skip(1)
            .map(|(j, g)| (format!("rate:{}:{j}", basis.kind()), g))
            .collect();
        Shape {
            basis,
            cols,
            dwell,
            at,
            step: (0.0, 0.0),
            raster: None,
        }
    }

    /// Every basis's shape for `p` (those it has), in the order of [`Basis::ALL`], but the
    /// map's refinement (built apart when offered: [`Problem::fallback_fine`]).
    pub fn all_of(p: &Problem) -> Vec<Arc<Shape>> {
        let raster = Raster::of(p).map(Arc::new);
        Basis::ALL
            .into_iter()
            .filter(|b| *b != Basis::MapFine)
            .filter_map(|b| Shape::of(b, p, raster.as_ref()).map(Arc::new))
            .collect()
    }

    pub fn of(basis: Basis, p: &Problem, raster: Option<&Arc<Raster>>) -> Option<Shape> {
        let s = &p.samples;
        let n = s.len();
        match basis {
            Basis::Direction => {
                let r = raster?;
                let plus: f64 = (0..n).filter(|&k| r.dir[k] > 0.0).map(|k| s.dt_s[k]).sum();
                let minus: f64 = (0..n).filter(|&k| r.dir[k] < 0.0).map(|k| s.dt_s[k]).sum();
                if plus <= 0.0 || minus <= 0.0 {
                    return None;
                }
                Some(Shape {
                    basis,
                    cols: vec![("rate:rate_per_direction".into(), r.dir.clone())],
                    dwell: vec![plus, minus],
                    at: Vec::new(),
                    step: (0.0, 0.0),
                    raster: Some(r.clone()),
                })
            }
            Basis::Line => {
                let r = raster?;
                let units: Vec<Vec<f64>> = (0..r.line_mm.len())
                    .map(|l| {
                        r.line_of
                            .iter()
                            .map(|&m| if m == l { 1.0 } else { 0.0 })
                            .collect()
                    })
                    .collect();
                let at = r.line_mm.iter().map(|&c| (c, 0.0)).collect();
                let mut sh = Shape::units(basis, units, at, p);
                sh.raster = Some(r.clone());
                Some(sh)
            }
            Basis::Window => {
                let dur = (s.t1_s - s.t0_s).max(f64::MIN_POSITIVE);
                let units = (0..WINDOWS)
                    .map(|w| {
                        (0..n)
                            .map(|k| {
                                let i = ((s.tau(k) * WINDOWS as f64) as usize).min(WINDOWS - 1);
                                if i == w {
                                    1.0
                                } else {
                                    0.0
                                }
                            })
                            .collect()
                    })
                    .collect();
                let len = dur / WINDOWS as f64;
                let at = (0..WINDOWS).map(|w| (w as f64 * len, 0.0)).collect();
                let mut sh = Shape::units(basis, units, at, p);
                sh.step = (len, 0.0);
                Some(sh)
            }
            Basis::Map => {
                let (x0, y0, nx, ny, hx, hy) = map_knots(p)?;
                let (units, at) = knot_hats(s, (x0, y0), (nx, ny), (hx, hy), |_, _| true);
                let mut sh = Shape::units(basis, units, at, p);
                sh.step = (hx, hy);
                Some(sh)
            }
            Basis::MapFine => {
                // The new knots of the map's grid halved; each hat at half the spacing. The
                // map's hats are sums of the halved grid's, so these and the map's together
                // span the bilinear map on the halved grid, and no column repeats one of the
                // map's. No reference unit: the surplus hats do not sum to a constant.
                let (x0, y0, nx, ny, hx, hy) = map_knots(p)?;
                let (fx, fy) = (0.5 * hx, 0.5 * hy);
                let (mx, my) = (2 * nx - 1, 2 * ny - 1);
                // The map's own knots are not new; the outer ring's are left out: a hat there
                // has half its reach off the path, is determined by the few pixels at the
                // part's edge, and the hold-out test's halves then disagree on it (held-out
                // reductions of -0.01 to -2.7 on square parts with them, +0.16 to +0.43 on
                // round ones without).
                let new_inner = |i: usize, j: usize| {
                    let outer = i == 0 || j == 0 || i == mx - 1 || j == my - 1;
                    !(outer || (i.is_multiple_of(2) && j.is_multiple_of(2)))
                };
                let (units, at) = knot_hats(s, (x0, y0), (mx, my), (fx, fy), new_inner);
                let mut sh = Shape::surplus(basis, units, at, p);
                sh.step = (fx, fy);
                Some(sh)
            }
        }
    }

    /// Bases that are all columns (no reference unit), the units with little dwell over the
    /// measured part (less than `MIN_SUPPORT` of the median unit's) left out: a knot beyond a
    /// round aperture cannot be told from its neighbours.
    fn surplus(basis: Basis, units: Vec<Vec<f64>>, at: Vec<(f64, f64)>, p: &Problem) -> Shape {
        // A knot is kept only over the measured part, too: one out on the path's overtravel is
        // determined by the few pixels its hat reaches, and the hold-out test's halves then
        // disagree on it (held-out reductions of -0.1 to -2.7 with them on square parts).
        let on = p.before_valid.mapv(|v| if v { 1.0 } else { 0.0 });
        let over = |j: usize| sample(&p.grid, &on, at[j].0, at[j].1) >= 0.5;
        let keep: Vec<usize> = supported(&units, p)
            .into_iter()
            .filter(|&j| over(j))
            .collect();
        let dwell = keep
            .iter()
            .map(|&j| {
                units[j]
                    .iter()
                    .zip(&p.samples.dt_s)
                    .map(|(a, b)| a * b)
                    .sum()
            })
            .collect();
        let at = keep.iter().map(|&j| at[j]).collect();
        let mut units: Vec<Option<Vec<f64>>> = units.into_iter().map(Some).collect();
        let cols = keep
            .iter()
            .enumerate()
            .map(|(n, &j)| {
                (
                    format!("rate:{}:{n}", basis.kind()),
                    units[j].take().unwrap_or_default(),
                )
            })
            .collect();
        Shape {
            basis,
            cols,
            dwell,
            at,
            step: (0.0, 0.0),
            raster: None,
        }
    }

    /// Relative rate of every unit (to the dwell-weighted mean rate), from the fitted linear
    /// coefficients: unit j's rate is `s0 + c_j` (c_0 = 0, the reference).
    fn relative(&self, lin: &Linear) -> Vec<f64> {
        let s0 = lin.s0();
        let mut u = vec![1.0];
        u.extend(self.cols.iter().map(|(n, _)| 1.0 + lin.get(n) / s0));
        let w: f64 = self.dwell.iter().sum();
        let mean = u.iter().zip(&self.dwell).map(|(a, b)| a * b).sum::<f64>() / w.max(1e-300);
        u.iter().map(|v| v / mean - 1.0).collect()
    }
}

/// Indices of the units with enough dwell over the measured part: at least `MIN_SUPPORT` of
/// the median unit's, and some.
fn supported(units: &[Vec<f64>], p: &Problem) -> Vec<usize> {
    let inside = inside_dwell(p);
    let support: Vec<f64> = units
        .iter()
        .map(|g| g.iter().zip(&inside).map(|(a, b)| a * b).sum())
        .collect();
    let mut sorted = support.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let med = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    (0..units.len())
        .filter(|&j| support[j] >= MIN_SUPPORT * med && support[j] > 0.0)
        .collect()
}

/// Each sample's dwell (s) when it lies over the measured part, else 0.
fn inside_dwell(p: &Problem) -> Vec<f64> {
    let on = p.before_valid.mapv(|v| if v { 1.0 } else { 0.0 });
    (0..p.samples.len())
        .map(|k| {
            let v = sample(&p.grid, &on, p.samples.x_mm[k], p.samples.y_mm[k]);
            if v >= 0.5 {
                p.samples.dt_s[k]
            } else {
                0.0
            }
        })
        .collect()
}

/// The rate map's knot grid over the path's extent: first knot (x0, y0) mm, knots per axis and
/// their spacing (mm). Knots no closer than two spot radii (finer is not a smooth map), at
/// most `MAP_KNOTS` per axis; `None` for a path without extent or fewer than four knots.
fn map_knots(p: &Problem) -> Option<(f64, f64, usize, usize, f64, f64)> {
    let s = &p.samples;
    let range = |v: &[f64]| {
        v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &x| {
            (a.0.min(x), a.1.max(x))
        })
    };
    let (x0, x1) = range(&s.x_mm);
    let (y0, y1) = range(&s.y_mm);
    let knots = |ext: f64| -> usize {
        ((ext / (2.0 * p.tif_radius_mm)).floor() as usize + 1).clamp(2, MAP_KNOTS)
    };
    let (nx, ny) = (knots(x1 - x0), knots(y1 - y0));
    if x1 - x0 <= 0.0 || y1 - y0 <= 0.0 || nx * ny < 4 {
        return None;
    }
    let (hx, hy) = ((x1 - x0) / (nx - 1) as f64, (y1 - y0) / (ny - 1) as f64);
    Some((x0, y0, nx, ny, hx, hy))
}

/// The rate map's bilinear hats (its knot grid, [`map_knots`]) as a smooth map added to the
/// measured removal, evaluated at the analysis pixels (`p.idx`): a smooth difference between
/// the two measurements that no rate causes. Knots whose hat covers less than `MIN_SUPPORT` of
/// the median knot's pixel weight are left out (a hat on a few rim pixels is a local fit of
/// them). Empty without a map grid.
///
/// Why `run` scores rate candidates beyond it. A real interferometer's error is not white:
/// three measurements of one flat a minute or so apart (`01_801B`, `02_801B`, `04_801B` in
/// `../shared/data`, 0.2457 mm pixels, a 97 mm aperture) differ pairwise by 0.87-1.64 nm RMS
/// after a plane, against a pixel-scale floor of 0.16-0.20 nm; the difference is smooth (air,
/// drift, alignment) and spread over many low orders (0.41-0.47 nm remain after 15
/// Zernike-like terms). The hold-out takes blocks a tenth of the map across as independent,
/// and a smooth error is predictable from the neighbouring blocks, so it passes. A rate effect
/// multiplies the removal, which is often nearly uniform (78 nm mean, 15 nm RMS in those
/// runs), so a smooth rate change and a smooth additive error look alike: on runs built from
/// two of those maps and an exactly deposited removal (`examples/calibration_real_repeat.rs`)
/// the selection accepted a rate map of up to 15-20 % and its refinement in every one of 12
/// runs with nothing injected. So a rate candidate (a kind named `rate_*`, but the map's
/// refinement, which only completes a map that passed) significant on the data is scored
/// again with these columns in the base. A fallback's candidate (generic maps, lines, windows
/// of many parameters) keeps the smaller of the two scores. A library kind (a named mechanism
/// of few parameters, possibly offered as several variants under one key: the height's
/// smoothing lengths) is judged by its variant the data score best: if that one alone predicts
/// the held-out data better than this smooth map does, or stays significant beyond it, all the
/// kind's variants keep their own scores (so the data still choose among them); otherwise they
/// too keep the smaller. The smooth map is not added to the model: what it would take stays in
/// the residual and is reported there (`unexplained`).
///
/// When the lab declares its instrument's repeatability (`Problem::repeatability_nm`), the
/// check is made only while what this map alone explains stays within the drift that
/// repeatability allows (`run::SmoothCheck`): a smooth structure far larger than the
/// instrument makes between two measurements is not its drift, and the rates keep their scores.
pub fn smooth_additive_columns(p: &Problem) -> Vec<Vec<f64>> {
    let Some((x0, y0, nx, ny, hx, hy)) = map_knots(p) else {
        return Vec::new();
    };
    let g = &p.grid;
    let hat = |v: f64, c: f64, h: f64| (1.0 - ((v - c) / h).abs()).max(0.0);
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let (cx, cy) = (x0 + i as f64 * hx, y0 + j as f64 * hy);
            cols.push(
                p.idx
                    .iter()
                    .map(|&k| hat(g.x_mm(k % g.cols), cx, hx) * hat(g.y_mm(k / g.cols), cy, hy))
                    .collect(),
            );
        }
    }
    let weight: Vec<f64> = cols.iter().map(|c| c.iter().sum()).collect();
    let mut sorted = weight.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    cols.into_iter()
        .zip(weight)
        .filter(|(_, w)| *w > 0.0 && *w >= MIN_SUPPORT * median)
        .map(|(c, _)| c)
        .collect()
}

/// Bilinear hats at every sample, one per knot `(i, j)` of the `n.0 x n.1` grid from `origin`
/// with spacings `h` (row by row) that `keep` admits, and the knots' positions (mm).
type KnotHats = (Vec<Vec<f64>>, Vec<(f64, f64)>);
fn knot_hats(
    s: &crate::path::Samples,
    origin: (f64, f64),
    n: (usize, usize),
    h: (f64, f64),
    keep: impl Fn(usize, usize) -> bool,
) -> KnotHats {
    let mut units = Vec::new();
    let mut at = Vec::new();
    for j in 0..n.1 {
        for i in 0..n.0 {
            if !keep(i, j) {
                continue;
            }
            let (cx, cy) = (origin.0 + i as f64 * h.0, origin.1 + j as f64 * h.1);
            units.push(knot_hat(s, cx, cy, h.0, h.1));
            at.push((cx, cy));
        }
    }
    (units, at)
}

/// The bilinear hat of knot (cx, cy) with spacings (hx, hy) at every sample.
fn knot_hat(s: &crate::path::Samples, cx: f64, cy: f64, hx: f64, hy: f64) -> Vec<f64> {
    let hat = |v: f64, c: f64, h: f64| (1.0 - ((v - c) / h).abs()).max(0.0);
    (0..s.len())
        .map(|k| hat(s.x_mm[k], cx, hx) * hat(s.y_mm[k], cy, hy))
        .collect()
}

/// A fitted fallback.
#[derive(Debug, Clone)]
pub struct Fallback {
    pub shape: Arc<Shape>,
}

/// Indices of the units whose |relative rate| is at least half the largest, largest first (at
/// most `n`).
fn deviating(rel: &[f64], n: usize) -> Vec<usize> {
    let max = rel.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mut idx: Vec<usize> = (0..rel.len())
        .filter(|&i| max > 0.0 && rel[i].abs() >= 0.5 * max)
        .collect();
    idx.sort_by(|&a, &b| rel[b].abs().total_cmp(&rel[a].abs()).then(a.cmp(&b)));
    idx.truncate(n);
    idx
}

fn pct(v: f64) -> String {
    format!("{:+.1} %", 100.0 * v)
}

impl Effect for Fallback {
    fn kind(&self) -> &'static str {
        self.shape.basis.kind()
    }
    fn key(&self) -> String {
        self.shape.basis.kind().into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn rate_terms(&self, _p: &Problem) -> Vec<(String, Vec<f64>)> {
        self.shape.cols.clone()
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        let sh = &self.shape;
        match sh.basis {
            Basis::Direction => {
                let axis = sh.raster.as_ref().map_or("x", |r| r.axis());
                let f = lin.get(&sh.cols[0].0) / lin.s0();
                vec![
                    ("axis".into(), Param::Text(axis.into())),
                    ("fraction".into(), Param::Num(f)),
                    (
                        "summary".into(),
                        Param::Text(format!(
                            "rate {} on lines travelled in +{axis}, {} in -{axis} \
                             (relative to the rate at turns)",
                            pct(f),
                            pct(-f)
                        )),
                    ),
                ]
            }
            Basis::Line => {
                let (axis, cross) = sh
                    .raster
                    .as_ref()
                    .map_or(("x", "y"), |r| (r.axis(), r.cross()));
                let rel = sh.relative(lin);
                let dev = deviating(&rel, 8);
                let list: Vec<String> = dev
                    .iter()
                    .map(|&i| format!("{cross} = {:.1} mm ({})", sh.at[i].0, pct(rel[i])))
                    .collect();
                let rms = (rel.iter().map(|v| v * v).sum::<f64>() / rel.len() as f64).sqrt();
                vec![
                    ("axis".into(), Param::Text(axis.into())),
                    (
                        "line_position_mm".into(),
                        Param::List(sh.at.iter().map(|a| a.0).collect()),
                    ),
                    ("rate_change_fraction".into(), Param::List(rel)),
                    (
                        "summary".into(),
                        Param::Text(format!(
                            "rate differs between raster lines (along {axis}) by {:.1} % RMS; \
                             largest: {}",
                            100.0 * rms,
                            list.join(", ")
                        )),
                    ),
                ]
            }
            Basis::Window => {
                let rel = sh.relative(lin);
                let dev = deviating(&rel, 6);
                let list: Vec<String> = dev
                    .iter()
                    .map(|&i| {
                        format!(
                            "{:.0}-{:.0} s ({})",
                            sh.at[i].0,
                            sh.at[i].0 + sh.step.0,
                            pct(rel[i])
                        )
                    })
                    .collect();
                vec![
                    (
                        "window_start_s".into(),
                        Param::List(sh.at.iter().map(|a| a.0).collect()),
                    ),
                    ("window_s".into(), Param::Num(sh.step.0)),
                    ("rate_change_fraction".into(), Param::List(rel)),
                    (
                        "summary".into(),
                        Param::Text(format!(
                            "rate varies between time windows; largest: {}",
                            list.join(", ")
                        )),
                    ),
                ]
            }
            Basis::Map => {
                let rel = sh.relative(lin);
                let (mut hi, mut lo) = (0, 0);
                for i in 0..rel.len() {
                    if rel[i] > rel[hi] {
                        hi = i;
                    }
                    if rel[i] < rel[lo] {
                        lo = i;
                    }
                }
                vec![
                    (
                        "knot_x_mm".into(),
                        Param::List(sh.at.iter().map(|a| a.0).collect()),
                    ),
                    (
                        "knot_y_mm".into(),
                        Param::List(sh.at.iter().map(|a| a.1).collect()),
                    ),
                    ("rate_change_fraction".into(), Param::List(rel.clone())),
                    (
                        "summary".into(),
                        Param::Text(format!(
                            "rate varies over the part (bilinear map, knots {:.1} x {:.1} mm): \
                             highest {} near (x, y) = ({:.1}, {:.1}) mm, lowest {} near \
                             ({:.1}, {:.1}) mm",
                            sh.step.0,
                            sh.step.1,
                            pct(rel[hi]),
                            sh.at[hi].0,
                            sh.at[hi].1,
                            pct(rel[lo]),
                            sh.at[lo].0,
                            sh.at[lo].1
                        )),
                    ),
                ]
            }
            Basis::MapFine => {
                // Each new knot's rate beyond the map's bilinear value there (the hat's
                // coefficient over the baseline rate).
                let s0 = lin.s0();
                let rel: Vec<f64> = sh.cols.iter().map(|(n, _)| lin.get(n) / s0).collect();
                let dev = deviating(&rel, 6);
                let list: Vec<String> = dev
                    .iter()
                    .map(|&i| {
                        format!(
                            "({:.1}, {:.1}) mm ({})",
                            sh.at[i].0,
                            sh.at[i].1,
                            pct(rel[i])
                        )
                    })
                    .collect();
                let rms = (rel.iter().map(|v| v * v).sum::<f64>() / rel.len().max(1) as f64).sqrt();
                vec![
                    (
                        "knot_x_mm".into(),
                        Param::List(sh.at.iter().map(|a| a.0).collect()),
                    ),
                    (
                        "knot_y_mm".into(),
                        Param::List(sh.at.iter().map(|a| a.1).collect()),
                    ),
                    ("rate_change_fraction".into(), Param::List(rel)),
                    (
                        "summary".into(),
                        Param::Text(format!(
                            "rate varies over the part finer than the rate map (knots {:.1} x \
                             {:.1} mm between the map's): {:.1} % RMS beyond the map; largest \
                             at (x, y) = {}",
                            sh.step.0,
                            sh.step.1,
                            100.0 * rms,
                            list.join(", ")
                        )),
                    ),
                ]
            }
        }
    }
}

/// Prescreen threshold: the residual's projection on a basis (sum over its columns of the
/// squared matched-filter projections) over the median of the same for `FLIPS` copies of the
/// residual with the signs of its hold-out blocks flipped at random (same amplitude and local
/// correlation, no coherence across blocks).
pub const PRESCREEN: f64 = 2.5;
const FLIPS: u64 = 8;

/// Matched filter (rate channel, times the samples' dwell) of the residual and of `FLIPS`
/// block-sign-flipped copies of it; `None` when the forward model cannot evaluate it.
fn flipped_matched(cur: &Current) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let r = cur.resid_map();
    let g = &cur.p.grid;
    let b = (g.rows.min(g.cols) / 10).max(4);
    let nbc = g.cols.div_ceil(b);
    let dt = &cur.p.samples.dt_s;
    let run = |m: &ndarray::Array2<f64>| -> Option<Vec<f64>> {
        let h = cur
            .ev
            .kernels
            .matched(Channel::Value, m, &cur.ev.exec)
            .ok()?;
        Some(h.iter().zip(dt).map(|(v, d)| v * d).collect())
    };
    // The residual and its flipped copies side by side, collected in order.
    let all: Vec<Option<Vec<f64>>> = (0..=FLIPS)
        .into_par_iter()
        .map(|f| {
            if f == 0 {
                // The residual's own: the rate channel's matched filter of this state.
                return Some(cur.matched(Channel::Value));
            }
            // Each block's sign drawn once.
            let nbr = g.rows.div_ceil(b);
            let flip: Vec<bool> = (0..(nbr * nbc) as u64)
                .map(|blk| splitmix(blk ^ f.wrapping_mul(0xA076_1D64_78BD_642F)) & 1 == 1)
                .collect();
            let mut m = r.clone();
            for ((i, j), v) in m.indexed_iter_mut() {
                if flip[(i / b) * nbc + j / b] {
                    *v = -*v;
                }
            }
            run(&m)
        })
        .collect();
    let mut all = all.into_iter().collect::<Option<Vec<_>>>()?;
    let obs = all.remove(0);
    Some((obs, all))
}

fn splitmix(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// For each matched filter `h` of `hs` (per sample): the sum over a basis' columns of the
/// squared projection of the residual on the column's dwell-centred rate weights. One pass
/// over each column serves every `h`; each sum is the sequential one from -0.0 (as
/// `Iterator::sum` forms it) of the per-filter computation.
fn projections(sh: &Shape, hs: &[&[f64]], dt: &[f64]) -> Vec<f64> {
    let sums: Vec<f64> = hs.iter().map(|h| h.iter().sum::<f64>()).collect();
    let w: f64 = dt.iter().sum();
    let mut out = vec![-0.0; hs.len()];
    let mut dots = vec![-0.0; hs.len()];
    for (_, g) in &sh.cols {
        let mut gd = -0.0;
        dots.fill(-0.0);
        for (i, (&a, &t)) in g.iter().zip(dt).enumerate() {
            // A zero weight adds a zero to every sum, which changes none of them (each sum
            // starts from -0.0, and -0.0 + 0 = +0.0 is still a zero): the bases are zero on
            // most samples (a knot's, a line's, a window's).
            if a == 0.0 {
                continue;
            }
            gd += a * t;
            for (d, h) in dots.iter_mut().zip(hs) {
                *d += a * h[i];
            }
        }
        let m = gd / w.max(1e-300);
        for ((o, d), s) in out.iter_mut().zip(&dots).zip(&sums) {
            let b = d - m * s;
            *o += b * b;
        }
    }
    out
}

/// Whether a fallback's held-out score clears the stricter bar (see the module note).
pub fn passes(s: &Score, kind: &str, n_params: usize) -> bool {
    if crate::selection::odd_in_travel(kind) {
        // No size bar for a signal odd in the travel direction (`selection::odd_in_travel`).
        return s.significant_for(kind) && s.z >= FALLBACK_Z;
    }
    s.significant()
        && s.z >= FALLBACK_Z
        && s.fraction >= FALLBACK_FRACTION * (n_params.max(1) as f64).sqrt()
}

/// Whether `kind` is one of the fallback's kinds (not a library kind).
pub fn is_fallback(kind: &str) -> bool {
    Basis::ALL.iter().any(|b| b.kind() == kind)
}

/// The fallback candidates not yet accepted that pass the prescreen. The selection scores
/// them with the library's candidates and keeps those whose held-out score clears the
/// stricter bar ([`passes`]).
pub fn candidates(cur: &Current) -> Vec<Candidate> {
    // The map's refinement only over an accepted map (its columns complete the map's).
    let fresh: Vec<Basis> = Basis::ALL
        .into_iter()
        .filter(|b| !cur.has(b.kind()))
        .filter(|b| *b != Basis::MapFine || cur.has(Basis::Map.kind()))
        .collect();
    if fresh.is_empty() {
        return Vec::new();
    }
    let p = cur.p;
    let mut shapes: Vec<Arc<Shape>> = p
        .fallback_shapes()
        .iter()
        .filter(|sh| fresh.contains(&sh.basis))
        .cloned()
        .collect();
    if fresh.contains(&Basis::MapFine) {
        shapes.extend(p.fallback_fine().cloned());
    }
    // Prescreen (matched filters only): the many-column bases go on to their columns only
    // when the residual projects on them more than block-sign-flipped copies of it do.
    let flips = flipped_matched(cur);
    let trace = std::env::var_os("BONNETLAB_TRACE").is_some();
    let shapes: Vec<Arc<Shape>> = shapes
        .into_iter()
        .filter(|sh| {
            // The map's refinement is offered over an accepted map only (rare), and its
            // projection is a small excess over the map's: its held-out score decides.
            if sh.cols.len() <= 1 || sh.basis == Basis::MapFine {
                return true;
            }
            let Some((obs, null)) = &flips else {
                return true;
            };
            let all: Vec<&[f64]> = std::iter::once(obs.as_slice())
                .chain(null.iter().map(|h| h.as_slice()))
                .collect();
            let mut tn = projections(sh, &all, &p.samples.dt_s);
            let t = tn.remove(0);
            tn.sort_by(|a, b| a.total_cmp(b));
            let med = tn[tn.len() / 2];
            if trace {
                eprintln!(
                    "fallback prescreen {}: {:.2} x the flipped median",
                    sh.basis.kind(),
                    t / med.max(1e-300)
                );
            }
            t >= PRESCREEN * med
        })
        .collect();
    if shapes.is_empty() {
        return Vec::new();
    }
    let mut out = Vec::new();
    for shape in shapes {
        let b = shape.basis;
        let extra: Vec<Vec<f64>> = shape
            .cols
            .par_iter()
            .map(|(_, g)| cur.rate_term_column(g))
            .collect();
        out.push(Candidate {
            key: b.kind().into(),
            kind: b.kind(),
            extra,
            make: Box::new(move |_, _| {
                Box::new(Fallback {
                    shape: shape.clone(),
                })
            }),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_line() {
        let v = [0.0, 2.0, 4.0];
        assert_eq!(nearest(&v, -1.0), 0);
        assert_eq!(nearest(&v, 0.9), 0);
        assert_eq!(nearest(&v, 1.1), 1);
        assert_eq!(nearest(&v, 3.5), 2);
        assert_eq!(nearest(&v, 9.0), 2);
    }

    /// The projections skip the zero weights of the (mostly zero) bases and still give the
    /// plain per-filter sums over every sample, bit for bit.
    #[test]
    fn projections_are_the_plain_sums_bit_for_bit() {
        let n = 500;
        let wave = |k: usize, f: f64| -> Vec<f64> {
            (0..n)
                .map(|i| ((i * (2 * k + 1)) as f64 * f).sin() * (1.0 + k as f64))
                .collect()
        };
        let dt: Vec<f64> = (0..n).map(|i| 0.05 + 0.01 * (i % 7) as f64).collect();
        // Compact bases (a hat, an indicator, one with negative values) and a dense one.
        let hat: Vec<f64> = (0..n)
            .map(|i| (1.0 - (i as f64 - 120.0).abs() / 40.0).max(0.0))
            .collect();
        let ind: Vec<f64> = (0..n)
            .map(|i| if (300..340).contains(&i) { 1.0 } else { 0.0 })
            .collect();
        let neg: Vec<f64> = (0..n)
            .map(|i| if i % 50 == 3 { -0.7 } else { 0.0 })
            .collect();
        let dense = wave(5, 0.013);
        let sh = Shape {
            basis: Basis::Map,
            cols: [hat, ind, neg, dense]
                .into_iter()
                .enumerate()
                .map(|(j, g)| (format!("c{j}"), g))
                .collect(),
            dwell: Vec::new(),
            at: Vec::new(),
            step: (0.0, 0.0),
            raster: None,
        };
        let hs: Vec<Vec<f64>> = (0..3).map(|k| wave(k, 0.037)).collect();
        let refs: Vec<&[f64]> = hs.iter().map(|h| h.as_slice()).collect();
        let got = projections(&sh, &refs, &dt);
        let w: f64 = dt.iter().sum();
        for (h, g) in hs.iter().zip(&got) {
            let sum: f64 = h.iter().sum();
            let mut want = -0.0;
            for (_, c) in &sh.cols {
                let gd: f64 = c.iter().zip(&dt).map(|(a, t)| a * t).sum();
                let d: f64 = c.iter().zip(h).map(|(a, v)| a * v).sum();
                let b = d - gd / w * sum;
                want += b * b;
            }
            assert_eq!(g.to_bits(), want.to_bits());
        }
    }

    #[test]
    fn deviating_units_are_the_large_ones() {
        let rel = [0.0, 0.05, -0.01, -0.06, 0.02];
        assert_eq!(deviating(&rel, 8), vec![3, 1]);
    }
}
