//! One-sigma uncertainties of the accepted effects' reported parameters: the fitted vector's
//! covariance (classical and cluster-robust over the hold-out blocks, the larger kept per
//! parameter) propagated to the reported parameters by finite differences (delta method).
//! Statistical, with one systematic term: where an accepted rate term rests on values the maps
//! do not measure (a height covariate under the tool off the measured pixels), the spread its
//! plausible values give (`fill_variances`, [`crate::fill_error`]). Another systematic model
//! error (an effect the library does not have) is not in it.
//! The registration's texture bias is removed from the estimate before (see
//! [`registration_texture_step`]), not added to its interval.

use crate::error::CalibrateError;
use crate::model::{Effect, Eval, Fit, Linear, Param, Problem};
use crate::refine::{jacobian, set_nl, sigma_steps};
use crate::selection::Split;

/// Numeric parameters of all effects as one flat vector (for the delta method).
fn flat_params(effects: &[Box<dyn Effect>], lin: &Linear) -> Vec<f64> {
    let mut v = Vec::new();
    for e in effects {
        for (_, p) in e.params(lin) {
            match p {
                Param::Num(x) => v.push(x),
                Param::List(xs) => v.extend(xs),
                Param::Text(_) => {}
            }
        }
    }
    v
}

/// One-sigma uncertainties of every numeric parameter: full Jacobian J (linear columns and
/// forward-difference columns of the non-linear parameters at fixed linear coefficients),
/// propagated to the reported parameters by finite differences. Two covariances of the fitted
/// vector are formed and the larger variance kept for each parameter:
/// - classical `s^2 (J^T J)^-1`, `s^2 = RSS / (n - p)`, right for independent residuals;
/// - cluster-robust (sandwich) `A^-1 B A^-1`, `A = J^T J`, `B = G / (G - 1) sum_b u_b u_b^T`,
///   `u_b = J_b^T r_b` summed over the pixels of hold-out block b (G blocks): residual structure
///   correlated within a block (unmodelled MSF, interpolation error) widens it, where the
///   classical form would be optimistic.
pub fn uncertainties(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev: &Eval,
    f: &Fit,
    blocks: &Split,
) -> Result<Vec<f64>, CalibrateError> {
    uncertainties_and_correlations(p, effects, ev, f, blocks).map(|(s, _)| s)
}

