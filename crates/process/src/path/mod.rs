//! Tool paths: commanded tool-centre positions sampled in time (the shared map frame, mm).
//!
//! Between samples the tool moves in a straight line at constant speed, so the dwell a point
//! receives is the time the tool centre spends there. Every model that reads a log (the
//! process model's `simulate`, the vibration coupling, calibration) reads it through
//! [`PathLog::with_corners`] first, which puts back the raster corners a sparse log's chords
//! cut; a path sampled on its corners (a generated raster) is unchanged by it. [`raster`] generates grating paths,
//! [`log`] reads path logs (`t_s,x_mm,y_mm` CSV), [`kinematics`] turns a dwell map into feeds and
//! applies the machine's velocity and acceleration limits.

pub mod kinematics;
pub mod log;
pub mod raster;

use serde::{Deserialize, Serialize};

use crate::error::ProcessError;

pub use log::read_path_csv;
pub use raster::{RasterSpec, ScanAxis};

/// A tool path: times (s, strictly increasing) and tool-centre positions (mm).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PathLog {
    pub t_s: Vec<f64>,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
}

impl PathLog {
    /// A path from equal-length vectors; times must increase strictly and all be finite.
    pub fn new(t_s: Vec<f64>, x_mm: Vec<f64>, y_mm: Vec<f64>) -> Result<PathLog, ProcessError> {
        if t_s.len() != x_mm.len() || t_s.len() != y_mm.len() {
            return Err(ProcessError::invalid("path vectors differ in length"));
        }
        for k in 0..t_s.len() {
            if !(t_s[k].is_finite() && x_mm[k].is_finite() && y_mm[k].is_finite()) {
                return Err(ProcessError::invalid(format!(
                    "path sample {k} is not finite"
                )));
            }
            if k > 0 && t_s[k] <= t_s[k - 1] {
                return Err(ProcessError::invalid(format!(
                    "path time does not increase at sample {k}"
                )));
            }
        }
        Ok(PathLog { t_s, x_mm, y_mm })
    }

    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Total duration in s.
    pub fn duration_s(&self) -> f64 {
        match (self.t_s.first(), self.t_s.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }

    /// Total path length in mm.
    pub fn length_mm(&self) -> f64 {
        (1..self.len())
            .map(|k| (self.x_mm[k] - self.x_mm[k - 1]).hypot(self.y_mm[k] - self.y_mm[k - 1]))
            .sum()
    }

    /// Position at time t (linear between samples, clamped at the ends).
    pub fn position_at(&self, t: f64) -> Option<(f64, f64)> {
        let n = self.len();
        if n == 0 {
            return None;
        }
        if t <= self.t_s[0] {
            return Some((self.x_mm[0], self.y_mm[0]));
        }
        if t >= self.t_s[n - 1] {
            return Some((self.x_mm[n - 1], self.y_mm[n - 1]));
        }
        let k = self.t_s.partition_point(|&v| v <= t).max(1) - 1;
        let f = (t - self.t_s[k]) / (self.t_s[k + 1] - self.t_s[k]);
        Some((
            self.x_mm[k] + f * (self.x_mm[k + 1] - self.x_mm[k]),
            self.y_mm[k] + f * (self.y_mm[k + 1] - self.y_mm[k]),
        ))
    }

    /// The same motion with extra samples: every segment cut into equal pieces no longer than
    /// `max_step_mm` (straight lines at constant speed, so the motion is unchanged). The
    /// original samples are kept; per-sample quantities of the result (rate weights, path
    /// perturbations) are then resolved at that spacing.
    pub fn densified(&self, max_step_mm: f64) -> PathLog {
        let n = self.len();
        let mut out = PathLog::default();
        for k in 0..n {
            out.t_s.push(self.t_s[k]);
            out.x_mm.push(self.x_mm[k]);
            out.y_mm.push(self.y_mm[k]);
            if k + 1 == n {
                break;
            }
            let (x0, y0) = (self.x_mm[k], self.y_mm[k]);
            let (ddx, ddy) = (self.x_mm[k + 1] - x0, self.y_mm[k + 1] - y0);
            let dt = self.t_s[k + 1] - self.t_s[k];
            let m = substeps(ddx.hypot(ddy), dt, max_step_mm, 0.0);
            for s in 1..m {
                let fr = s as f64 / m as f64;
                out.t_s.push(self.t_s[k] + fr * dt);
                out.x_mm.push(x0 + fr * ddx);
                out.y_mm.push(y0 + fr * ddy);
            }
        }
        out
    }

    /// The path with the corners its samples cut restored: where the chords on either side of
    /// a chord turn by more than [`CORNER_TURN_DEG`], the tool turned a corner inside it (a
    /// raster's turn into and out of its pitch step, sampled at a fixed rate). The vertex goes
    /// where the lines through those two chords meet, if it lies ahead of the chord's start and
    /// behind its end, each within twice the chord's length, and if its legs can be travelled
    /// in the chord's time at the neighbouring chords' speeds (within [`CORNER_SLACK`]): a
    /// chord whose neighbours cut corners themselves (the pitch step between two corners) is
    /// not a corner, and neither is a chord between two chords that get one. The chord's time
    /// is split over the two legs in proportion to each leg's length over its neighbouring
    /// chord's speed. (Sharing the time left over, the stop a corner costs, in proportion to
    /// the two speeds instead puts a stop-and-go corner's time within 1 ms rather than 9, but
    /// moved the vibration coupling's clock on a log whose corners the robot does not stop
    /// at by 0.01 s and its fitted forcing from 5 N to 4 N: `tests/forcing_truth.rs`.)
    ///
    /// A turnaround whose pitch step holds a single sample (a 2 mm step at 12 mm/s logged at
    /// 10 Hz does one time in ten) has two cut corners in consecutive chords, neither with a
    /// straight neighbour on the step's side: the step is taken square to the two antiparallel
    /// lines, through that sample, and its speed from the time the lines leave it. A step with
    /// no sample in it (a short step at a low log rate) is left as the chord that cuts it.
    /// Samples on a corner, smooth curves (turns under the threshold over two chords) and
    /// chords next to a standstill are left as they are.
    pub fn with_corners(&self) -> PathLog {
        let n = self.len();
        let mut vertex: Vec<Option<(f64, f64, f64)>> = vec![None; n.saturating_sub(1)];
        let chord = |a: usize| {
            let (dx, dy) = (
                self.x_mm[a + 1] - self.x_mm[a],
                self.y_mm[a + 1] - self.y_mm[a],
            );
            (dx, dy, self.t_s[a + 1] - self.t_s[a], dx.hypot(dy))
        };
        let cos_turn = CORNER_TURN_DEG.to_radians().cos();
        // One corner inside chord k, between the straight chords k - 1 and k + 1.
        for (k, slot) in vertex
            .iter_mut()
            .enumerate()
            .take(n.saturating_sub(2))
            .skip(1)
        {
            let (ax, ay, at, la) = chord(k - 1);
            let (bx, by, bt, lb) = chord(k);
            let (cx, cy, ct, lc) = chord(k + 1);
            let tiny = 1e-9 * (la + lb + lc).max(f64::MIN_POSITIVE);
            if la <= tiny || lb <= tiny || lc <= tiny {
                continue;
            }
            let (ux, uy, wx, wy) = (ax / la, ay / la, cx / lc, cy / lc);
            if ux * wx + uy * wy > cos_turn {
                continue;
            }
            // Vertex v = s_k + u a_hat = s_(k+1) - w c_hat.
            let det = ux * wy - uy * wx;
            if det.abs() < 1e-9 {
                continue;
            }
            let u = (bx * wy - by * wx) / det;
            let w = (ux * by - uy * bx) / det;
            if !(u > 1e-6 * lb && w > 1e-6 * lb && u < 2.0 * lb && w < 2.0 * lb) {
                continue;
            }
            *slot = self
                .corner_time(k, (u, la / at), (w, lc / ct), bt)
                .map(|tv| (tv, self.x_mm[k] + u * ux, self.y_mm[k] + u * uy));
        }
        // A turnaround whose pitch step holds one sample: chords k and k + 1 each cut a
        // corner, between antiparallel lines k - 1 and k + 2 (each straight on with the chord
        // beyond it). The step runs from line to line through that sample, square to the
        // lines (a raster's step).
        let cos_straight = STRAIGHT_TURN_DEG.to_radians().cos();
        let straight = |a: usize| {
            let ((px, py, _, lp), (qx, qy, _, lq)) = (chord(a), chord(a + 1));
            lp > 0.0 && lq > 0.0 && px * qx + py * qy >= cos_straight * lp * lq
        };
        for k in 2..n.saturating_sub(4) {
            if !(straight(k - 2) && straight(k + 2)) {
                continue;
            }
            let (ax, ay, at, la) = chord(k - 1);
            let (_, _, bt, lb) = chord(k);
            let (_, _, ct, lc) = chord(k + 1);
            let (dx, dy, dt, ld) = chord(k + 2);
            let tiny = 1e-9 * (la + lb + lc + ld).max(f64::MIN_POSITIVE);
            if la <= tiny || lb <= tiny || lc <= tiny || ld <= tiny {
                continue;
            }
            let (ux, uy, wx, wy) = (ax / la, ay / la, dx / ld, dy / ld);
            if ux * wx + uy * wy > -cos_turn {
                continue;
            }
            // The sample in the step, and where the step meets each line.
            let (px, py) = (self.x_mm[k + 1], self.y_mm[k + 1]);
            let u = (px - self.x_mm[k]) * ux + (py - self.y_mm[k]) * uy;
            let w = (self.x_mm[k + 2] - px) * wx + (self.y_mm[k + 2] - py) * wy;
            let v1 = (self.x_mm[k] + u * ux, self.y_mm[k] + u * uy);
            let v2 = (self.x_mm[k + 2] - w * wx, self.y_mm[k + 2] - w * wy);
            let h1 = (px - v1.0).hypot(py - v1.1);
            let h2 = (px - v2.0).hypot(py - v2.1);
            if !(u > 1e-6 * lb && w > 1e-6 * lc && h1 > 1e-6 * lb && h2 > 1e-6 * lc) {
                continue;
            }
            // The step's speed: its length over the time the two chords leave it.
            let left = bt + ct - u * at / la - w * dt / ld;
            if left <= 0.0 {
                continue;
            }
            let vs = (h1 + h2) / left;
            let t1 = self.corner_time(k, (u, la / at), (h1, vs), bt);
            let t2 = self.corner_time(k + 1, (h2, vs), (w, ld / dt), ct);
            if let (Some(t1), Some(t2)) = (t1, t2) {
                vertex[k] = Some((t1, v1.0, v1.1));
                vertex[k + 1] = Some((t2, v2.0, v2.1));
            }
        }
        // A chord between two chords that cut corners is the step between them: where the
        // lines through its neighbours meet is not a corner it cut.
        let between: Vec<bool> = (0..vertex.len())
            .map(|k| {
                k >= 1
                    && k + 1 < vertex.len()
                    && vertex[k - 1].is_some()
                    && vertex[k].is_some()
                    && vertex[k + 1].is_some()
            })
            .collect();
        for (v, b) in vertex.iter_mut().zip(between) {
            if b {
                *v = None;
            }
        }
        let mut out = PathLog::default();
        for k in 0..n {
            out.t_s.push(self.t_s[k]);
            out.x_mm.push(self.x_mm[k]);
            out.y_mm.push(self.y_mm[k]);
            if let Some(&Some((t, x, y))) = vertex.get(k) {
                out.t_s.push(t);
                out.x_mm.push(x);
                out.y_mm.push(y);
            }
        }
        out
    }

    /// When the tool passed a corner inside chord k (duration `bt`, s) whose legs are
    /// `(length mm, speed mm/s)` before and after it: the chord's time split over the legs in
    /// proportion to each leg's time at its speed. `None` when the legs cannot be travelled
    /// in the chord's time (more than [`CORNER_SLACK`] of it short: the vertex is not a
    /// corner the chord cut) or the corner would fall within rounding of a sample.
    fn corner_time(&self, k: usize, leg1: (f64, f64), leg2: (f64, f64), bt: f64) -> Option<f64> {
        let ((l1, v1), (l2, v2)) = (leg1, leg2);
        if !(v1 > 0.0 && v2 > 0.0 && v1.is_finite() && v2.is_finite()) {
            return None;
        }
        let (t1, t2) = (l1 / v1, l2 / v2);
        if bt - t1 - t2 < -CORNER_SLACK * bt {
            return None;
        }
        let tv = self.t_s[k] + bt * t1 / (t1 + t2);
        // Times stay strictly increasing (a vertex within rounding of a sample is left out).
        (tv > self.t_s[k] && tv < self.t_s[k + 1]).then_some(tv)
    }

    /// Per-sample `values` of this path (linear in time between samples) at `times` (s, within
    /// the path's span and increasing): how a per-sample quantity (a rate weight) follows the
    /// path onto [`Self::with_corners`]' or [`Self::densified`]'s samples.
    pub fn values_at(&self, values: &[f64], times: &[f64]) -> Vec<f64> {
        let n = self.len().min(values.len());
        let mut k = 0;
        times
            .iter()
            .map(|&t| {
                if n < 2 {
                    return values.first().copied().unwrap_or(0.0);
                }
                while k + 2 < n && self.t_s[k + 1] <= t {
                    k += 1;
                }
                let f = ((t - self.t_s[k]) / (self.t_s[k + 1] - self.t_s[k])).clamp(0.0, 1.0);
                values[k] + f * (values[k + 1] - values[k])
            })
            .collect()
    }

    /// Sub-steps of the path: for every segment, `m` equal pieces no longer than `max_step_mm`
    /// (and no longer than `max_dt_s` in time), each given as (midpoint x, y, duration, segment
    /// index, fraction along the segment at the midpoint). Calls `f` for each.
    pub fn for_each_substep(
        &self,
        max_step_mm: f64,
        max_dt_s: f64,
        mut f: impl FnMut(f64, f64, f64, usize, f64),
    ) {
        for k in 0..self.len().saturating_sub(1) {
            let (x0, y0) = (self.x_mm[k], self.y_mm[k]);
            let (ddx, ddy) = (self.x_mm[k + 1] - x0, self.y_mm[k + 1] - y0);
            let dt = self.t_s[k + 1] - self.t_s[k];
            let m = substeps(ddx.hypot(ddy), dt, max_step_mm, max_dt_s);
            let h = dt / m as f64;
            for s in 0..m {
                let fr = (s as f64 + 0.5) / m as f64;
                f(x0 + fr * ddx, y0 + fr * ddy, h, k, fr);
            }
        }
    }
}

/// Smallest turn between the chords on either side of a chord that [`PathLog::with_corners`]
/// reads as a corner inside it (degrees).
pub const CORNER_TURN_DEG: f64 = 30.0;

/// How far short of a chord's time its restored corner's legs may fall (a fraction of the
/// chord's time; [`PathLog::with_corners`]). Legs that need longer at their neighbours' speeds
/// than the chord took mean the chords on either side cut corners themselves: the chord is a
/// pitch step between two cut corners, not a corner. Measured on 10 Hz logs of rasters at 2
/// to 4 mm pitch: restored corners have 0 to 0.27 of the chord's time spare, such chords
/// 0.27 to 2 short.
pub const CORNER_SLACK: f64 = 0.1;

/// Two chords turning by less than this (degrees) run on in the same direction (a line of a
/// raster on either side of a turnaround, [`PathLog::with_corners`]).
pub const STRAIGHT_TURN_DEG: f64 = 5.0;

/// Number of equal sub-steps of a segment (at least 1, bounded so a corrupt log cannot ask for
/// an absurd allocation of time).
pub(crate) fn substeps(len_mm: f64, dt_s: f64, max_step_mm: f64, max_dt_s: f64) -> usize {
    let a = if max_step_mm > 0.0 {
        (len_mm / max_step_mm).ceil()
    } else {
        1.0
    };
    let b = if max_dt_s > 0.0 {
        (dt_s / max_dt_s).ceil()
    } else {
        1.0
    };
    a.max(b).clamp(1.0, 1.0e7) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn substeps_cover_the_duration_and_length() {
        let p = PathLog::new(
            vec![0.0, 2.0, 3.0],
            vec![0.0, 1.0, 1.0],
            vec![0.0, 0.0, 0.5],
        )
        .unwrap();
        let (mut t, mut x_weighted) = (0.0, 0.0);
        p.for_each_substep(0.1, 1.0, |x, _, dt, _, _| {
            t += dt;
            x_weighted += x * dt;
        });
        assert!((t - 3.0).abs() < 1e-12);
        // Time-weighted mean x: 2 s at mean 0.5, 1 s at 1.0.
        assert!((x_weighted / t - 2.0 / 3.0).abs() < 1e-12);
        assert!((p.length_mm() - 1.5).abs() < 1e-12);
        assert_eq!(p.position_at(2.5), Some((1.0, 0.25)));
        assert!(PathLog::new(vec![0.0, 0.0], vec![0.0; 2], vec![0.0; 2]).is_err());
    }

    /// A raster turn (along +x at 2 mm/s, a 2 mm pitch step in +y at 8 mm/s, back along -x
    /// at 2 mm/s), sampled every 0.1 s from an offset so that no sample falls on a corner.
    fn raster_turn(t: f64) -> (f64, f64) {
        let (t1, t2) = (5.0, 5.25);
        if t <= t1 {
            (2.0 * t, 0.0)
        } else if t <= t2 {
            (10.0, 8.0 * (t - t1))
        } else {
            (10.0 - 2.0 * (t - t2), 2.0)
        }
    }

    #[test]
    fn corners_cut_by_the_samples_are_restored() {
        let ts: Vec<f64> = (0..100).map(|k| 0.037 + 0.1 * k as f64).collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = ts.iter().map(|&t| raster_turn(t)).unzip();
        let p = PathLog::new(ts.clone(), xs, ys).unwrap();
        let c = p.with_corners();
        assert_eq!(c.len(), p.len() + 2);
        assert!(PathLog::new(c.t_s.clone(), c.x_mm.clone(), c.y_mm.clone()).is_ok());
        // The two vertices, where the motion turned, at the times it turned.
        for (tv, xv, yv) in [(5.0, 10.0, 0.0), (5.25, 10.0, 2.0)] {
            let k = c
                .x_mm
                .iter()
                .zip(&c.y_mm)
                .position(|(x, y)| (x - xv).abs() < 1e-9 && (y - yv).abs() < 1e-9)
                .expect("vertex restored");
            assert!((c.t_s[k] - tv).abs() < 1e-9, "{} against {tv}", c.t_s[k]);
        }
        // The restored path is the motion itself (straight legs at constant speed).
        for k in 0..400 {
            let t = 0.04 + 0.0245 * k as f64;
            let (a, b) = (c.position_at(t).unwrap(), raster_turn(t));
            assert!((a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9, "{t}");
        }
        // The chord reading cuts the corners by up to 0.3 mm.
        let cut = (0..400)
            .map(|k| 0.04 + 0.0245 * k as f64)
            .map(|t| {
                let (a, b) = (p.position_at(t).unwrap(), raster_turn(t));
                (a.0 - b.0).hypot(a.1 - b.1)
            })
            .fold(0.0, f64::max);
        assert!(cut > 0.1, "{cut}");
        // Read once, the corners are the path's own: a second reading changes nothing.
        assert_eq!(c.with_corners(), c);
        // A per-sample weight linear in time follows onto the restored samples exactly.
        let w: Vec<f64> = p.t_s.iter().map(|t| 1.0 + 0.03 * t).collect();
        let wc = p.values_at(&w, &c.t_s);
        assert_eq!(wc.len(), c.len());
        for (v, t) in wc.iter().zip(&c.t_s) {
            assert!((v - (1.0 + 0.03 * t)).abs() < 1e-12, "{v} at {t}");
        }
    }

    /// A corner of a motion: (t s, x mm, y mm).
    type Corner = (f64, f64, f64);

    /// A raster of `lines` lines 10 mm long at 5 mm/s joined by `pitch` mm steps at 12 mm/s,
    /// the tool stopping at every corner with 500 mm/s^2 (as a robot does): position at time
    /// t, and the corners' (t, x, y). Exact kinematics, independent of any log reading.
    fn stop_and_go(lines: usize, pitch: f64) -> (impl Fn(f64) -> (f64, f64), Vec<Corner>) {
        let a = 500.0;
        // (start x, start y, unit x, unit y, length, cruise speed, start time)
        let mut legs: Vec<(f64, f64, f64, f64, f64, f64, f64)> = Vec::new();
        let (mut x, mut y, mut t) = (0.0, 0.0, 0.0);
        let mut corners = Vec::new();
        for i in 0..lines {
            let dir = if i % 2 == 0 { 1.0 } else { -1.0 };
            let mut steps = vec![(dir, 0.0, 10.0, 5.0)];
            if i + 1 < lines {
                steps.push((0.0, 1.0, pitch, 12.0));
            }
            for (ux, uy, len, v) in steps {
                if !legs.is_empty() {
                    corners.push((t, x, y));
                }
                legs.push((x, y, ux, uy, len, v, t));
                t += len / v + v / a;
                x += ux * len;
                y += uy * len;
            }
        }
        let at = move |t: f64| {
            let leg = legs
                .iter()
                .rev()
                .find(|l| l.6 <= t)
                .copied()
                .unwrap_or(legs[0]);
            let (x0, y0, ux, uy, len, v, t0) = leg;
            let (ta, da) = (v / a, v * v / (2.0 * a));
            let tc = (len - 2.0 * da) / v;
            let s = (t - t0).max(0.0);
            let d = if s < ta {
                0.5 * a * s * s
            } else if s < ta + tc {
                da + v * (s - ta)
            } else {
                let r = (2.0 * ta + tc - s).max(0.0);
                len - 0.5 * a * r * r
            };
            (x0 + ux * d, y0 + uy * d)
        };
        (at, corners)
    }

    #[test]
    fn a_stop_and_go_raster_logged_at_10_hz_gets_its_corners_back() {
        // 2 mm steps take 0.19 s: at 10 Hz one turnaround in ten holds a single sample in its
        // step (two consecutive cut corners), the others two. Twenty log phases.
        let (motion, corners) = stop_and_go(12, 2.0);
        let end = corners.last().unwrap().0 + 2.0;
        let (mut single, mut worst_t, mut worst_d) = (0, 0.0f64, 0.0f64);
        for phase in 0..20 {
            let ts: Vec<f64> = (0..)
                .map(|k| 0.0013 + 0.00497 * phase as f64 + 0.1 * k as f64)
                .take_while(|&t| t < end)
                .collect();
            let (xs, ys): (Vec<f64>, Vec<f64>) = ts.iter().map(|&t| motion(t)).unzip();
            let p = PathLog::new(ts.clone(), xs, ys).unwrap();
            let c = p.with_corners();
            // Every vertex added is a corner, at about the time the tool was there.
            for k in (0..c.len()).filter(|k| !ts.contains(&c.t_s[*k])) {
                let (d, dt) = corners
                    .iter()
                    .map(|&(tc, xc, yc)| ((c.x_mm[k] - xc).hypot(c.y_mm[k] - yc), c.t_s[k] - tc))
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap();
                worst_d = worst_d.max(d);
                worst_t = worst_t.max(dt.abs());
            }
            // Every corner no sample fell on (to 0.1 um) is restored.
            for &(_, xc, yc) in &corners {
                let near = |x: &[f64], y: &[f64]| {
                    x.iter().zip(y).any(|(x, y)| (x - xc).hypot(y - yc) < 1e-4)
                };
                assert!(
                    near(&p.x_mm, &p.y_mm) || near(&c.x_mm, &c.y_mm),
                    "phase {phase}: corner ({xc}, {yc}) not restored"
                );
            }
            for w in corners.chunks(2) {
                let in_step = ts.iter().filter(|&&t| t > w[0].0 && t < w[1].0).count();
                single += usize::from(in_step == 1);
            }
        }
        assert!(single >= 10, "{single} single-sample steps");
        // Positions exact; times within the stop a corner costs (10-24 ms), which the split
        // by the legs' times does not place (measured: 10.0 ms at worst).
        assert!(worst_d < 1e-9, "{worst_d} mm");
        assert!(worst_t < 0.012, "{worst_t} s");
    }

    #[test]
    fn a_step_between_two_cut_corners_is_not_a_corner() {
        // A 2 mm step at 12 mm/s holding two samples: the chord between them runs square to
        // the lines, and the lines through its neighbours (each cutting a corner) meet
        // outside the raster; it must stay straight.
        let (motion, corners) = stop_and_go(2, 2.0);
        let ts: Vec<f64> = (0..30).map(|k| 0.0613 + 0.1 * k as f64).collect();
        assert_eq!(
            ts.iter()
                .filter(|&&t| t > corners[0].0 && t < corners[1].0)
                .count(),
            2
        );
        let (xs, ys): (Vec<f64>, Vec<f64>) = ts.iter().map(|&t| motion(t)).unzip();
        let c = PathLog::new(ts, xs, ys).unwrap().with_corners();
        assert!(c.x_mm.iter().all(|&x| x <= 10.0 + 1e-9), "{:?}", c.x_mm);
    }

    #[test]
    fn smooth_curves_and_sampled_corners_are_left_alone() {
        // A circle sampled every 10 degrees: 20 degrees over two chords.
        let n = 40;
        let a = |k: usize| k as f64 * 10f64.to_radians();
        let p = PathLog::new(
            (0..n).map(|k| k as f64).collect(),
            (0..n).map(|k| 5.0 * a(k).cos()).collect(),
            (0..n).map(|k| 5.0 * a(k).sin()).collect(),
        )
        .unwrap();
        assert_eq!(p.with_corners(), p);
        // A raster turn sampled on its corners.
        let ts: Vec<f64> = (0..80).map(|k| 0.125 * k as f64).collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = ts.iter().map(|&t| raster_turn(t)).unzip();
        let p = PathLog::new(ts, xs, ys).unwrap();
        assert_eq!(p.with_corners(), p);
    }

    #[test]
    fn densified_keeps_the_motion() {
        let p = PathLog::new(
            vec![0.0, 2.0, 3.0],
            vec![0.0, 1.0, 1.0],
            vec![0.0, 0.0, 0.5],
        )
        .unwrap();
        let d = p.densified(0.1);
        assert_eq!(d.len(), 10 + 5 + 1);
        assert!(PathLog::new(d.t_s.clone(), d.x_mm.clone(), d.y_mm.clone()).is_ok());
        for t in [0.0, 0.37, 1.99, 2.0, 2.5, 3.0] {
            let (a, b) = (p.position_at(t).unwrap(), d.position_at(t).unwrap());
            assert!(
                (a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12,
                "{t}"
            );
        }
        assert_eq!((d.t_s[10], d.x_mm[10]), (2.0, 1.0));
    }
}
