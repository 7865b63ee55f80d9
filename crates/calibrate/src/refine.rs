//! Joint refinement of the accepted effects' non-linear parameters by variable projection:
//! the linear coefficients (rate scale, rate effects, piston, tilt) are re-solved exactly for
//! every trial of the non-linear ones, and Levenberg-Marquardt steps (the project's one driver,
//! `bonnetlab_surface::lm`) use forward-difference Jacobians of that profiled residual (each
//! column one model evaluation; the registration's columns are analytic).

use bonnetlab_surface::lm::{self, LmProblem, LmSettings};

use rayon::prelude::*;

use crate::error::CalibrateError;
use crate::model::{evaluate, fit, Effect, Eval, Fit, Problem};

fn nl_vec(effects: &[Box<dyn Effect>]) -> (Vec<f64>, Vec<f64>) {
    let mut v = Vec::new();
    let mut s = Vec::new();
    for e in effects {
        v.extend(e.nl());
        s.extend(e.nl_steps());
    }
    (v, s)
}

pub fn set_nl(effects: &mut [Box<dyn Effect>], v: &[f64]) {
    let mut k = 0;
    for e in effects.iter_mut() {
        let n = e.nl().len();
        if n > 0 {
            e.set_nl(&v[k..k + n]);
            k += n;
        }
    }
}

/// Steps of the non-linear parameters' differences for the uncertainties (see
/// `Effect::nl_sigma_steps`), in [`jacobian`]'s order.
pub fn sigma_steps(effects: &[Box<dyn Effect>]) -> Vec<f64> {
    effects.iter().flat_map(|e| e.nl_sigma_steps()).collect()
}

/// Forward-difference Jacobian columns of the profiled residual (or, not `profiled`, of the
/// residual at the same linear coefficients), with steps `steps` (the refinement's
/// `nl_steps`, or [`sigma_steps`] for the uncertainties).
pub fn jacobian(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev0: &Eval,
    f0: &Fit,
    profiled: bool,
    steps: &[f64],
) -> Result<Vec<Vec<f64>>, CalibrateError> {
    let (theta, _) = nl_vec(effects);
    // Registration parameters: analytic columns from the smoothed after map (see
    // `effects::registration`), profiled by projecting out the linear columns.
    let mut analytic: Vec<Option<Vec<f64>>> = vec![None; theta.len()];
    let mut k = 0;
    for e in effects {
        let n = e.nl().len();
        if e.registration().is_some() && n == 3 {
            for (o, c) in crate::effects::registration::jacobian(p, ev0)
                .into_iter()
                .enumerate()
            {
                analytic[k + o] = Some(if profiled { project_out(ev0, &c)? } else { c });
            }
        }
        k += n;
    }
    // The numeric columns side by side (each its own evaluation), kept in parameter order.
    let numeric: Vec<Result<Option<Vec<f64>>, CalibrateError>> = (0..theta.len())
        .into_par_iter()
        .map(|i| {
            if analytic[i].is_some() {
                return Ok(None);
            }
            numeric_column(p, effects, ev0, f0, profiled, &theta, steps, i).map(Some)
        })
        .collect();
    let mut cols = Vec::with_capacity(theta.len());
    for (a, n) in analytic.into_iter().zip(numeric) {
        let c = a.or(n?).ok_or_else(|| {
            CalibrateError::Processing("a Jacobian column was neither analytic nor numeric".into())
        })?;
        cols.push(c);
    }
    Ok(cols)
}

/// Column `i` of the Jacobian by a forward difference of the residual.
#[allow(clippy::too_many_arguments)]
fn numeric_column(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev0: &Eval,
    f0: &Fit,
    profiled: bool,
    theta: &[f64],
    steps: &[f64],
    i: usize,
) -> Result<Vec<f64>, CalibrateError> {
    let mut t = theta.to_vec();
    t[i] += steps[i];
    let mut trial: Vec<Box<dyn Effect>> = effects.to_vec();
    set_nl(&mut trial, &t);
    let ev = evaluate(p, &trial, Some(ev0))?;
    let r = if profiled {
        fit(&ev, &[])?.resid
    } else {
        // Residual at the same linear coefficients.
        let mut r = ev.m.clone();
        for (k, ri) in r.iter_mut().enumerate() {
            if ev.w[k] == 0.0 {
                *ri = 0.0;
                continue;
            }
            for (c, col) in f0.coef.iter().zip(&ev.cols) {
                *ri -= c * col[k];
            }
        }
        r
    };
    // Pixels whose validity changes with the step carry no derivative information.
    Ok(r.iter()
        .zip(&f0.resid)
        .zip(ev.w.iter().zip(&ev0.w))
        .map(|((a, b), (w1, w0))| if w1 == w0 { (a - b) / steps[i] } else { 0.0 })
        .collect())
}

