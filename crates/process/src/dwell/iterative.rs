//! Iterative non-negative dwell solver: accelerated projected gradient (FISTA) on
//!
//!   min_T  1/2 || P (Z - B * T) ||^2 + lambda sum(T)   subject to T >= 0,
//!
//! where P keeps the clear aperture and removes piston and tilt there, and B * T is an FFT
//! convolution. The step is 1 / max|B(f)|^2 (the Lipschitz constant, since ||P|| <= 1). The
//! dwell penalty lambda (nm^2 per s of dwell) is the trade-off knob: 0 gives the smallest
//! residual; larger values buy total dwell with residual. Starting point: a uniform dwell that
//! removes the mean desired removal (or a given map, e.g. the RIFTA solution).

use ndarray::Array2;

use super::{finish, DwellProblem, DwellSolution, PistonTilt, TradeOffPoint};
use crate::error::ProcessError;

/// Options of [`solve_iterative`].
#[derive(Debug, Clone, PartialEq)]
pub struct IterativeOptions {
    pub iterations: usize,
    /// Dwell penalty lambda (nm^2 / s).
    pub dwell_penalty: f64,
    /// Starting dwell map (on the dwell grid); `None`: uniform.
    pub start: Option<Array2<f64>>,
    /// Stop when the CA residual RMS changes by less than this fraction over 10 iterations.
    pub rel_tol: f64,
}

impl Default for IterativeOptions {
    fn default() -> Self {
        IterativeOptions {
            iterations: 300,
            dwell_penalty: 0.0,
            start: None,
            rel_tol: 1e-4,
        }
    }
}

/// Solves the dwell problem by accelerated projected gradient.
pub fn solve_iterative(
    p: &DwellProblem,
    o: &IterativeOptions,
) -> Result<DwellSolution, ProcessError> {
    if !(o.dwell_penalty.is_finite() && o.dwell_penalty >= 0.0) {
        return Err(ProcessError::invalid("dwell_penalty must be >= 0"));
    }
    let mut conv = p.convolver();
    let proj = PistonTilt::new(&p.aperture);
    let lip = conv
        .kernel_spectrum()
        .iter()
        .fold(0.0f64, |m, k| m.max(k.norm_sqr()));
    if lip <= 0.0 {
        return Err(ProcessError::Processing("the TIF removes nothing".into()));
    }
    let step = 1.0 / lip;
    let mut t = match &o.start {
        Some(s) if s.dim() == p.dim() => s.mapv(|v| v.max(0.0)),
        Some(_) => {
            return Err(ProcessError::invalid(
                "start dwell does not match the dwell grid",
            ))
        }
        None => {
            let n = proj.count().max(1) as f64;
            let mean = p
                .desired_nm
                .iter()
                .zip(p.aperture.iter())
                .filter(|(_, &m)| m)
                .map(|(v, _)| *v)
                .sum::<f64>()
                / n;
            let vol = p.tif.rate_nm_per_s.sum();
            Array2::from_elem(p.dim(), (mean / vol).max(0.0))
        }
    };
    let mut y = t.clone();
    let mut tk = 1.0f64;
    let mut history: Vec<f64> = Vec::new();
    let mut iterations = 0;
    for it in 0..o.iterations {
        let res = proj.residual(&(&p.desired_nm - &conv.apply(y.view())));
        if it % 10 == 0 {
            let rms = proj.rms(&res);
            if let Some(&last) = history.last() {
                if (last - rms).abs() <= o.rel_tol * last {
                    break;
                }
            }
            history.push(rms);
        }
        let grad = conv.apply_adjoint(res.view());
        let shrink = o.dwell_penalty * step;
        let mut t_new = &y + &(grad * step);
        t_new.mapv_inplace(|v| (v - shrink).max(0.0));
        let tk1 = 0.5 * (1.0 + (1.0 + 4.0 * tk * tk).sqrt());
        let mom = (tk - 1.0) / tk1;
        y = &t_new + &((&t_new - &t) * mom);
        y.mapv_inplace(|v| v.max(0.0));
        t = t_new;
        tk = tk1;
        iterations = it + 1;
    }
    let sol = finish(p, &proj, &mut conv, t, "iterative", iterations, Vec::new());
    let point = TradeOffPoint {
        parameter: o.dwell_penalty,
        residual_rms_nm: sol.residual_rms_nm,
        total_dwell_s: sol.total_dwell_s,
    };
    Ok(DwellSolution {
        trade_off: vec![point],
        ..sol
    })
}

/// Residual vs total dwell for several dwell penalties (each a full solve).
pub fn trade_off_curve(
    p: &DwellProblem,
    penalties: &[f64],
    base: &IterativeOptions,
) -> Result<Vec<TradeOffPoint>, ProcessError> {
    penalties
        .iter()
        .map(|&l| {
            let o = IterativeOptions {
                dwell_penalty: l,
                ..base.clone()
            };
            solve_iterative(p, &o).map(|s| s.trade_off[0])
        })
        .collect()
}
