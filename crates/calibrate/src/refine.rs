//! Joint refinement of the accepted effects' non-linear parameters by variable projection:
//! the linear coefficients (rate scale, rate effects, piston, tilt) are re-solved exactly for
//! every trial of the non-linear ones, and Levenberg-Marquardt steps use forward-difference
//! Jacobians of that profiled residual (each column one model evaluation).

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

/// Forward-difference Jacobian columns of the profiled residual, and the evaluations' residuals.
pub fn jacobian(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev0: &Eval,
    f0: &Fit,
    profiled: bool,
) -> Result<Vec<Vec<f64>>, CalibrateError> {
    let (theta, steps) = nl_vec(effects);
    let mut cols = Vec::with_capacity(theta.len());
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
    for i in 0..theta.len() {
        if let Some(c) = analytic[i].take() {
            cols.push(c);
            continue;
        }
        let mut t = theta.clone();
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
        cols.push(
            // Pixels whose validity changes with the step carry no derivative information.
            r.iter()
                .zip(&f0.resid)
                .zip(ev.w.iter().zip(&ev0.w))
                .map(|((a, b), (w1, w0))| if w1 == w0 { (a - b) / steps[i] } else { 0.0 })
                .collect(),
        );
    }
    Ok(cols)
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

/// Refines the non-linear parameters in place; returns the final evaluation and fit.
pub fn refine(
    p: &Problem,
    effects: &mut [Box<dyn Effect>],
    iters: usize,
) -> Result<(Eval, Fit), CalibrateError> {
    let mut ev = evaluate(p, effects, None)?;
    let mut f = fit(&ev, &[])?;
    let (mut theta, _) = nl_vec(effects);
    if theta.is_empty() {
        return Ok((ev, f));
    }
    let n = theta.len();
    let mut lambda = 1e-3;
    for _ in 0..iters {
        let j = jacobian(p, effects, &ev, &f, true)?;
        let mut jtj = vec![vec![0.0; n]; n];
        let mut jtr = vec![0.0; n];
        for a in 0..n {
            for b in a..n {
                let s: f64 = j[a].iter().zip(&j[b]).map(|(x, y)| x * y).sum();
                jtj[a][b] = s;
                jtj[b][a] = s;
            }
            jtr[a] = j[a].iter().zip(&f.resid).map(|(x, y)| x * y).sum();
        }
        let mut improved = false;
        for _ in 0..6 {
            let mut m = jtj.clone();
            for (a, row) in m.iter_mut().enumerate() {
                row[a] += lambda * jtj[a][a].max(1e-300);
            }
            let Some(delta) = crate::lsq::solve(&m, &jtr) else {
                break;
            };
            let t: Vec<f64> = theta.iter().zip(&delta).map(|(a, d)| a - d).collect();
            let mut trial: Vec<Box<dyn Effect>> = effects.to_vec();
            set_nl(&mut trial, &t);
            let ev_t = evaluate(p, &trial, Some(&ev))?;
            let f_t = fit(&ev_t, &[])?;
            // Compare mean squares: the valid aperture may change slightly with registration.
            if f_t.rss / f_t.n.max(1.0) < f.rss / f.n.max(1.0) {
                let gain = 1.0 - (f_t.rss / f_t.n.max(1.0)) / (f.rss / f.n.max(1.0));
                set_nl(effects, &t);
                theta = effects.iter().flat_map(|e| e.nl()).collect();
                ev = ev_t;
                f = f_t;
                lambda = (lambda / 4.0).max(1e-7);
                improved = gain > 1e-6;
                break;
            }
            lambda *= 8.0;
        }
        if !improved {
            break;
        }
    }
    Ok((ev, f))
}
