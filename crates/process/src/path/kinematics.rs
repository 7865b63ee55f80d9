//! Kinematics: feeds from a dwell map, and what a machine with velocity and acceleration limits
//! actually executes.
//!
//! - [`dwell_raster`]: a raster whose feed realises a dwell-density map (s/mm^2): along a line of
//!   pitch p the time per unit length is D p, so the feed is v = 1 / (D p), clamped to the
//!   machine's [v_min, v_max].
//! - [`apply_limits`]: re-times a commanded path so the speed never exceeds the commanded speed
//!   or v_max and the tangential acceleration stays within a_max, stopping at sharp corners
//!   (turnarounds): a trapezoidal profile per line, generalised to varying feeds by the usual
//!   forward / backward pass. The realised path is slower where the commanded feed changes faster
//!   than the machine can follow, so it dwells longer there: compare the dwell maps of the
//!   commanded and realised paths ([`crate::removal::dwell_map`]) to see the execution error.

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use super::{PathLog, RasterSpec, ScanAxis};
use crate::error::ProcessError;
use crate::grid::Grid;
use crate::tif::bilinear;

/// Machine limits along the path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    pub v_min_mm_per_s: f64,
    pub v_max_mm_per_s: f64,
    pub a_max_mm_per_s2: f64,
    /// Direction changes sharper than this (deg) are taken from a full stop.
    pub stop_angle_deg: f64,
}

impl Default for Limits {
    /// A robot polishing cell: 0.05 to 200 mm/s, 500 mm/s^2, stop at corners over 30 deg.
    fn default() -> Self {
        Limits {
            v_min_mm_per_s: 0.05,
            v_max_mm_per_s: 200.0,
            a_max_mm_per_s2: 500.0,
            stop_angle_deg: 30.0,
        }
    }
}

impl Limits {
    fn check(&self) -> Result<(), ProcessError> {
        let ok = self.v_min_mm_per_s > 0.0
            && self.v_max_mm_per_s >= self.v_min_mm_per_s
            && self.a_max_mm_per_s2 > 0.0
            && self.v_max_mm_per_s.is_finite()
            && self.a_max_mm_per_s2.is_finite()
            && self.stop_angle_deg.is_finite();
        if ok {
            Ok(())
        } else {
            Err(ProcessError::invalid(
                "limits need 0 < v_min <= v_max and a_max > 0, all finite",
            ))
        }
    }
}

/// Most points a re-timed path may have: seven `f64` vectors of this length are about 220 MB.
pub const MAX_RETIME_POINTS: usize = 4_000_000;