/// [`uncertainties`] and the correlation matrix of the same reported parameters, from the
/// classical covariance `(J^T J)^-1` of the joint fit (the scale `s^2` cancels): how far the
/// data tell one accepted effect's parameter from another's.
pub fn uncertainties_and_correlations(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev: &Eval,
    f: &Fit,
    blocks: &Split,
) -> Result<(Vec<f64>, Vec<Vec<f64>>), CalibrateError> {
    let (cols, nlin) = joint_columns(p, effects, ev, f)?;
    let all: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let n = all.len();
    // `J^T J` (upper triangle by blocked sums: each entry the sequential sum of `x_i y_i`
    // from -0.0, as `Iterator::sum` forms it; unit weights leave every product exact).
    let ones = vec![1.0; f.resid.len()];
    let upper = crate::lsq::products(&all, &all, &ones, None, -0.0);
    let mut jtj = vec![vec![0.0; n]; n];
    for a in 0..n {
        for b in a..n {
            jtj[a][b] = upper[a][b];
            jtj[b][a] = upper[a][b];
        }
    }
    let cov = crate::lsq::inverse(&jtj)
        .ok_or_else(|| CalibrateError::Processing("singular covariance".into()))?;
    let s2 = f.rss / (f.n - n as f64).max(1.0);
    let robust = sandwich(&all, &f.resid, &cov, blocks);
    let lin0 = ev.linear(f);
    let base = flat_params(effects, &lin0);
    let theta0: Vec<f64> = effects.iter().flat_map(|e| e.nl()).collect();
    let steps = sigma_steps(effects);
    let unresolved: Vec<f64> = effects.iter().flat_map(|e| e.nl_unresolved(p)).collect();
    let mut grads = vec![vec![0.0; n]; base.len()];
    for j in 0..n {
        let (vals, h) = if j < nlin {
            let h = 1e-6 * f.coef[j].abs().max(1e-9);
            let mut lin = lin0.clone();
            lin.coef[j] += h;
            (flat_params(effects, &lin), h)
        } else {
            let k = j - nlin;
            let mut t = theta0.clone();
            t[k] += steps[k];
            let mut trial: Vec<Box<dyn Effect>> = effects.to_vec();
            set_nl(&mut trial, &t);
            (flat_params(&trial, &lin0), steps[k])
        };
        for (g, (v, b)) in grads.iter_mut().zip(vals.iter().zip(&base)) {
            g[j] = (v - b) / h;
        }
    }
    let fill = fill_variances(p, effects, ev, f, &all, &cov, &grads)?;
    let m = grads.len();
    let mut pc = vec![vec![0.0; m]; m];
    for i in 0..m {
        for j in i..m {
            let mut s = 0.0;
            for a in 0..n {
                for b in 0..n {
                    s += grads[i][a] * cov[a][b] * grads[j][b];
                }
            }
            pc[i][j] = s;
            pc[j][i] = s;
        }
    }
    let corr: Vec<Vec<f64>> = (0..m)
        .map(|i| {
            (0..m)
                .map(|j| {
                    let d = (pc[i][i] * pc[j][j]).sqrt();
                    if d > 0.0 && d.is_finite() {
                        (pc[i][j] / d).clamp(-1.0, 1.0)
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    let sig = grads
        .iter()
        .zip(&fill)
        .map(|(g, fill)| {
            let quad = |c: &[Vec<f64>]| {
                let mut s = 0.0;
                for a in 0..n {
                    for b in 0..n {
                        s += g[a] * c[a][b] * g[b];
                    }
                }
                s
            };
            let classical = s2 * quad(&cov);
            let clustered = robust.as_deref().map(quad).unwrap_or(0.0);
            // A parameter the data cannot resolve within a span: uniform over it.
            let flat: f64 = unresolved
                .iter()
                .enumerate()
                .map(|(k, w)| (g[nlin + k] * w).powi(2) / 12.0)
                .sum();
            (classical.max(clustered).max(0.0) + flat + fill).sqrt()
        })
        .collect();
    Ok((sig, corr))
}

/// The variance each reported parameter takes from rate terms resting on values the maps do
/// not measure ([`Effect::term_errors`], [`crate::fill_error`]): for every draw `e` of a term's
/// error, the data hold `b R(g + e)` where the model has `b R(g)`, so the fitted vector moves
/// by `(J^T J)^-1 J^T (b R(e))` (linearised, `b` the term's fitted coefficient, `R(e)`
/// un-centred) and the reported parameters by the delta method's gradients; the mean square of
/// those moves over the draws. Zero for every parameter when no effect has such a term.
fn fill_variances(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev: &Eval,
    f: &Fit,
    cols: &[&[f64]],
    cov: &[Vec<f64>],
    grads: &[Vec<f64>],
) -> Result<Vec<f64>, CalibrateError> {
    use bonnetlab_process::removal::Fidelity;
    use rayon::prelude::*;
    let mut out = vec![0.0; grads.len()];
    let n = cols.len();
    // `R(1)`: the baseline column (un-centres a rate term's column).
    let Some(base) = ev.names.iter().position(|c| c == "baseline") else {
        return Ok(out);
    };
    let one = &ev.cols[base];
    for e in effects {
        for (name, draws) in e.term_errors(p, crate::fill_error::DRAWS) {
            let Some(j) = ev.names.iter().position(|c| *c == name) else {
                continue;
            };
            if draws.is_empty() {
                continue;
            }
            let b = f.coef[j];
            let moves: Vec<Vec<f64>> = draws
                .par_iter()
                .map(|err| {
                    let (c, mean) =
                        p.rate_term_column(Fidelity::Full, &ev.kernels, &ev.exec, err)?;
                    // `R(e)` un-centred on the analysis pixels, weighted as the joint columns.
                    let y: Vec<f64> = c
                        .iter()
                        .zip(one)
                        .zip(&ev.w)
                        .map(|((c, one), w)| b * (c + mean * one) * w)
                        .collect();
                    let jty: Vec<f64> = cols
                        .iter()
                        .map(|col| col.iter().zip(&y).map(|(a, b)| a * b).sum())
                        .collect();
                    let dtheta: Vec<f64> = (0..n)
                        .map(|a| (0..n).map(|k| cov[a][k] * jty[k]).sum())
                        .collect();
                    Ok(grads
                        .iter()
                        .map(|g| g.iter().zip(&dtheta).map(|(a, b)| a * b).sum())
                        .collect())
                })
                .collect::<Result<_, CalibrateError>>()?;
            let k = moves.len() as f64;
            for mv in &moves {
                for (o, d) in out.iter_mut().zip(mv) {
                    *o += d * d / k;
                }
            }
        }
    }
    Ok(out)
}

/// The columns of the joint fit at `ev`: the linear columns (weighted) first, then the
/// non-linear parameters' Jacobian (unprofiled); and the number of linear ones.
fn joint_columns(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev: &Eval,
    f: &Fit,
) -> Result<(Vec<Vec<f64>>, usize), CalibrateError> {
    let mut cols: Vec<Vec<f64>> = ev
        .cols
        .iter()
        .map(|c| c.iter().zip(&ev.w).map(|(a, w)| a * w).collect())
        .collect();
    let nlin = cols.len();
    cols.extend(jacobian(p, effects, ev, f, false, &sigma_steps(effects))?);
    Ok((cols, nlin))
}

/// Smoothing (pixels) of the after map for the second registration estimating equation.
const ALT_SMOOTH_PX: f64 = 2.0;

/// The correction of a fitted 3-parameter registration for texture that does not resample
/// identically, as a step of the non-linear parameters (zero but for the registration's dx,
/// dy in mm and rotation in rad); `None` without such a registration or when the step is not
/// small (over half a pixel anywhere on the map: the linearisation would not hold).
///
/// The fit solves `J1^T r = 0`, `J1` the registration columns from the after map smoothed by
/// 1 px (see `effects::registration`). Texture finer than the map's Nyquist, point-sampled
/// at two sub-pixel phases, leaves a residual correlated with those columns, so the zero is
/// biased (every hold-out block alike: neither the classical nor the block-robust covariance
/// sees it). The same equation with the columns from a 2 px smoothing, `J2^T r(theta + d) = 0`,
/// linearised `d = (J2^T J1)^-1 J2^T r`, has its zero further out along the same direction:
/// on the validation harness's power-law and real-map runs (400 x 400 at 0.25 mm, 60 runs,
/// two seeds) the 1 px estimate's error was -0.70 to -1.08 times `d` per parameter
/// (correlation 0.74-0.99). The estimate is extrapolated linearly in the smoothing width to
/// none, `theta - d` (no factor fitted to those runs): the errors fell 3-4x in dx and dy and
/// 1.5x in rotation, and the statistical intervals then cover the truth in 71-73 % of them
/// (reports/calibration.md). On a smooth or noise-only surface `d` is at the statistical
/// scale, and so is the step.
pub fn registration_texture_step(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    ev: &Eval,
    f: &Fit,
) -> Result<Option<Vec<f64>>, CalibrateError> {
    let mut k = 0;
    let mut at = None;
    for e in effects {
        let m = e.nl().len();
        if e.registration().is_some() && m == 3 {
            at = Some(k);
        }
        k += m;
    }
    let Some(at) = at else {
        return Ok(None);
    };
    let (cols, nlin) = joint_columns(p, effects, ev, f)?;
    let all: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let alt = crate::effects::registration::jacobian_smoothed(p, ev, ALT_SMOOTH_PX);
    let col = nlin + at;
    let j2: Vec<&[f64]> = (0..all.len())
        .map(|i| {
            if (col..col + 3).contains(&i) {
                alt[i - col].as_slice()
            } else {
                all[i]
            }
        })
        .collect();
    // Every `j2[a] . cols[b]` and `j2[a] . resid` by blocked sums (each the sequential sum of
    // `x_i y_i` from -0.0, as `Iterator::sum` forms it; unit weights leave the products exact).
    let mut targets = all.clone();
    targets.push(&f.resid);
    let ones = vec![1.0; f.resid.len()];
    let x = crate::lsq::products_from(&j2, &targets, &ones, None, -0.0, |_| 0);
    let n = all.len();
    let m = nalgebra::DMatrix::from_fn(n, n, |a, b| x[a][b]);
    let rhs = nalgebra::DVector::from_fn(n, |a, _| x[a][n]);
    let Some(d) = m.lu().solve(&rhs) else {
        return Ok(None);
    };
    let d: Vec<f64> = d.iter().copied().collect();
    if d.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    // The step's largest displacement on the map, in pixels.
    let g = &p.grid;
    let pix = g.dx_mm.min(g.dy_mm);
    let radius = 0.5 * (g.cols as f64 * g.dx_mm).hypot(g.rows as f64 * g.dy_mm);
    let (sx, sy, st) = (d[col], d[col + 1], d[col + 2]);
    if (sx.hypot(sy) + radius * st.abs()) > 0.5 * pix {
        return Ok(None);
    }
    let mut step = vec![0.0; k];
    step[at..at + 3].copy_from_slice(&d[col..col + 3]);
    Ok(Some(step))
}

/// Cluster-robust covariance `A^-1 B A^-1` with the hold-out blocks as clusters (see
/// `uncertainties`); `None` with fewer than 8 populated blocks.
fn sandwich(
    cols: &[&[f64]],
    resid: &[f64],
    a_inv: &[Vec<f64>],
    sp: &Split,
) -> Option<Vec<Vec<f64>>> {
    let n = cols.len();
    let mut u = vec![vec![0.0; n]; sp.n_blocks];
    let mut used = vec![false; sp.n_blocks];
    for (i, (&b, &r)) in sp.block.iter().zip(resid).enumerate() {
        if r == 0.0 {
            continue;
        }
        used[b] = true;
        for (k, c) in cols.iter().enumerate() {
            u[b][k] += c[i] * r;
        }
    }
    let g = used.iter().filter(|v| **v).count() as f64;
    if g < 8.0 {
        return None;
    }
    let mut bm = vec![vec![0.0; n]; n];
    for ub in u.iter().zip(&used).filter(|(_, u)| **u).map(|(v, _)| v) {
        for a in 0..n {
            for c in 0..n {
                bm[a][c] += ub[a] * ub[c];
            }
        }
    }
    let corr = g / (g - 1.0);
    let a = nalgebra::DMatrix::from_fn(n, n, |i, j| a_inv[i][j]);
    let b = nalgebra::DMatrix::from_fn(n, n, |i, j| bm[i][j]);
    let s = &a * b * &a * corr;
    Some(
        (0..n)
            .map(|i| (0..n).map(|j| s[(i, j)]).collect())
            .collect(),
    )
}
