//! Generator of synthetic measured runs, independent of the calibration's fast model.
//!
//! A run: an analytic before surface (figure + MSF), a commanded raster path whose feed realises
//! a dwell map derived from that surface, a measured spot (the true TIF dwelled at a point, as a
//! noisy height map), and the after map made by exact time-domain deposition of the true TIF
//! along the *executed* path at the *true* instantaneous rate, then misregistered, tilted,
//! noised and given dropouts. Effects the model is not told about are injected through
//! [`Injected`]; several are outside the calibration library's exact forms on purpose.
//!
//! Conventions of the injected effects (what the calibration should report):
//! - rate factors multiply: `rate(t) = rate_0 * prod(factors)`; `RateDrift`: `1 + f * tau`
//!   (tau = run-time fraction 0..1); `RateCovariate`: `1 + c * q` with q in natural units (x, y, mm;
//!   feed mm/s; height nm and slope nm/mm of the before surface without piston/tilt; signed
//!   distance to the part edge mm; time s);
//! - executed position = commanded - lag * u (u = unit travel direction) + path error;
//! - registration: a feature at true position p appears in the after map at
//!   `R(theta) (p - c) + c + (dx, dy)`, c = map centre.

pub mod deposit;
pub mod raster;
pub mod surface_fn;
pub mod true_tif;
pub mod write;

use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use ndarray::Array2;

use crate::error::CalibrateError;
use crate::grid::MapGrid;
use crate::path::PathLog;
use deposit::Instant;
use raster::RasterPlan;
use surface_fn::SurfaceFn;
use true_tif::TrueTif;

/// Shape of a periodic path error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Waveform {
    Sine,
    /// Symmetric triangle wave of the same amplitude and period (outside the library's form).
    Triangle,
}

/// What a periodic path error's phase runs with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WiggleCoord {
    /// Commanded x (mm).
    X,
    /// Commanded y (mm).
    Y,
    /// Arc length along the commanded path (mm).
    Arc,
}

/// An effect injected into a run (the calibration is not told).
#[derive(Debug, Clone, PartialEq)]
pub enum Injected {
    Registration {
        dx_mm: f64,
        dy_mm: f64,
        rotation_deg: f64,
    },
    RateDrift {
        fraction_per_run: f64,
    },
    TifScale {
        scale: f64,
    },
    DirectionLag {
        lag_mm: f64,
    },
    PeriodicPathError {
        axis_x: bool,
        amplitude_mm: f64,
        period_mm: f64,
        phase_rad: f64,
        coord: WiggleCoord,
        waveform: Waveform,
    },
    RateCovariate {
        covariate: String,
        coefficient: f64,
    },
    /// Rate oscillating in time: factor 1 + a sin(2 pi t / period_s).
    RateOscillation {
        amplitude_fraction: f64,
        period_s: f64,
    },
    /// Pressure drift step: factor 1 + fraction after run-time fraction `at_tau`.
    RateStep {
        at_tau: f64,
        fraction: f64,
    },
    /// A local pit in the after surface (not removal by the tool): Gaussian, depth nm.
    LocalDefect {
        x_mm: f64,
        y_mm: f64,
        radius_mm: f64,
        depth_nm: f64,
    },
    /// Constant offset of the executed spot from the commanded position.
    PathOffset {
        dx_mm: f64,
        dy_mm: f64,
    },
}

