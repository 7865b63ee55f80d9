//! The commanded tool path (time-stamped tool-centre positions) and its densification into
//! short sub-steps, each carrying its dwell and the along-path covariates the effects use.
//!
//! Between two logged samples the tool is taken to move in a straight line at constant speed
//! (the log is the commanded motion). Each segment is cut into sub-steps no longer than
//! `max_step_mm`; a sub-step is represented by its midpoint, its duration `dt_s`, its unit travel
//! direction and its feed.

/// Commanded tool-centre positions in the map frame (mm): the process crate's path type.
pub use bonnetlab_process::PathLog;

/// Sub-steps of the commanded path (midpoints).
#[derive(Debug, Clone, Default)]
pub struct Samples {
    pub t_s: Vec<f64>,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub dt_s: Vec<f64>,
    /// Unit travel direction (0, 0 when the tool stands still).
    pub ux: Vec<f64>,
    pub uy: Vec<f64>,
    pub feed_mm_per_s: Vec<f64>,
    /// Arc length travelled from the start of the path to the midpoint (mm).
    pub arc_mm: Vec<f64>,
    /// Start and end time of the run (s).
    pub t0_s: f64,
    pub t1_s: f64,
}

impl Samples {
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Run time fraction in [0, 1] of sub-step `k`.
    pub fn tau(&self, k: usize) -> f64 {
        (self.t_s[k] - self.t0_s) / (self.t1_s - self.t0_s).max(f64::MIN_POSITIVE)
    }

    /// Dwell-weighted mean of a per-sample quantity.
    pub fn dwell_mean(&self, q: &[f64]) -> f64 {
        let (mut s, mut w) = (0.0, 0.0);
        for (v, dt) in q.iter().zip(&self.dt_s) {
            s += v * dt;
            w += dt;
        }
        if w > 0.0 {
            s / w
        } else {
            0.0
        }
    }
}

/// Cuts the path into sub-steps of at most `max_step_mm` (and at least one per segment).
pub fn densify(path: &PathLog, max_step_mm: f64) -> Samples {
    let step = max_step_mm.max(1e-6);
    let mut s = Samples {
        t0_s: path.t_s.first().copied().unwrap_or(0.0),
        t1_s: path.t_s.last().copied().unwrap_or(0.0),
        ..Samples::default()
    };
    let mut arc = 0.0;
    for k in 0..path.len().saturating_sub(1) {
        let (t0, t1) = (path.t_s[k], path.t_s[k + 1]);
        let (x0, y0) = (path.x_mm[k], path.y_mm[k]);
        let (ddx, ddy) = (path.x_mm[k + 1] - x0, path.y_mm[k + 1] - y0);
        let len = ddx.hypot(ddy);
        // A segment implying an absurd number of sub-steps is bad data; cap keeps memory bounded.
        let n = ((len / step).ceil() as usize).clamp(1, 100_000);
        let dt = (t1 - t0) / n as f64;
        let (ux, uy) = if len > 0.0 {
            (ddx / len, ddy / len)
        } else {
            (0.0, 0.0)
        };
        let feed = len / (t1 - t0);
        for m in 0..n {
            let f = (m as f64 + 0.5) / n as f64;
            s.t_s.push(t0 + f * (t1 - t0));
            s.x_mm.push(x0 + f * ddx);
            s.y_mm.push(y0 + f * ddy);
            s.dt_s.push(dt);
            s.ux.push(ux);
            s.uy.push(uy);
            s.feed_mm_per_s.push(feed);
            s.arc_mm.push(arc + f * len);
        }
        arc += len;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn densify_conserves_time_and_length() {
        let p = PathLog::new(
            vec![0.0, 2.0, 3.0],
            vec![0.0, 1.0, 1.0],
            vec![0.0, 0.0, 0.5],
        )
        .unwrap();
        let s = densify(&p, 0.1);
        let total: f64 = s.dt_s.iter().sum();
        assert!((total - 3.0).abs() < 1e-12);
        assert_eq!(s.len(), 10 + 5);
        assert!((s.feed_mm_per_s[0] - 0.5).abs() < 1e-12);
        assert!((s.uy[12] - 1.0).abs() < 1e-12);
        assert!((s.arc_mm[14] - (1.0 + 0.45)).abs() < 1e-12);
        assert!(PathLog::new(vec![0.0, 0.0], vec![0.0; 2], vec![0.0; 2]).is_err());
    }
}
