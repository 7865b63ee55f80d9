//! `periodic_path_error`: the executed path wiggles along one axis,
//! `e(q) = a sin(2 pi q / P) + b cos(2 pi q / P)` (amplitude_mm = hypot(a, b)), where the phase
//! runs with a coordinate of the commanded path: x, y, the arc length, or time (a vibration).
//! Detection: the residual's matched filter for a displacement along the axis,
//! `h_k = dt_k (r * dK/daxis)(p_k)`, is a function of q; its periodogram's peaks give candidate
//! periods; the linearised columns `-(dK/daxis) * D_{sin}`, `... D_{cos}` give a and b.

use rayon::prelude::*;

use crate::effects::{spectral_peaks, Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coord {
    X,
    Y,
    Arc,
    Time,
}

impl Coord {
    pub fn name(self) -> &'static str {
        match self {
            Coord::X => "x",
            Coord::Y => "y",
            Coord::Arc => "arc_length",
            Coord::Time => "time",
        }
    }

    pub fn values(self, p: &Problem) -> Vec<f64> {
        let s = &p.samples;
        match self {
            Coord::X => s.x_mm.clone(),
            Coord::Y => s.y_mm.clone(),
            Coord::Arc => s.arc_mm.clone(),
            Coord::Time => s.t_s.iter().map(|t| t - s.t0_s).collect(),
        }
    }
}

#[derive(Debug, Clone)]
pub struct PeriodicPathError {
    pub axis_x: bool,
    pub coord: Coord,
    /// Period in the coordinate's unit (mm, or s for time).
    pub period: f64,
    pub a: f64,
    pub b: f64,
    /// Mean feed (mm/s), to express a time period in mm.
    pub mean_feed: f64,
}

impl Effect for PeriodicPathError {
    fn kind(&self) -> &'static str {
        "periodic_path_error"
    }
    fn key(&self) -> String {
        format!(
            "periodic_path_error:{}:{}",
            if self.axis_x { "x" } else { "y" },
            self.coord.name()
        )
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.period, self.a, self.b]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.period = v[0].abs().max(1e-6);
        self.a = v[1];
        self.b = v[2];
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![self.period * 1e-3, 0.003, 0.003]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn perturb(&self, p: &Problem, xs: &mut [f64], ys: &mut [f64]) {
        let q = self.coord.values(p);
        let w = 2.0 * std::f64::consts::PI / self.period;
        let target = if self.axis_x { xs } else { ys };
        for (t, qk) in target.iter_mut().zip(q) {
            *t += self.a * (w * qk).sin() + self.b * (w * qk).cos();
        }
    }
    fn implausible(&self, p: &Problem, _lin: &Linear) -> Option<String> {
        let amp = self.a.hypot(self.b);
        let pix = p.grid.dx_mm.max(p.grid.dy_mm);
        let period_mm = self.period_mm();
        let min_period = min_period_mm(p, self.coord);
        if amp > p.tif_radius_mm {
            Some(format!(
                "amplitude {amp:.3} mm is larger than the spot (radius {:.3} mm)",
                p.tif_radius_mm
            ))
        } else if period_mm < min_period {
            Some(format!(
                "period {period_mm:.3} mm is below what the path samples in {} ({min_period:.3} mm): it aliases onto the raster lines",
                self.coord.name()
            ))
        } else if period_mm < 2.0 * pix {
            Some(format!(
                "period {period_mm:.3} mm is below two map pixels ({:.3} mm)",
                2.0 * pix
            ))
        } else {
            None
        }
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        let period_mm = self.period_mm();
        let mut v = vec![
            (
                "axis".into(),
                Param::Text(if self.axis_x { "x" } else { "y" }.into()),
            ),
            ("amplitude_mm".into(), Param::Num(self.a.hypot(self.b))),
            ("period_mm".into(), Param::Num(period_mm)),
            (
                "phase_deg".into(),
                Param::Num(self.b.atan2(self.a).to_degrees()),
            ),
            ("coordinate".into(), Param::Text(self.coord.name().into())),
        ];
        if self.coord == Coord::Time {
            v.push(("period_s".into(), Param::Num(self.period)));
        }
        v
    }
}

impl PeriodicPathError {
    /// The period in mm (a time period through the mean feed).
    pub fn period_mm(&self) -> f64 {
        if self.coord == Coord::Time {
            self.period * self.mean_feed
        } else {
            self.period
        }
    }
}

/// Shortest period (mm) a wiggle in coordinate `coord` can have and still be sampled by the
/// path: across the raster lines (x for lines along y, y for lines along x) the path visits
/// the coordinate only at the line spacing, so anything below two spacings aliases onto the
/// lines; along the path (x or y along the lines, arc length, time) no bound beyond the map's.
pub fn min_period_mm(p: &Problem, coord: Coord) -> f64 {
    let s = &p.samples;
    match coord {
        Coord::X => 2.0 * line_spacing(s, false).unwrap_or(0.0),
        Coord::Y => 2.0 * line_spacing(s, true).unwrap_or(0.0),
        Coord::Arc | Coord::Time => 0.0,
    }
}