/// `c` minus its weighted least-squares fit by the evaluation's linear columns.
fn project_out(ev: &Eval, c: &[f64]) -> Result<Vec<f64>, CalibrateError> {
    let cols: Vec<&[f64]> = ev.cols.iter().map(|v| v.as_slice()).collect();
    let (g, r) = crate::lsq::gram(&cols, c, &ev.w, None);
    let coef = crate::lsq::solve(&g, &r)
        .ok_or_else(|| CalibrateError::Processing("singular projection".into()))?;
    let mut out = c.to_vec();
    for (a, col) in coef.iter().zip(&cols) {
        for ((o, v), w) in out.iter_mut().zip(col.iter()).zip(&ev.w) {
            if *w != 0.0 {
                *o -= a * v;
            }
        }
    }
    Ok(out)
}

/// The refinement as the project's one Levenberg-Marquardt driver (`bonnetlab_surface::lm`)
/// sees it: the effects' non-linear parameters, the profiled residual of the joint linear fit,
/// and its mean square as the cost (the valid aperture may change slightly with registration,
/// so sums of squares over different pixel counts are not comparable).
struct Refinement<'a> {
    p: &'a Problem,
    /// The effects at the point the driver stands on.
    effects: Vec<Box<dyn Effect>>,
}

impl Refinement<'_> {
    /// The effects at `x`, and `x` as they hold it (an effect may normalise its parameters).
    fn at(&self, x: &[f64]) -> (Vec<Box<dyn Effect>>, Vec<f64>) {
        let mut e = self.effects.to_vec();
        set_nl(&mut e, x);
        let held = e.iter().flat_map(|e| e.nl()).collect();
        (e, held)
    }
}

impl LmProblem for Refinement<'_> {
    type State = (Eval, Fit);
    type Error = CalibrateError;

    fn residual<'s>(&self, s: &'s (Eval, Fit)) -> &'s [f64] {
        &s.1.resid
    }

    fn cost(&self, s: &(Eval, Fit)) -> f64 {
        s.1.rss / s.1.n.max(1.0)
    }

    fn jacobian(&mut self, x: &[f64], s: &(Eval, Fit)) -> Result<Vec<Vec<f64>>, CalibrateError> {
        self.effects = self.at(x).0;
        let steps = nl_vec(&self.effects).1;
        jacobian(self.p, &self.effects, &s.0, &s.1, true, &steps)
    }

    fn propose(&self, x: &[f64], step: &[f64]) -> Vec<f64> {
        let t: Vec<f64> = x.iter().zip(step).map(|(a, d)| a + d).collect();
        self.at(&t).1
    }

    fn evaluate(
        &mut self,
        x: &[f64],
        current: &(Eval, Fit),
    ) -> Result<Option<(Eval, Fit)>, CalibrateError> {
        let (trial, _) = self.at(x);
        let ev = evaluate(self.p, &trial, Some(&current.0))?;
        let f = fit(&ev, &[])?;
        Ok(Some((ev, f)))
    }
}

/// Refines the non-linear parameters in place; returns the final evaluation and fit.
pub fn refine(
    p: &Problem,
    effects: &mut [Box<dyn Effect>],
    iters: usize,
) -> Result<(Eval, Fit), CalibrateError> {
    let ev = evaluate(p, effects, None)?;
    let f = fit(&ev, &[])?;
    let (theta, _) = nl_vec(effects);
    if theta.is_empty() || iters == 0 {
        return Ok((ev, f));
    }
    let settings = LmSettings {
        max_iter: iters,
        max_tries: 6,
        lambda0: 1e-3,
        increase: 8.0,
        decrease: 4.0,
        lambda_min: 1e-7,
        rel_tol: 1e-6,
        step_tol: 0.0,
        // At the minimum of a noisy profiled residual (forward-difference columns of a
        // discretised model) the next step is predicted to gain less than this; trying it
        // anyway cost up to `max_tries` full evaluations, each rejected at a higher damping.
        pred_tol: 1e-6,
        diag_floor: 1e-300,
    };
    let mut problem = Refinement {
        p,
        effects: effects.to_vec(),
    };
    let out = lm::minimize(&mut problem, theta, (ev, f), &settings)?;
    set_nl(effects, &out.x);
    let mut state = out.state;
    let scans: Vec<f64> = effects.iter().flat_map(|e| e.nl_scan(p)).collect();
    for (k, &d) in scans.iter().enumerate() {
        if d > 0.0 {
            if let Some(better) = scan_profile(p, effects, k, d, &state)? {
                state = better;
            }
        }
    }
    Ok(state)
}

