//! Exact time-domain deposition with a per-instant modulation hook: at every sub-step of the
//! path the caller may displace the tool from the logged position, scale the removal rate and
//! widen the footprint. This is the project's one exact deposition:
//! [`crate::removal::deposit_exact`] calls it with the per-sample weights as the rate factor,
//! and it serves processes whose rate, spot shape or executed position vary in time or along
//! the path in ways a per-sample weight cannot express (a spot that grows, a rate that depends
//! on the travel direction or on where the tool is, a lag or a wiggle of the executed
//! position). The synthetic-run generator uses it as its independent truth, and the vibration
//! coupling as its direct reference (the instantaneous TIF under the robot's vibration,
//! `bonnetlab_vibration::coupling::direct`), also the deposition of the bundled recipe runs;
//! it never uses the FFT model.
//!
//! Footprint widening by `scale` s: the rate at offset r is `T(r / s)` (peak unchanged, volume
//! times s^2), with the footprint's half-extent times s.

use ndarray::Array2;
use rayon::prelude::*;

use crate::error::ProcessError;
use crate::grid::Grid;
use crate::path::PathLog;
use crate::removal::{check_exact_budget, deposit_one, exact_step, ExactOptions};
use crate::tif::RateField;

/// One sub-step of the logged path, as the modulation hook sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubStep {
    /// Time at the sub-step's midpoint (s, the log's clock).
    pub t_s: f64,
    /// Logged tool-centre position at the midpoint (mm).
    pub x_mm: f64,
    pub y_mm: f64,
    /// Velocity of the segment it lies on (mm/s).
    pub vx_mm_per_s: f64,
    pub vy_mm_per_s: f64,
    /// Index of that segment (samples `segment` and `segment + 1`).
    pub segment: usize,
    /// Where the midpoint lies on that segment (0 at sample `segment`, 1 at the next).
    pub fraction: f64,
    /// Duration of the sub-step (s).
    pub dt_s: f64,
}

/// What the process did at one sub-step, relative to the log and the nominal footprint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Modulation {
    /// Executed position minus logged position (mm).
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// Rate factor (1 = nominal).
    pub rate: f64,
    /// Footprint widening (1 = nominal; must be positive).
    pub scale: f64,
}

impl Default for Modulation {
    fn default() -> Self {
        Modulation {
            dx_mm: 0.0,
            dy_mm: 0.0,
            rate: 1.0,
            scale: 1.0,
        }
    }
}

impl Modulation {
    /// Both modulations at once: displacements add, rate factors and widenings multiply
    /// (`T(r / s)` of a field already widened by `s'` is the field widened by `s s'`).
    pub fn and(self, o: Modulation) -> Modulation {
        Modulation {
            dx_mm: self.dx_mm + o.dx_mm,
            dy_mm: self.dy_mm + o.dy_mm,
            rate: self.rate * o.rate,
            scale: self.scale * o.scale,
        }
    }
}

/// A rate field widened by `s`: `T(r / s)`.
struct Widened<'a> {
    inner: &'a dyn RateField,
    s: f64,
}

impl RateField for Widened<'_> {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.inner.rate_at_mm(dx_mm / self.s, dy_mm / self.s)
    }
    fn half_extent_mm(&self) -> (f64, f64) {
        let (ex, ey) = self.inner.half_extent_mm();
        (ex * self.s, ey * self.s)
    }
}

/// Sub-steps deposited per block (32 MB of steps), so memory stays bounded whatever the
/// path's length.
const BLOCK: usize = 1 << 20;