/// Re-times `path` under `limits`. Segments are first split to at most `ds_max_mm` so the speed
/// is nearly constant within each; positions are kept, times change. Zero-length segments
/// (dwelling in place) keep their duration.
pub fn apply_limits(
    path: &PathLog,
    limits: &Limits,
    ds_max_mm: f64,
) -> Result<PathLog, ProcessError> {
    limits.check()?;
    if !(ds_max_mm > 0.0 && ds_max_mm.is_finite()) {
        return Err(ProcessError::invalid("ds_max_mm must be positive"));
    }
    let n = path.len();
    if n < 2 {
        return Ok(path.clone());
    }
    // The size is known before anything is allocated: refuse a path that would need too many
    // points (a log with coordinates of 1e12 mm asks for 1e14) with the numbers that say why.
    let mut length = 0.0f64;
    let mut pieces = 1.0f64;
    for k in 0..n - 1 {
        let len = (path.x_mm[k + 1] - path.x_mm[k]).hypot(path.y_mm[k + 1] - path.y_mm[k]);
        length += len;
        pieces += if len.is_finite() {
            (len / ds_max_mm).ceil().max(1.0)
        } else {
            f64::INFINITY
        };
    }
    if pieces.is_nan() || pieces > MAX_RETIME_POINTS as f64 {
        return Err(ProcessError::invalid(format!(
            "the path is {length:.4e} mm long: re-timing it in {ds_max_mm} mm steps needs \
             {pieces:.3e} points, over the limit of {MAX_RETIME_POINTS} (check the path log's \
             coordinates and units)"
        )));
    }
    let cap = pieces as usize;
    // Split into short pieces, carrying each piece's commanded speed and in-place dwell.
    let mut xs = Vec::with_capacity(cap);
    let mut ys = Vec::with_capacity(cap);
    xs.push(path.x_mm[0]);
    ys.push(path.y_mm[0]);
    let mut cmd_v = Vec::with_capacity(cap);
    let mut still_dt = Vec::with_capacity(cap);
    for k in 0..n - 1 {
        let (x0, y0) = (path.x_mm[k], path.y_mm[k]);
        let (dx, dy) = (path.x_mm[k + 1] - x0, path.y_mm[k + 1] - y0);
        let len = dx.hypot(dy);
        let dt = path.t_s[k + 1] - path.t_s[k];
        let m = super::substeps(len, 0.0, ds_max_mm, 0.0);
        for s in 1..=m {
            let f = s as f64 / m as f64;
            xs.push(x0 + f * dx);
            ys.push(y0 + f * dy);
            if len > 0.0 {
                cmd_v.push((len / dt).clamp(limits.v_min_mm_per_s, limits.v_max_mm_per_s));
                still_dt.push(0.0);
            } else {
                cmd_v.push(0.0);
                still_dt.push(dt / m as f64);
            }
        }
    }
    let np = xs.len();
    let seg_len: Vec<f64> = (0..np - 1)
        .map(|k| (xs[k + 1] - xs[k]).hypot(ys[k + 1] - ys[k]))
        .collect();
    // Node speed caps: 0 at the ends, at stops in place and at sharp corners.
    let cos_stop = limits.stop_angle_deg.to_radians().cos();
    let mut vn = vec![0.0; np];
    for k in 1..np - 1 {
        let (a, b) = (seg_len[k - 1], seg_len[k]);
        if a == 0.0 || b == 0.0 {
            continue;
        }
        let c = ((xs[k] - xs[k - 1]) * (xs[k + 1] - xs[k])
            + (ys[k] - ys[k - 1]) * (ys[k + 1] - ys[k]))
            / (a * b);
        if c >= cos_stop {
            vn[k] = cmd_v[k - 1].min(cmd_v[k]);
        }
    }
    let acc = limits.a_max_mm_per_s2;
    for k in 1..np {
        vn[k] = vn[k].min((vn[k - 1] * vn[k - 1] + 2.0 * acc * seg_len[k - 1]).sqrt());
    }
    for k in (0..np - 1).rev() {
        vn[k] = vn[k].min((vn[k + 1] * vn[k + 1] + 2.0 * acc * seg_len[k]).sqrt());
    }
    let mut t = vec![path.t_s[0]; np];
    for k in 0..np - 1 {
        let s = seg_len[k];
        let dt = if s == 0.0 {
            still_dt[k]
        } else {
            let (v0, v1) = (vn[k], vn[k + 1]);
            let vc = cmd_v[k]
                .min(((v0 * v0 + v1 * v1) / 2.0 + acc * s).sqrt())
                .max(v0.max(v1));
            let s_acc = (vc * vc - v0 * v0) / (2.0 * acc);
            let s_dec = (vc * vc - v1 * v1) / (2.0 * acc);
            let s_cruise = (s - s_acc - s_dec).max(0.0);
            (vc - v0) / acc + (vc - v1) / acc + s_cruise / vc
        };
        // A zero-duration piece cannot occur with s > 0; guard the strict increase anyway.
        t[k + 1] = t[k] + dt.max(1e-12);
    }
    PathLog::new(t, xs, ys)
}