#[derive(Debug, Clone)]
pub struct SynthConfig {
    pub seed: u64,
    pub rows: usize,
    pub cols: usize,
    pub pixel_mm: f64,
    pub figure_rms_nm: f64,
    pub msf_rms_nm: f64,
    pub tif: TrueTif,
    pub pitch_mm: f64,
    pub feed_min_mm_per_s: f64,
    pub feed_max_mm_per_s: f64,
    pub sample_hz: f64,
    /// Deposition step along the executed path (mm).
    pub deposit_step_mm: f64,
    pub spot_dwell_s: f64,
    pub spot_noise_nm: f64,
    /// Where the spot's dip sits in its map, (x, y) mm from the map's centre pixel (a real
    /// spot is never exactly centred).
    pub spot_offset_mm: (f64, f64),
    /// White measurement noise RMS of each map (nm).
    pub noise_nm: f64,
    pub dropout_fraction: f64,
    /// Set-up tilt of the after map (nm across the map) and piston (nm).
    pub setup_tilt_nm: f64,
    pub setup_piston_nm: f64,
    /// Clear aperture: a disc of this diameter (mm) about the map centre; pixels outside it
    /// are invalid in both maps (a round part). `None`: the whole map is the part.
    pub aperture_diameter_mm: Option<f64>,
    pub effects: Vec<Injected>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            seed: 1,
            rows: 160,
            cols: 180,
            pixel_mm: 0.5,
            figure_rms_nm: 40.0,
            msf_rms_nm: 4.0,
            tif: TrueTif::default(),
            pitch_mm: 3.0,
            feed_min_mm_per_s: 2.0,
            feed_max_mm_per_s: 12.0,
            sample_hz: 10.0,
            deposit_step_mm: 0.1,
            spot_dwell_s: 20.0,
            spot_noise_nm: 0.3,
            spot_offset_mm: (0.0, 0.0),
            noise_nm: 0.3,
            dropout_fraction: 0.003,
            setup_tilt_nm: 15.0,
            setup_piston_nm: 7.0,
            aperture_diameter_mm: None,
            effects: Vec::new(),
        }
    }
}

impl SynthConfig {
    /// The reference large run of the calibration bench and the examples: an n x n map of a
    /// 100 mm part (pixel 100 / n mm, deposition every 0.2 mm), seed 5, with a rate drift of
    /// -20 % and a misregistration of (0.2, -0.15) mm and 0.05 deg.
    pub fn reference_large_run(n: usize) -> SynthConfig {
        SynthConfig {
            rows: n,
            cols: n,
            pixel_mm: 100.0 / n as f64,
            deposit_step_mm: 0.2,
            seed: 5,
            effects: vec![
                Injected::RateDrift {
                    fraction_per_run: -0.2,
                },
                Injected::Registration {
                    dx_mm: 0.2,
                    dy_mm: -0.15,
                    rotation_deg: 0.05,
                },
            ],
            ..SynthConfig::default()
        }
    }
}

/// A generated run.
#[derive(Debug, Clone)]
pub struct SynthRun {
    pub before: Surface,
    pub after: Surface,
    pub spot: Surface,
    pub spot_dwell_s: f64,
    pub path: PathLog,
    pub pitch_mm: f64,
    /// The removal actually deposited (nm, true frame, no noise) for checks.
    pub true_removal_nm: Array2<f64>,
}

/// Per-commanded-instant covariates the injected rate effects can depend on.
struct Covariates<'a> {
    surf: &'a SurfaceFn,
    plane: (f64, f64, f64),
    part: (f64, f64, f64, f64),
}

impl Covariates<'_> {
    fn value(&self, name: &str, t: f64, x: f64, y: f64, feed: f64) -> Result<f64, CalibrateError> {
        Ok(match name {
            "time" => t,
            "x" => x,
            "y" => y,
            "feed" => feed,
            "height" => {
                self.surf.value(x, y) - (self.plane.0 + self.plane.1 * x + self.plane.2 * y)
            }
            "slope" => {
                let (gx, gy) = self.surf.gradient(x, y);
                (gx - self.plane.1).hypot(gy - self.plane.2)
            }
            "edge_distance" => {
                let (x0, x1, y0, y1) = self.part;
                let inside = x >= x0 && x <= x1 && y >= y0 && y <= y1;
                if inside {
                    (x - x0).min(x1 - x).min(y - y0).min(y1 - y)
                } else {
                    let ddx = (x0 - x).max(0.0).max(x - x1);
                    let ddy = (y0 - y).max(0.0).max(y - y1);
                    -ddx.hypot(ddy)
                }
            }
            other => {
                return Err(CalibrateError::InvalidInput(format!(
                    "unknown covariate '{other}'"
                )))
            }
        })
    }
}

fn wave(w: Waveform, phase: f64) -> f64 {
    match w {
        Waveform::Sine => phase.sin(),
        Waveform::Triangle => {
            let p = (phase / (2.0 * std::f64::consts::PI)).rem_euclid(1.0);
            // triangle with sin's phase: 0 at 0, +1 at 1/4, -1 at 3/4
            if p < 0.25 {
                4.0 * p
            } else if p < 0.75 {
                2.0 - 4.0 * p
            } else {
                4.0 * p - 4.0
            }
        }
    }
}