/// Exact deposition (nm on `grid`) of `field` along `path`, modulated at every sub-step by
/// `modulate`. Sub-steps of [`exact_step`] (midpoint rule; default length a quarter pixel and
/// at most 1/80 of the nominal footprint's smaller half-extent; at most `opts.max_dt_s` in
/// time). The hook is called once per sub-step, in time order, so it may follow a time series
/// (the vibration coupling's instantaneous TIF: a lateral displacement, and an offset change
/// as a rate factor and a widening).
pub fn deposit_exact_modulated(
    path: &PathLog,
    field: &dyn RateField,
    grid: &Grid,
    opts: &ExactOptions,
    mut modulate: impl FnMut(&SubStep) -> Modulation,
) -> Result<Array2<f64>, ProcessError> {
    let (ex, ey) = field.half_extent_mm();
    let step = exact_step(field, grid, opts)?;
    check_exact_budget(path, grid, step, opts, (ex, ey))?;
    let g = *grid;
    let zero = || Array2::<f64>::zeros((g.rows, g.cols));
    // (x, y, rate * dt, scale), deposited in parallel block by block.
    let flush = |steps: &[[f64; 4]], out: &mut Array2<f64>| {
        let chunk = (steps.len() / (4 * rayon::current_num_threads()).max(1)).max(256);
        let part = steps
            .par_chunks(chunk)
            .map(|c| {
                let mut acc = zero();
                for &[x, y, w, s] in c {
                    if s == 1.0 {
                        // Nominal footprint: no rescaling of every pixel's offset.
                        let rate = |dx, dy| field.rate_at_mm(dx, dy);
                        deposit_one(&mut acc, &g, rate, x, y, w, ex, ey);
                    } else {
                        let wf = Widened { inner: field, s };
                        let rate = |dx, dy| wf.rate_at_mm(dx, dy);
                        deposit_one(&mut acc, &g, rate, x, y, w, ex * s, ey * s);
                    }
                }
                acc
            })
            .reduce(zero, |a, b| a + b);
        *out += &part;
    };
    let mut out = zero();
    let mut steps: Vec<[f64; 4]> = Vec::new();
    let mut bad: Option<String> = None;
    path.for_each_substep(step, opts.max_dt_s, |x, y, dt, k, fr| {
        if bad.is_some() {
            return;
        }
        let seg_dt = path.t_s[k + 1] - path.t_s[k];
        let s = SubStep {
            t_s: path.t_s[k] + fr * seg_dt,
            x_mm: x,
            y_mm: y,
            vx_mm_per_s: (path.x_mm[k + 1] - path.x_mm[k]) / seg_dt,
            vy_mm_per_s: (path.y_mm[k + 1] - path.y_mm[k]) / seg_dt,
            segment: k,
            fraction: fr,
            dt_s: dt,
        };
        let m = modulate(&s);
        if !(m.scale > 0.0
            && m.scale.is_finite()
            && m.rate.is_finite()
            && m.dx_mm.is_finite()
            && m.dy_mm.is_finite())
        {
            bad = Some(format!("modulation at t = {} s is not valid: {m:?}", s.t_s));
            return;
        }
        let (px, py) = (x + m.dx_mm, y + m.dy_mm);
        let (rx, ry) = (ex * m.scale, ey * m.scale);
        let inside = px >= grid.x0_mm - rx
            && px <= grid.x_mm(grid.cols - 1) + rx
            && py >= grid.y0_mm - ry
            && py <= grid.y_mm(grid.rows - 1) + ry;
        if inside && m.rate != 0.0 {
            steps.push([px, py, dt * m.rate, m.scale]);
            if steps.len() == BLOCK {
                flush(&steps, &mut out);
                steps.clear();
            }
        }
    });
    if let Some(b) = bad {
        return Err(ProcessError::invalid(b));
    }
    if !steps.is_empty() {
        flush(&steps, &mut out);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::removal::deposit_exact;
    use crate::tif::GaussianTif;

    #[test]
    fn unit_modulation_is_deposit_exact_and_hooks_act() {
        let grid = Grid::new(40, 60, 0.5, 0.5, 0.0, 0.0).unwrap();
        let g = GaussianTif::new(1.5, 9.0, 5.0).unwrap();
        let p = PathLog::new(
            vec![0.0, 4.0, 5.0, 9.0],
            vec![8.0, 22.0, 22.0, 8.0],
            vec![8.0, 8.0, 11.0, 11.0],
        )
        .unwrap();
        let o = ExactOptions::default();
        let a = deposit_exact(&p, &g, &grid, None, &o).unwrap();
        // Independent truth: at pixels more than the footprint's radius (4.5 mm) from the step
        // over at x = 22, the removal is the two horizontal lines' line integrals of the TIF at
        // 3.5 mm/s, by Simpson's rule on a fine grid (not the module's sub-steps).
        let line = |x: f64, y: f64, y_line: f64| {
            let d2 = (y - y_line) * (y - y_line);
            if d2 >= 4.5 * 4.5 {
                return 0.0;
            }
            let half = (4.5 * 4.5 - d2).sqrt();
            let (lo, hi) = ((8.0 - x).max(-half), (22.0 - x).min(half));
            let n = 20_000;
            let h = (hi - lo) / n as f64;
            let f = |s: f64| 5.0 * (-(d2 + s * s) / (2.0 * 1.5 * 1.5)).exp();
            let mut sum = f(lo) + f(hi);
            for k in 1..n {
                sum += f(lo + k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
            }
            sum * h / 3.0 / 3.5
        };
        for (x, y) in [(15.0, 8.0), (15.0, 9.5), (12.0, 12.0), (10.0, 5.0)] {
            let (i, j) = ((y / 0.5) as usize, (x / 0.5) as usize);
            let want = line(x, y, 8.0) + line(x, y, 11.0);
            assert!(
                (a[[i, j]] - want).abs() < 1e-3 * want,
                "({x}, {y}): {} vs {want}",
                a[[i, j]]
            );
        }
        // Rate 2 doubles; a widening by s multiplies the volume by s^2 (footprint inside).
        let c = deposit_exact_modulated(&p, &g, &grid, &o, |_| Modulation {
            rate: 2.0,
            scale: 1.2,
            ..Modulation::default()
        })
        .unwrap();
        let (va, vc) = (a.sum(), c.sum());
        assert!((vc / va - 2.0 * 1.44).abs() < 2e-3, "{}", vc / va);
        // A displacement moves the removal: the centroid shifts by it.
        let d = deposit_exact_modulated(&p, &g, &grid, &o, |_| Modulation {
            dx_mm: 1.0,
            dy_mm: -0.5,
            ..Modulation::default()
        })
        .unwrap();
        let cen = |m: &Array2<f64>| {
            let (mut sx, mut sy) = (0.0, 0.0);
            for ((i, j), v) in m.indexed_iter() {
                sx += v * grid.x_mm(j);
                sy += v * grid.y_mm(i);
            }
            (sx / m.sum(), sy / m.sum())
        };
        let (c0, c1) = (cen(&a), cen(&d));
        assert!((c1.0 - c0.0 - 1.0).abs() < 1e-3 && (c1.1 - c0.1 + 0.5).abs() < 1e-3);
        // Invalid modulation is an error, not a panic.
        assert!(deposit_exact_modulated(&p, &g, &grid, &o, |_| Modulation {
            scale: 0.0,
            ..Modulation::default()
        })
        .is_err());
    }
}