/// Spacing (mm) of the raster lines across the scan: the median gap between the distinct line
/// positions (y for lines travelled along x when `lines_along_x`, else x) of the samples moving
/// along the lines; `None` without at least three lines.
pub fn line_spacing(s: &crate::path::Samples, lines_along_x: bool) -> Option<f64> {
    let mut pos: Vec<f64> = (0..s.len())
        .filter(|&k| {
            let (along, across) = if lines_along_x {
                (s.ux[k], s.uy[k])
            } else {
                (s.uy[k], s.ux[k])
            };
            along.abs() > 0.99 && across.abs() < 0.05
        })
        .map(|k| if lines_along_x { s.y_mm[k] } else { s.x_mm[k] })
        .collect();
    pos.sort_by(|a, b| a.total_cmp(b));
    let mut lines: Vec<f64> = Vec::new();
    for v in pos {
        if lines.last().is_none_or(|l| v - l > 1e-3) {
            lines.push(v);
        }
    }
    if lines.len() < 3 {
        return None;
    }
    let mut gaps: Vec<f64> = lines.windows(2).map(|w| w[1] - w[0]).collect();
    let mid = gaps.len() / 2;
    gaps.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Some(gaps[mid])
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    let p = cur.p;
    let s = &p.samples;
    let pix = p.grid.dx_mm.max(p.grid.dy_mm);
    let duration = (s.t1_s - s.t0_s).max(1e-9);
    let arc_total = s.arc_mm.last().copied().unwrap_or(0.0);
    let mean_feed = arc_total / duration;
    let max_feed = s
        .feed_mm_per_s
        .iter()
        .cloned()
        .fold(0.0, f64::max)
        .max(1e-9);
    let (wx, wy) = (
        p.grid.cols as f64 * p.grid.dx_mm,
        p.grid.rows as f64 * p.grid.dy_mm,
    );
    // The two axes side by side (each through its own channel), collected x first.
    let per_axis = |axis_x: bool| -> Vec<Candidate> {
        let kern = if axis_x { Channel::Dx } else { Channel::Dy };
        let h = cur.matched(kern);
        // The coordinates side by side, collected in order.
        let per_coord = |coord: Coord| -> Vec<Candidate> {
            let mut out = Vec::new();
            let key = format!(
                "periodic_path_error:{}:{}",
                if axis_x { "x" } else { "y" },
                coord.name()
            );
            if cur.has(&key) {
                return out;
            }
            let q = coord.values(p);
            // A raster samples the coordinate across its lines only at the line spacing: a
            // wiggle in that coordinate with a period below two spacings is not observed by
            // the path, it aliases onto the lines (a 2.7 mm "period" at a 2.7 mm pitch was
            // accepted with a 0.42 mm amplitude in place of a slow rate oscillation).
            let (pmin, pmax) = match coord {
                Coord::X => (
                    (4.0 * pix).max(2.0 * line_spacing(s, false).unwrap_or(0.0)),
                    wx / 3.0,
                ),
                Coord::Y => (
                    (4.0 * pix).max(2.0 * line_spacing(s, true).unwrap_or(0.0)),
                    wy / 3.0,
                ),
                Coord::Arc => (4.0 * pix, wx.max(wy) / 3.0),
                Coord::Time => (4.0 * pix / max_feed, wx.max(wy) / 3.0 / mean_feed.max(1e-9)),
            };
            for (period, _) in spectral_peaks(&q, &h, pmin, pmax, 1) {
                let w = 2.0 * std::f64::consts::PI / period;
                let gs: Vec<f64> = q.iter().map(|v| (w * v).sin()).collect();
                let gc: Vec<f64> = q.iter().map(|v| (w * v).cos()).collect();
                let cs: Vec<f64> = cur.column(&[(&gs, kern)]).into_iter().map(|v| -v).collect();
                let cc: Vec<f64> = cur.column(&[(&gc, kern)]).into_iter().map(|v| -v).collect();
                out.push(Candidate {
                    key: key.clone(),
                    kind: "periodic_path_error",
                    extra: vec![cs, cc],
                    make: Box::new(move |c, s0| {
                        Box::new(PeriodicPathError {
                            axis_x,
                            coord,
                            period,
                            a: c[0] / s0,
                            b: c[1] / s0,
                            mean_feed,
                        })
                    }),
                });
            }
            out
        };
        [Coord::X, Coord::Y, Coord::Arc, Coord::Time]
            .into_par_iter()
            .map(per_coord)
            .collect::<Vec<_>>()
            .into_iter()
            .flatten()
            .collect()
    };
    let (mut x, y) = rayon::join(|| per_axis(true), || per_axis(false));
    x.extend(y);
    x
}