/// A raster whose feed realises `dwell_density_s_per_mm2` (on `grid`), under `limits`.
/// Returns the commanded path (feeds clamped but no acceleration limit) and the realised one.
pub fn dwell_raster(
    spec: &RasterSpec,
    dwell_density_s_per_mm2: &Array2<f64>,
    grid: &Grid,
    limits: &Limits,
    ds_mm: f64,
) -> Result<(PathLog, PathLog), ProcessError> {
    limits.check()?;
    if dwell_density_s_per_mm2.dim() != (grid.rows, grid.cols) {
        return Err(ProcessError::invalid("dwell map and grid differ in shape"));
    }
    if !(ds_mm > 0.0 && ds_mm.is_finite() && spec.pitch_mm > 0.0) {
        return Err(ProcessError::invalid("ds_mm and pitch must be positive"));
    }
    let base = spec.generate()?;
    // Resample the constant-feed raster by arc length and give each piece the feed of its
    // midpoint's dwell density.
    let density_at = |x: f64, y: f64| {
        let (u, v) = grid.frac_index(x, y);
        bilinear(dwell_density_s_per_mm2, u, v)
    };
    let mut t = vec![0.0];
    let mut xs = vec![base.x_mm[0]];
    let mut ys = vec![base.y_mm[0]];
    for k in 0..base.len() - 1 {
        let (x0, y0) = (base.x_mm[k], base.y_mm[k]);
        let (dx, dy) = (base.x_mm[k + 1] - x0, base.y_mm[k + 1] - y0);
        let len = dx.hypot(dy);
        let m = super::substeps(len, 0.0, ds_mm, 0.0);
        let along_scan = match spec.axis {
            ScanAxis::X => dy.abs() < 1e-12,
            ScanAxis::Y => dx.abs() < 1e-12,
        };
        for s in 1..=m {
            let (fm, f) = ((s as f64 - 0.5) / m as f64, s as f64 / m as f64);
            let piece = len / m as f64;
            let v = if along_scan {
                let d = density_at(x0 + fm * dx, y0 + fm * dy);
                if d > 0.0 {
                    1.0 / (d * spec.pitch_mm)
                } else {
                    limits.v_max_mm_per_s
                }
            } else {
                limits.v_max_mm_per_s
            }
            .clamp(limits.v_min_mm_per_s, limits.v_max_mm_per_s);
            let last = *t.last().unwrap_or(&0.0);
            t.push(last + piece / v);
            xs.push(x0 + f * dx);
            ys.push(y0 + f * dy);
        }
    }
    let commanded = PathLog::new(t, xs, ys)?;
    let realised = apply_limits(&commanded, limits, ds_mm)?;
    Ok((commanded, realised))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_on_a_single_line() {
        // 100 mm at 10 mm/s with a = 20 mm/s^2: 0.5 s up, 0.5 s down, 2.5 mm each, 95 mm cruise.
        let p = PathLog::new(vec![0.0, 10.0], vec![0.0, 100.0], vec![0.0, 0.0]).unwrap();
        let lim = Limits {
            a_max_mm_per_s2: 20.0,
            ..Limits::default()
        };
        let r = apply_limits(&p, &lim, 0.5).unwrap();
        assert!(
            (r.duration_s() - (0.5 + 0.5 + 9.5)).abs() < 1e-9,
            "{}",
            r.duration_s()
        );
        // Short line that never reaches cruise: triangle, t = 2 sqrt(s / a).
        let p = PathLog::new(vec![0.0, 0.1], vec![0.0, 2.0], vec![0.0, 0.0]).unwrap();
        let r = apply_limits(&p, &lim, 0.01).unwrap();
        assert!((r.duration_s() - 2.0 * (2.0f64 / 20.0).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn corners_stop_and_straight_joints_do_not() {
        let lim = Limits {
            a_max_mm_per_s2: 10.0,
            ..Limits::default()
        };
        let straight =
            PathLog::new(vec![0.0, 1.0, 2.0], vec![0.0, 10.0, 20.0], vec![0.0; 3]).unwrap();
        let corner = PathLog::new(
            vec![0.0, 1.0, 2.0],
            vec![0.0, 10.0, 10.0],
            vec![0.0, 0.0, 10.0],
        )
        .unwrap();
        let ts = apply_limits(&straight, &lim, 1.0).unwrap().duration_s();
        let tc = apply_limits(&corner, &lim, 1.0).unwrap().duration_s();
        // Straight: 1 s up (5 mm) + 1 s down + 10 mm cruise at 10 mm/s; corner: two 2 s legs.
        assert!((ts - 3.0).abs() < 1e-9, "{ts}");
        assert!((tc - 4.0).abs() < 1e-9, "{tc}");
    }

    #[test]
    fn feed_follows_dwell_density() {
        let grid = Grid::new(21, 41, 0.5, 0.5, 0.0, 0.0).unwrap();
        // 0.5 s/mm^2 on the left half, 0.25 on the right; pitch 2 mm -> 1 and 2 mm/s.
        let d = Array2::from_shape_fn((21, 41), |(_, j)| if j < 20 { 0.5 } else { 0.25 });
        let spec = RasterSpec::over_rect((0.0, 20.0), (4.0, 4.0), 2.0, 1.0);
        let lim = Limits {
            a_max_mm_per_s2: 1e6,
            ..Limits::default()
        };
        let (cmd, real) = dwell_raster(&spec, &d, &grid, &lim, 0.1).unwrap();
        // 10 s + 5 s, less 0.125 s where the bilinear density ramps over the half pixel at x = 10.
        assert!(
            (cmd.duration_s() - 14.875).abs() < 0.01,
            "{}",
            cmd.duration_s()
        );
        assert!((real.duration_s() - cmd.duration_s()).abs() < 0.01);
        let slow = Limits {
            a_max_mm_per_s2: 0.5,
            ..Limits::default()
        };
        let (_, real) = dwell_raster(&spec, &d, &grid, &slow, 0.1).unwrap();
        assert!(real.duration_s() > cmd.duration_s() + 0.5);
    }

    #[test]
    fn huge_coordinates_are_refused_before_allocating() {
        let p = PathLog::new(
            vec![0.0, 1.0, 2.0],
            vec![-1e12, 1e12, -1e12],
            vec![0.0, 0.0, 1e12],
        )
        .unwrap();
        let e = apply_limits(&p, &Limits::default(), 0.1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("over the limit") && e.contains("mm long"), "{e}");
        let p = PathLog::new(vec![0.0, 1.0], vec![-1e308, 1e308], vec![0.0, 0.0]).unwrap();
        let e = apply_limits(&p, &Limits::default(), 0.1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("over the limit"), "{e}");
    }
}
