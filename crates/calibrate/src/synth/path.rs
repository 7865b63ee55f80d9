//! The tool motion of a synthetic run and its log. The feed along each raster line realises a
//! dwell-per-area map (`bonnetlab_process::path::kinematics::dwell_raster`: piecewise constant
//! feed `1 / (density * pitch)`, then the machine's acceleration limit); that realised motion is
//! what the tool did. The log the calibration gets is that motion sampled at a fixed rate
//! (10 Hz by default), straight lines between samples, as a robot controller records it.

use bonnetlab_process::path::kinematics::{dwell_raster, Limits};
use bonnetlab_process::path::RasterSpec;
use bonnetlab_process::{Grid, PathLog};
use ndarray::Array2;

use crate::error::CalibrateError;

/// The raster over a rectangle.
#[derive(Debug, Clone, Copy)]
pub struct RasterPlan {
    pub x_range_mm: (f64, f64),
    pub y_range_mm: (f64, f64),
    pub pitch_mm: f64,
    pub feed_min_mm_per_s: f64,
    pub feed_max_mm_per_s: f64,
    pub sample_hz: f64,
}

fn perr(e: bonnetlab_process::ProcessError) -> CalibrateError {
    CalibrateError::InvalidInput(format!("synthetic path: {e}"))
}

/// The realised motion (feeds piecewise constant over 0.25 mm pieces, acceleration-limited)
/// and its log at `sample_hz`.
pub fn raster_motion(
    plan: &RasterPlan,
    density_s_per_mm2: &Array2<f64>,
    density_grid: &Grid,
) -> Result<(PathLog, PathLog), CalibrateError> {
    let mut spec = RasterSpec::over_rect(
        plan.x_range_mm,
        plan.y_range_mm,
        plan.pitch_mm,
        plan.feed_max_mm_per_s,
    );
    spec.sample_dt_s = 1.0 / plan.sample_hz;
    let limits = Limits {
        v_min_mm_per_s: plan.feed_min_mm_per_s,
        v_max_mm_per_s: plan.feed_max_mm_per_s,
        ..Limits::default()
    };
    let (_, motion) =
        dwell_raster(&spec, density_s_per_mm2, density_grid, &limits, 0.25).map_err(perr)?;
    let log = sample_log(&motion, plan.sample_hz)?;
    Ok((motion, log))
}

/// `motion` sampled every `1 / hz` s from its start, plus its last instant.
pub fn sample_log(motion: &PathLog, hz: f64) -> Result<PathLog, CalibrateError> {
    if !(hz > 0.0 && hz.is_finite()) || motion.len() < 2 {
        return Err(CalibrateError::InvalidInput(
            "synthetic path: sample rate must be positive".into(),
        ));
    }
    let (t0, t1) = (motion.t_s[0], motion.t_s[motion.len() - 1]);
    let dt = 1.0 / hz;
    let (mut t, mut x, mut y) = (Vec::new(), Vec::new(), Vec::new());
    let mut k = 0usize;
    loop {
        let tk = t0 + k as f64 * dt;
        if tk > t1 - 1e-6 * dt {
            break;
        }
        let (px, py) = motion.position_at(tk).unwrap_or((0.0, 0.0));
        t.push(tk);
        x.push(px);
        y.push(py);
        k += 1;
    }
    t.push(t1);
    x.push(motion.x_mm[motion.len() - 1]);
    y.push(motion.y_mm[motion.len() - 1]);
    PathLog::new(t, x, y).map_err(perr)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_density_raster_takes_area_times_density() {
        let g = Grid::new(21, 21, 1.0, 1.0, -5.0, -5.0).unwrap();
        // 0.05 s/mm^2 at a 1 mm pitch: 20 mm/s along the lines.
        let d = Array2::from_elem((21, 21), 0.05);
        let plan = RasterPlan {
            x_range_mm: (0.0, 10.0),
            y_range_mm: (0.0, 2.0),
            pitch_mm: 1.0,
            feed_min_mm_per_s: 1.0,
            feed_max_mm_per_s: 20.0,
            sample_hz: 10.0,
        };
        let (m, log) = raster_motion(&plan, &d, &g).unwrap();
        // 3 lines of 10 mm + 2 step-overs of 1 mm at 20 mm/s, plus acceleration at 6 stops.
        assert!(m.duration_s() >= 32.0 / 20.0 && m.duration_s() < 32.0 / 20.0 + 0.3);
        assert!((log.duration_s() - m.duration_s()).abs() < 1e-12);
        assert!(log.t_s.windows(2).all(|w| w[1] - w[0] <= 0.1 + 1e-12));
        assert!((log.x_mm.last().unwrap() - 10.0).abs() < 1e-9);
    }
}
