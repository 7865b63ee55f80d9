//! The commanded tool path (time-stamped tool-centre positions) as the calibration resolves it:
//! the samples of the path with the corners its sampling cut restored
//! ([`PathLog::with_corners`]: a raster's turns into and out of its pitch steps, which a 10 Hz
//! log's chords cut by up to a few tenths of a mm, moving the slow dwell at the turnarounds),
//! densified by the process crate ([`PathLog::densified`]: straight
//! lines at constant speed, pieces no longer than a given step), each carrying its share of the
//! dwell and the along-path covariates the effects use. Per-sample rate weights and position
//! perturbations act on these samples; the forward model interpolates them linearly between
//! samples, as it does for any path.

/// Commanded tool-centre positions in the map frame (mm): the process crate's path type.
pub use bonnetlab_process::PathLog;

/// Samples of the densified commanded path.
#[derive(Debug, Clone, Default)]
pub struct Samples {
    pub t_s: Vec<f64>,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    /// Dwell share of the sample (s): half of each adjacent interval, so a weight interpolated
    /// linearly between samples has the dwell integral `sum_k dt_k g_k`.
    pub dt_s: Vec<f64>,
    /// Unit travel direction, of the mean velocity of the adjacent intervals (0, 0 when the tool
    /// stands still).
    pub ux: Vec<f64>,
    pub uy: Vec<f64>,
    pub feed_mm_per_s: Vec<f64>,
    /// Arc length travelled from the start of the path to the sample (mm).
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

    /// A per-sample quantity less its dwell-weighted mean (how rate terms enter the model: a
    /// centred term leaves the baseline's rate scale alone).
    pub fn centred(&self, q: &[f64]) -> Vec<f64> {
        let mean = self.dwell_mean(q);
        q.iter().map(|v| v - mean).collect()
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

impl Samples {
    /// The samples of `path` with its cut corners restored and densified to pieces of at most
    /// `max_step_mm`, and that path (the commanded motion as read).
    pub fn of(path: &PathLog, max_step_mm: f64) -> (Samples, PathLog) {
        let d = path.with_corners().densified(max_step_mm.max(1e-6));
        let n = d.len();
        let mut s = Samples {
            t0_s: d.t_s.first().copied().unwrap_or(0.0),
            t1_s: d.t_s.last().copied().unwrap_or(0.0),
            t_s: d.t_s.clone(),
            x_mm: d.x_mm.clone(),
            y_mm: d.y_mm.clone(),
            ..Samples::default()
        };
        // Velocity of interval k (between samples k and k + 1).
        let vel: Vec<(f64, f64, f64)> = (0..n.saturating_sub(1))
            .map(|k| {
                let dt = d.t_s[k + 1] - d.t_s[k];
                let (dx, dy) = (d.x_mm[k + 1] - d.x_mm[k], d.y_mm[k + 1] - d.y_mm[k]);
                (dx / dt, dy / dt, dt)
            })
            .collect();
        let mut arc = 0.0;
        for k in 0..n {
            let before = k.checked_sub(1).map(|j| vel[j]);
            let after = vel.get(k).copied();
            let (mut vx, mut vy, mut m, mut dt) = (0.0, 0.0, 0.0, 0.0);
            for (ax, ay, adt) in before.into_iter().chain(after) {
                vx += ax;
                vy += ay;
                m += 1.0;
                dt += 0.5 * adt;
            }
            let (vx, vy) = if m > 0.0 {
                (vx / m, vy / m)
            } else {
                (0.0, 0.0)
            };
            let speed = vx.hypot(vy);
            let (ux, uy) = if speed > 1e-12 {
                (vx / speed, vy / speed)
            } else {
                (0.0, 0.0)
            };
            if k > 0 {
                arc += (d.x_mm[k] - d.x_mm[k - 1]).hypot(d.y_mm[k] - d.y_mm[k - 1]);
            }
            s.dt_s.push(dt);
            s.ux.push(ux);
            s.uy.push(uy);
            s.feed_mm_per_s.push(speed);
            s.arc_mm.push(arc);
        }
        (s, d)
    }

    /// The path through `(xs, ys)` at the samples' times (the executed path of a perturbed
    /// state).
    pub fn path_through(&self, xs: &[f64], ys: &[f64]) -> PathLog {
        PathLog {
            t_s: self.t_s.clone(),
            x_mm: xs.to_vec(),
            y_mm: ys.to_vec(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_share_the_time_and_follow_the_motion() {
        let p = PathLog::new(
            vec![0.0, 2.0, 3.0],
            vec![0.0, 1.0, 1.0],
            vec![0.0, 0.0, 0.5],
        )
        .unwrap();
        let (s, d) = Samples::of(&p, 0.1);
        let total: f64 = s.dt_s.iter().sum();
        assert!((total - 3.0).abs() < 1e-12);
        assert_eq!(s.len(), 10 + 5 + 1);
        assert_eq!(d.len(), s.len());
        assert!((s.feed_mm_per_s[3] - 0.5).abs() < 1e-12);
        assert!((s.uy[12] - 1.0).abs() < 1e-12);
        assert!((s.arc_mm[14] - (1.0 + 0.4)).abs() < 1e-12);
        // The corner between the two segments: the mean of their velocities.
        assert!((s.ux[10] - s.uy[10]).abs() < 1e-12);
    }
}
