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
    /// behind its end, each within twice the chord's length; the chord's time is split over the
    /// two legs in proportion to each leg's length over its neighbouring chord's speed. Samples
    /// on a corner, smooth curves (turns under the threshold over two chords) and chords next
    /// to a standstill are left as they are.
    pub fn with_corners(&self) -> PathLog {
        let n = self.len();
        let mut out = PathLog::default();
        let chord = |a: usize| {
            (
                self.x_mm[a + 1] - self.x_mm[a],
                self.y_mm[a + 1] - self.y_mm[a],
                self.t_s[a + 1] - self.t_s[a],
            )
        };
        let cos_turn = CORNER_TURN_DEG.to_radians().cos();
        for k in 0..n {
            out.t_s.push(self.t_s[k]);
            out.x_mm.push(self.x_mm[k]);
            out.y_mm.push(self.y_mm[k]);
            if k == 0 || k + 2 >= n {
                continue;
            }
            let (ax, ay, at) = chord(k - 1);
            let (bx, by, bt) = chord(k);
            let (cx, cy, ct) = chord(k + 1);
            let (la, lb, lc) = (ax.hypot(ay), bx.hypot(by), cx.hypot(cy));
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
            let (t1, t2) = (u * at / la, w * ct / lc);
            let tv = self.t_s[k] + bt * t1 / (t1 + t2);
            // Times stay strictly increasing (a vertex within rounding of a sample is left out).
            if !(tv > self.t_s[k] && tv < self.t_s[k + 1]) {
                continue;
            }
            out.t_s.push(tv);
            out.x_mm.push(self.x_mm[k] + u * ux);
            out.y_mm.push(self.y_mm[k] + u * uy);
        }
        out
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
