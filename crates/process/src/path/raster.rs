//! Raster ("grating") paths: lines along the scan axis, stepped along the other axis by the
//! pitch (the grating spacing), at a constant feed. Samples are emitted every `sample_dt_s` and
//! at every corner, so the log is exact for straight-line interpolation between samples.
//!
//! Bidirectional rasters reverse every other line. Unidirectional rasters return to the start
//! side at `rapid_mm_per_s` along the next line (a robot without a lift stays in contact, so the
//! return's small dwell is part of the log). Lines extend `overtravel_mm` past the scan range on
//! both ends, so the tool enters and leaves the part at full feed.

use serde::{Deserialize, Serialize};

use super::PathLog;
use crate::error::ProcessError;

/// The axis the lines run along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ScanAxis {
    /// Lines along X, stepped along Y (the paper's grating path).
    X,
    /// Lines along Y, stepped along X.
    Y,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RasterSpec {
    /// Scan range along the scan axis (start, end) in mm, without overtravel.
    pub scan_range_mm: (f64, f64),
    /// Step range along the other axis (first line, last line bound) in mm.
    pub step_range_mm: (f64, f64),
    pub pitch_mm: f64,
    pub axis: ScanAxis,
    pub bidirectional: bool,
    pub overtravel_mm: f64,
    pub feed_mm_per_s: f64,
    /// Return speed of unidirectional rasters.
    pub rapid_mm_per_s: f64,
    /// Sampling interval of the emitted log.
    pub sample_dt_s: f64,
}

impl RasterSpec {
    /// A bidirectional X raster over a rectangle with the paper's feed (1.6 mm/s) and pitch.
    pub fn over_rect(
        x_mm: (f64, f64),
        y_mm: (f64, f64),
        pitch_mm: f64,
        feed_mm_per_s: f64,
    ) -> RasterSpec {
        RasterSpec {
            scan_range_mm: x_mm,
            step_range_mm: y_mm,
            pitch_mm,
            axis: ScanAxis::X,
            bidirectional: true,
            overtravel_mm: 0.0,
            feed_mm_per_s,
            rapid_mm_per_s: 10.0 * feed_mm_per_s,
            sample_dt_s: 0.1,
        }
    }

    /// Line positions along the step axis.
    pub fn line_positions_mm(&self) -> Vec<f64> {
        let (a, b) = self.step_range_mm;
        let n = ((b - a) / self.pitch_mm + 1e-9).floor().max(0.0) as usize + 1;
        (0..n).map(|k| a + k as f64 * self.pitch_mm).collect()
    }

    /// The corner points (scan, step coordinates) and the speed of each leg.
    fn legs(&self) -> (Vec<(f64, f64)>, Vec<f64>) {
        let (s0, s1) = (
            self.scan_range_mm.0 - self.overtravel_mm,
            self.scan_range_mm.1 + self.overtravel_mm,
        );
        let lines = self.line_positions_mm();
        let mut pts = Vec::with_capacity(2 * lines.len() + 1);
        let mut speeds = Vec::new();
        for (k, &y) in lines.iter().enumerate() {
            let forward = !self.bidirectional || k % 2 == 0;
            let (a, b) = if forward { (s0, s1) } else { (s1, s0) };
            if k > 0 {
                // Step over (bidirectional) or return (unidirectional) to the line start.
                speeds.push(if self.bidirectional {
                    self.feed_mm_per_s
                } else {
                    self.rapid_mm_per_s
                });
            }
            pts.push((a, y));
            speeds.push(self.feed_mm_per_s);
            pts.push((b, y));
        }
        (pts, speeds)
    }