/// Least-squares plane (piston, tilt) of the surface function over the grid.
fn plane_fit(f: &SurfaceFn, g: &MapGrid) -> (f64, f64, f64) {
    let (cx, cy) = g.centre_mm();
    let (mut sz, mut sxz, mut syz, mut sxx, mut syy, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..g.rows {
        for j in 0..g.cols {
            let (x, y) = (g.x_mm(j) - cx, g.y_mm(i) - cy);
            let z = f.value(g.x_mm(j), g.y_mm(i));
            sz += z;
            sxz += x * z;
            syz += y * z;
            sxx += x * x;
            syy += y * y;
            n += 1.0;
        }
    }
    let (a, b) = (sxz / sxx, syz / syy);
    (sz / n - a * cx - b * cy, a, b)
}

/// Catmull-Rom bicubic sample of a grid map at fractional pixel (fi, fj), clamped.
fn bicubic(a: &Array2<f64>, fi: f64, fj: f64) -> f64 {
    let (r, c) = a.dim();
    let (i0, j0) = (fi.floor() as isize, fj.floor() as isize);
    let (ti, tj) = (fi - i0 as f64, fj - j0 as f64);
    let w = |t: f64| -> [f64; 4] {
        [
            0.5 * (-t * t * t + 2.0 * t * t - t),
            0.5 * (3.0 * t * t * t - 5.0 * t * t + 2.0),
            0.5 * (-3.0 * t * t * t + 4.0 * t * t + t),
            0.5 * (t * t * t - t * t),
        ]
    };
    let (wi, wj) = (w(ti), w(tj));
    let mut s = 0.0;
    for (di, wa) in wi.iter().enumerate() {
        let ii = (i0 - 1 + di as isize).clamp(0, r as isize - 1) as usize;
        for (dj, wb) in wj.iter().enumerate() {
            let jj = (j0 - 1 + dj as isize).clamp(0, c as isize - 1) as usize;
            s += wa * wb * a[(ii, jj)];
        }
    }
    s
}

/// Generates a run.
pub fn generate(cfg: &SynthConfig) -> Result<SynthRun, CalibrateError> {
    if cfg.rows < 16 || cfg.cols < 16 || cfg.pixel_mm <= 0.0 || cfg.pitch_mm <= 0.0 {
        return Err(CalibrateError::InvalidInput(
            "synthetic run: grid or pitch too small".into(),
        ));
    }
    let mut rng = Rng::new(cfg.seed);
    let d = cfg.pixel_mm;
    let grid = MapGrid {
        rows: cfg.rows,
        cols: cfg.cols,
        dx_mm: d,
        dy_mm: d,
        x0_mm: 0.0,
        y0_mm: 0.0,
    };
    let (wx, wy) = ((cfg.cols - 1) as f64 * d, (cfg.rows - 1) as f64 * d);
    let surf = SurfaceFn::random(
        &mut rng,
        wx.max(wy),
        cfg.figure_rms_nm,
        cfg.msf_rms_nm,
        (0.04, 0.2),
    );
    let plane = plane_fit(&surf, &grid);
    let cov = Covariates {
        surf: &surf,
        plane,
        part: (-0.5 * d, wx + 0.5 * d, -0.5 * d, wy + 0.5 * d),
    };

    // Feed from a dwell map: more dwell (slower) where the figure is high.
    let fig_rms = cfg.figure_rms_nm.max(1e-9);
    let (vmin, vmax) = (cfg.feed_min_mm_per_s, cfg.feed_max_mm_per_s);
    let feed_at = |x: f64, y: f64| -> f64 {
        let h = (surf.value(x, y) / (2.5 * fig_rms)).clamp(-1.0, 1.0); // -1..1
        let dwell_per_area = (1.0 / (vmax * cfg.pitch_mm)) * (1.0 - (h + 1.0) / 2.0)
            + (1.0 / (vmin * cfg.pitch_mm)) * ((h + 1.0) / 2.0);
        1.0 / (dwell_per_area * cfg.pitch_mm)
    };
    let over = cfg.tif.radius_mm * 0.8;
    let plan = RasterPlan {
        x_min_mm: -over,
        x_max_mm: wx + over,
        y_min_mm: -over,
        y_max_mm: wy + over,
        pitch_mm: cfg.pitch_mm,
        sample_hz: cfg.sample_hz,
    };
    let path = raster(&plan, feed_at);

    // Executed instants.
    let (t0, t1) = (path.t_s[0], *path.t_s.last().unwrap_or(&1.0));
    let mut steps = Vec::new();
    let mut arc = 0.0;
    let mut scale = 1.0;
    for e in &cfg.effects {
        if let Injected::TifScale { scale: s } = e {
            scale *= s;
        }
    }
    for k in 0..path.len() - 1 {
        let (xa, ya, xb, yb) = (
            path.x_mm[k],
            path.y_mm[k],
            path.x_mm[k + 1],
            path.y_mm[k + 1],
        );
        let len = (xb - xa).hypot(yb - ya);
        let dt_seg = path.t_s[k + 1] - path.t_s[k];
        let n = ((len / cfg.deposit_step_mm).ceil() as usize).max(1);
        let (ux, uy) = if len > 0.0 {
            ((xb - xa) / len, (yb - ya) / len)
        } else {
            (0.0, 0.0)
        };
        let feed = len / dt_seg;
        for m in 0..n {
            let f = (m as f64 + 0.5) / n as f64;
            let t = path.t_s[k] + f * dt_seg;
            let (xc, yc) = (xa + f * (xb - xa), ya + f * (yb - ya));
            let s_arc = arc + f * len;
            let tau = (t - t0) / (t1 - t0);
            let (mut x, mut y, mut rate) = (xc, yc, 1.0);
            for e in &cfg.effects {
                match e {
                    Injected::RateDrift { fraction_per_run } => {
                        rate *= 1.0 + fraction_per_run * tau
                    }
                    Injected::DirectionLag { lag_mm } => {
                        x -= lag_mm * ux;
                        y -= lag_mm * uy;
                    }
                    Injected::PeriodicPathError {
                        axis_x,
                        amplitude_mm,
                        period_mm,
                        phase_rad,
                        coord,
                        waveform,
                    } => {
                        let q = match coord {
                            WiggleCoord::X => xc,
                            WiggleCoord::Y => yc,
                            WiggleCoord::Arc => s_arc,
                        };
                        let e = amplitude_mm
                            * wave(
                                *waveform,
                                2.0 * std::f64::consts::PI * q / period_mm + phase_rad,
                            );
                        if *axis_x {
                            x += e;
                        } else {
                            y += e;
                        }
                    }
                    Injected::RateCovariate {
                        covariate,
                        coefficient,
                    } => rate *= 1.0 + coefficient * cov.value(covariate, t - t0, xc, yc, feed)?,
                    Injected::RateOscillation {
                        amplitude_fraction,
                        period_s,
                    } => {
                        rate *= 1.0
                            + amplitude_fraction
                                * (2.0 * std::f64::consts::PI * (t - t0) / period_s).sin()
                    }
                    Injected::RateStep { at_tau, fraction } if tau >= *at_tau => {
                        rate *= 1.0 + fraction
                    }
                    Injected::PathOffset { dx_mm, dy_mm } => {
                        x += dx_mm;
                        y += dy_mm;
                    }
                    _ => {}
                }
            }
            steps.push(Instant {
                x_mm: x,
                y_mm: y,
                dt_s: dt_seg / n as f64,
                rate_factor: rate,
                scale,
            });
        }
        arc += len;
    }
    let removal = deposit::deposit(&grid, &cfg.tif, &steps);

    // Before map: truth + its own noise and dropouts.
    let mut before = Array2::from_shape_fn((cfg.rows, cfg.cols), |(i, j)| {
        surf.value(grid.x_mm(j), grid.y_mm(i))
    });
    // After map: truth at the misregistered positions.
    let (cx, cy) = grid.centre_mm();
    let (mut rdx, mut rdy, mut rth) = (0.0, 0.0, 0.0);
    for e in &cfg.effects {
        if let Injected::Registration {
            dx_mm,
            dy_mm,
            rotation_deg,
        } = e
        {
            rdx += dx_mm;
            rdy += dy_mm;
            rth += rotation_deg.to_radians();
        }
    }
    let mut after = Array2::from_shape_fn((cfg.rows, cfg.cols), |(i, j)| {
        // after-map pixel q shows the true point p = R(-theta) (q - c - d) + c
        let (qx, qy) = (grid.x_mm(j) - cx - rdx, grid.y_mm(i) - cy - rdy);
        let (c, s) = (rth.cos(), rth.sin());
        let (px, py) = (c * qx + s * qy + cx, -s * qx + c * qy + cy);
        let mut h = surf.value(px, py) - bicubic(&removal, py / d, px / d);
        for e in &cfg.effects {
            if let Injected::LocalDefect {
                x_mm,
                y_mm,
                radius_mm,
                depth_nm,
            } = e
            {
                let r2 = (px - x_mm).powi(2) + (py - y_mm).powi(2);
                h -= depth_nm * (-0.5 * r2 / (radius_mm * radius_mm)).exp();
            }
        }
        h
    });
    let mut vb = Array2::from_elem((cfg.rows, cfg.cols), true);
    let mut va = Array2::from_elem((cfg.rows, cfg.cols), true);
    for (map, valid, setup) in [(&mut before, &mut vb, false), (&mut after, &mut va, true)] {
        let (tx, ty) = if setup {
            (
                cfg.setup_tilt_nm * (rng.uniform() - 0.5) * 2.0,
                cfg.setup_tilt_nm * (rng.uniform() - 0.5) * 2.0,
            )
        } else {
            (0.0, 0.0)
        };
        let piston = if setup { cfg.setup_piston_nm } else { 0.0 };
        for ((i, j), h) in map.indexed_iter_mut() {
            *h += piston
                + tx * (grid.x_mm(j) / wx - 0.5)
                + ty * (grid.y_mm(i) / wy - 0.5)
                + cfg.noise_nm * rng.normal();
        }
        // Dropouts: isolated pixels plus a few small clusters.
        let n_drop = (cfg.dropout_fraction * (cfg.rows * cfg.cols) as f64) as usize;
        for _ in 0..n_drop {
            valid[(rng.below(cfg.rows), rng.below(cfg.cols))] = false;
        }
        for _ in 0..3.min(n_drop) {
            let (ci, cj) = (rng.below(cfg.rows), rng.below(cfg.cols));
            for i in ci.saturating_sub(2)..(ci + 3).min(cfg.rows) {
                for j in cj.saturating_sub(2)..(cj + 3).min(cfg.cols) {
                    valid[(i, j)] = false;
                }
            }
        }
    }
    if let Some(dia) = cfg.aperture_diameter_mm {
        let r2 = 0.25 * dia * dia;
        for v in [&mut vb, &mut va] {
            for ((i, j), ok) in v.indexed_iter_mut() {
                if (grid.x_mm(j) - cx).powi(2) + (grid.y_mm(i) - cy).powi(2) > r2 {
                    *ok = false;
                }
            }
        }
    }
    let mk = |h: Array2<f64>, v: Array2<bool>, name: &str| -> Result<Surface, CalibrateError> {
        let mut s = Surface::with_mask(h, v, Some(d), Some(d))?;
        s.provenance.format = "synthetic".into();
        s.provenance.comment = Some(name.into());
        Ok(s)
    };

    // Measured spot: odd-sized map of the (unscaled) true TIF dwelled at its centre.
    let off = cfg.spot_offset_mm.0.abs().max(cfg.spot_offset_mm.1.abs());
    let half = ((cfg.tif.radius_mm * 1.25 + off) / d).ceil() as usize;
    let n = 2 * half + 1;
    let spot_h = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = ((j as f64 - half as f64) * d, (i as f64 - half as f64) * d);
        let (ox, oy) = cfg.spot_offset_mm;
        3.0 - cfg.spot_dwell_s * cfg.tif.rate(x - ox, y - oy, 1.0)
            + cfg.spot_noise_nm * rng.normal()
    });
    let mut spot = Surface::new(spot_h, Some(d), Some(d))?;
    spot.provenance.format = "synthetic".into();
    spot.origin_mm = (-(half as f64) * d, -(half as f64) * d);

    Ok(SynthRun {
        before: mk(before, vb, "before")?,
        after: mk(after, va, "after")?,
        spot,
        spot_dwell_s: cfg.spot_dwell_s,
        path,
        pitch_mm: cfg.pitch_mm,
        true_removal_nm: removal,
    })
}

use raster::raster;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_wave_has_sine_phase_and_unit_amplitude() {
        let q = std::f64::consts::FRAC_PI_2;
        assert!((wave(Waveform::Triangle, q) - 1.0).abs() < 1e-12);
        assert!((wave(Waveform::Triangle, 3.0 * q) + 1.0).abs() < 1e-12);
        assert!(wave(Waveform::Triangle, 0.0).abs() < 1e-12);
    }
}