/// Points of [`scan_profile`]'s coarse scan on each side of the start.
const SCAN_POINTS: usize = 8;
/// Golden-section search of [`scan_profile`] down to this share of the scan step.
const SCAN_TOL: f64 = 1.0 / 64.0;

/// Non-linear parameter `k` of `effects` moved to the least profiled mean square near it, the
/// others held: a coarse scan at `d` steps outwards, up to `SCAN_POINTS` on each side, until
/// the best point is bracketed, then a golden-section search over one step either side of
/// it to `d * SCAN_TOL`.
/// `effects` is updated and the new state returned only when the cost fell below `current`'s.
/// For parameters (see `Effect::nl_scan`) whose profile is V-shaped beyond a short span: there
/// the forward-difference Gauss-Newton steps of the refinement move a few 1e-5 of the run per
/// iteration (issue 15's harness: a step time left 0.003 of the run from the profile's
/// minimum, 17 of its sigmas, the process band 1.23x the floor).
fn scan_profile(
    p: &Problem,
    effects: &mut [Box<dyn Effect>],
    k: usize,
    d: f64,
    current: &(Eval, Fit),
) -> Result<Option<(Eval, Fit)>, CalibrateError> {
    let cost = |f: &Fit| f.rss / f.n.max(1.0);
    let x0: Vec<f64> = effects.iter().flat_map(|e| e.nl()).collect();
    let trial_at = |t: f64| {
        let mut x = x0.clone();
        x[k] = t;
        let mut trial = effects.to_vec();
        set_nl(&mut trial, &x);
        trial
    };
    let cost_at = |t: f64| -> Result<f64, CalibrateError> {
        let ev = evaluate(p, &trial_at(t), Some(&current.0))?;
        Ok(cost(&fit(&ev, &[])?))
    };
    let start = cost(&current.1);
    let (mut best_t, mut best_c) = (x0[k], start);
    // Outwards a pair at a time (the two side by side) until the best point has a higher one
    // beyond it on both sides: two evaluations where the refinement ended at the minimum.
    for i in 1..=SCAN_POINTS {
        let pair = [x0[k] - i as f64 * d, x0[k] + i as f64 * d];
        let (a, b) = rayon::join(|| cost_at(pair[0]), || cost_at(pair[1]));
        for (t, c) in pair.into_iter().zip([a?, b?]) {
            if c < best_c {
                (best_t, best_c) = (t, c);
            }
        }
        if (best_t - x0[k]).abs() < (i as f64 - 0.5) * d {
            break;
        }
    }
    // Golden section over [best - d, best + d] (a bracket when the scan's best is inside it).
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut b) = (best_t - d, best_t + d);
    let (mut u, mut v) = (b - g * (b - a), a + g * (b - a));
    let (mut cu, mut cv) = (cost_at(u)?, cost_at(v)?);
    while b - a > d * SCAN_TOL {
        if cu < cv {
            (b, v, cv) = (v, u, cu);
            u = b - g * (b - a);
            cu = cost_at(u)?;
        } else {
            (a, u, cu) = (u, v, cv);
            v = a + g * (b - a);
            cv = cost_at(v)?;
        }
        for (t, c) in [(u, cu), (v, cv)] {
            if c < best_c {
                (best_t, best_c) = (t, c);
            }
        }
    }
    if best_c >= start {
        return Ok(None);
    }
    let trial = trial_at(best_t);
    let ev = evaluate(p, &trial, Some(&current.0))?;
    let f = fit(&ev, &[])?;
    for (e, t) in effects.iter_mut().zip(trial) {
        *e = t;
    }
    Ok(Some((ev, f)))
}