    /// The sampled path log.
    pub fn generate(&self) -> Result<PathLog, ProcessError> {
        let pos = |n: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ProcessError::invalid(format!(
                    "raster {n} must be positive, got {v}"
                )))
            }
        };
        pos("pitch_mm", self.pitch_mm)?;
        pos("feed_mm_per_s", self.feed_mm_per_s)?;
        pos("rapid_mm_per_s", self.rapid_mm_per_s)?;
        pos("sample_dt_s", self.sample_dt_s)?;
        let finite = [
            self.scan_range_mm.0,
            self.scan_range_mm.1,
            self.step_range_mm.0,
            self.step_range_mm.1,
            self.overtravel_mm,
        ];
        if finite.iter().any(|v| !v.is_finite()) || self.overtravel_mm < 0.0 {
            return Err(ProcessError::invalid(
                "raster ranges must be finite, overtravel >= 0",
            ));
        }
        if self.step_range_mm.1 < self.step_range_mm.0 {
            return Err(ProcessError::invalid("raster step range is reversed"));
        }
        let (pts, speeds) = self.legs();
        let est = self.estimated_samples(&pts, &speeds);
        if est > 50_000_000.0 {
            return Err(ProcessError::invalid(
                "raster would need more than 5e7 samples",
            ));
        }
        let mut log = PathLog::default();
        let mut t = 0.0;
        let put = |log: &mut PathLog, t: f64, p: (f64, f64)| {
            let (x, y) = match self.axis {
                ScanAxis::X => (p.0, p.1),
                ScanAxis::Y => (p.1, p.0),
            };
            log.t_s.push(t);
            log.x_mm.push(x);
            log.y_mm.push(y);
        };
        put(&mut log, t, pts[0]);
        for (w, &v) in pts.windows(2).zip(&speeds) {
            let (a, b) = (w[0], w[1]);
            let len = (b.0 - a.0).hypot(b.1 - a.1);
            if len == 0.0 {
                continue;
            }
            let dur = len / v;
            let m = (dur / self.sample_dt_s).ceil().max(1.0) as usize;
            for s in 1..=m {
                let f = s as f64 / m as f64;
                put(
                    &mut log,
                    t + f * dur,
                    (a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1)),
                );
            }
            t += dur;
        }
        Ok(log)
    }

    fn estimated_samples(&self, pts: &[(f64, f64)], speeds: &[f64]) -> f64 {
        pts.windows(2)
            .zip(speeds)
            .map(|(w, v)| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1) / v / self.sample_dt_s + 1.0)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bidirectional_raster_geometry_and_timing() {
        let mut r = RasterSpec::over_rect((0.0, 30.0), (0.0, 9.0), 3.0, 1.5);
        r.overtravel_mm = 2.0;
        let p = r.generate().unwrap();
        // 4 lines of 34 mm plus 3 step-overs of 3 mm, all at 1.5 mm/s.
        assert!((p.length_mm() - (4.0 * 34.0 + 9.0)).abs() < 1e-9);
        assert!((p.duration_s() - (4.0 * 34.0 + 9.0) / 1.5).abs() < 1e-9);
        assert_eq!((p.x_mm[0], p.y_mm[0]), (-2.0, 0.0));
        let last = p.len() - 1;
        assert!((p.x_mm[last] - -2.0).abs() < 1e-12 && (p.y_mm[last] - 9.0).abs() < 1e-12);
        assert!(p.t_s.windows(2).all(|w| w[1] - w[0] <= 0.1 + 1e-12));
    }

    #[test]
    fn unidirectional_y_raster_returns_fast() {
        let mut r = RasterSpec::over_rect((0.0, 10.0), (0.0, 2.0), 1.0, 1.0);
        r.bidirectional = false;
        r.axis = ScanAxis::Y;
        r.rapid_mm_per_s = 10.0;
        let p = r.generate().unwrap();
        let ret = (10.0f64 * 10.0 + 1.0).sqrt();
        assert!((p.duration_s() - (30.0 + 2.0 * ret / 10.0)).abs() < 1e-9);
        // Lines run along Y at fixed x.
        assert_eq!(p.x_mm[0], 0.0);
        assert!(r.generate().is_ok());
        r.pitch_mm = 0.0;
        assert!(r.generate().is_err());
    }
}
