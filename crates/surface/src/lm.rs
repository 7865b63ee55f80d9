//! Levenberg-Marquardt: the project's one damped Gauss-Newton driver for small non-linear
//! least-squares problems (a handful of parameters, any number of residuals).
//!
//! The caller describes its problem through [`LmProblem`]: how to evaluate a trial point (its
//! residual vector and the cost compared between trials), the Jacobian of the residual at the
//! current point (columns `d r / d x_k`, by finite differences or analytically), and optionally
//! how a step becomes a trial point (clamping to a plausible region). The driver owns the
//! damping schedule and the stopping rules, set by [`LmSettings`].
//!
//! Each iteration solves `min |J d + r|^2 + lambda sum_k D_k d_k^2`, with `D_k` the squared norm
//! of Jacobian column k (Marquardt's scaling, so parameters of any unit are damped alike). The
//! tall system is reduced once per iteration to the upper-triangular factor of `[J | -r]` with
//! the streaming QR of [`crate::lsq`]; every damping tried then costs only a small QR of that
//! factor stacked on the damping rows, never the normal equations (whose conditioning is the
//! square of the Jacobian's). A trial is accepted when its cost is finite and lower; lambda then
//! shrinks, otherwise it grows and the step is solved again.

use crate::lsq::{solve_from_r, StreamingQr};

/// Damping schedule and stopping rules.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmSettings {
    /// Iterations (Jacobian evaluations) at the most.
    pub max_iter: usize,
    /// Dampings tried per iteration before giving up on finding a lower cost.
    pub max_tries: usize,
    /// Starting damping.
    pub lambda0: f64,
    /// Factor lambda is multiplied by after a rejected trial.
    pub increase: f64,
    /// Factor lambda is divided by after an accepted trial.
    pub decrease: f64,
    /// Lambda never goes below this after an accepted trial.
    pub lambda_min: f64,
    /// Stop once an accepted step lowers the cost by less than this fraction of it.
    pub rel_tol: f64,
    /// Stop once an accepted step's largest component is below this (parameter units).
    pub step_tol: f64,
    /// Stop without trying a step once the undamped (Gauss-Newton) step is predicted, by the
    /// linearised residual, to lower the sum of squares by less than this fraction of it
    /// (0: never). No damped step is predicted to do better, so at a noisy minimum this saves
    /// the evaluations of the trials a rising damping would otherwise reject one by one.
    pub pred_tol: f64,
    /// Floor of the column scaling `D_k` (a column of zeros is still damped).
    pub diag_floor: f64,
}

impl Default for LmSettings {
    fn default() -> Self {
        LmSettings {
            max_iter: 100,
            max_tries: 12,
            lambda0: 1e-3,
            increase: 10.0,
            decrease: 3.0,
            lambda_min: 1e-12,
            rel_tol: 1e-12,
            step_tol: 0.0,
            pred_tol: 0.0,
            diag_floor: 1e-300,
        }
    }
}

/// A non-linear least-squares problem as the driver sees it.
pub trait LmProblem {
    /// What an evaluation carries (at least the residual vector).
    type State;
    type Error;

    /// The residual vector of an evaluation (data minus model, or its negative: the driver only
    /// needs it to agree with [`LmProblem::jacobian`]).
    fn residual<'s>(&self, state: &'s Self::State) -> &'s [f64];

    /// The cost compared between trials; the sum of squares of the residual unless overridden
    /// (for example a mean square where the number of residuals may change between trials).
    fn cost(&self, state: &Self::State) -> f64 {
        self.residual(state).iter().map(|r| r * r).sum()
    }

    /// Columns `d r / d x_k` at `x`, whose evaluation is `state`; one column per parameter, each
    /// as long as the residual.
    fn jacobian(&mut self, x: &[f64], state: &Self::State) -> Result<Vec<Vec<f64>>, Self::Error>;

    /// The point tried for a step from `x` (by default `x + step`); clamp here.
    fn propose(&self, x: &[f64], step: &[f64]) -> Vec<f64> {
        x.iter().zip(step).map(|(a, d)| a + d).collect()
    }

    /// Evaluates a trial point; `Ok(None)` when the model cannot be evaluated there (the trial
    /// counts as rejected). `current` is the evaluation at the point the step starts from, for
    /// problems that reuse parts of it.
    fn evaluate(
        &mut self,
        x: &[f64],
        current: &Self::State,
    ) -> Result<Option<Self::State>, Self::Error>;
}

/// Where the driver stopped.
#[derive(Debug, Clone)]
pub struct LmOutcome<S> {
    pub x: Vec<f64>,
    pub state: S,
    pub cost: f64,
    /// Iterations run (Jacobians evaluated).
    pub iterations: usize,
    /// Whether a stopping rule (relative gain, step size, predicted gain, or no lower cost at
    /// any damping) ended the run rather than the iteration limit.
    pub converged: bool,
}

/// Minimises the problem's cost from `x` (whose evaluation is `state`).
pub fn minimize<P: LmProblem>(
    problem: &mut P,
    x: Vec<f64>,
    state: P::State,
    settings: &LmSettings,
) -> Result<LmOutcome<P::State>, P::Error> {
    let mut x = x;
    let mut state = state;
    let mut cost = problem.cost(&state);
    let mut lambda = settings.lambda0;
    let np = x.len();
    let mut iterations = 0;
    let mut converged = false;
    if np == 0 {
        return Ok(LmOutcome {
            x,
            state,
            cost,
            iterations,
            converged: true,
        });
    }
    let p = np + 1;
    let mut row = vec![0.0; p];
    while iterations < settings.max_iter {
        iterations += 1;
        let jac = problem.jacobian(&x, &state)?;
        debug_assert_eq!(jac.len(), np);
        let r = problem.residual(&state);
        let mut qr = StreamingQr::new(p);
        for (i, &ri) in r.iter().enumerate() {
            for (k, col) in jac.iter().enumerate() {
                row[k] = col[i];
            }
            row[np] = -ri;
            qr.push_row(&row);
        }
        let rf = qr.finish();
        // |r|^2 and |r + J d_GN|^2: the corner of the factor of [J | -r] holds the latter.
        let rss: f64 = r.iter().map(|v| v * v).sum();
        let after_gn = rf[np * p + np] * rf[np * p + np];
        if rss > 0.0 && rss - after_gn < settings.pred_tol * rss {
            converged = true;
            break;
        }
        // Squared column norms of J: R^T R = [J | -r]^T [J | -r].
        let diag: Vec<f64> = (0..np)
            .map(|k| {
                (0..=k)
                    .map(|i| rf[i * p + k] * rf[i * p + k])
                    .sum::<f64>()
                    .max(settings.diag_floor)
            })
            .collect();
        let mut accepted = false;
        for _ in 0..settings.max_tries {
            let mut damped = StreamingQr::new(p);
            for i in 0..p {
                damped.push_row(&rf[i * p..(i + 1) * p]);
            }
            for (k, d) in diag.iter().enumerate() {
                row.iter_mut().for_each(|v| *v = 0.0);
                row[k] = (lambda * d).sqrt();
                damped.push_row(&row);
            }
            let step = solve_from_r(&damped.finish(), p).coefficients;
            if step.iter().all(|v| v.is_finite()) {
                let trial = problem.propose(&x, &step);
                if let Some(st) = problem.evaluate(&trial, &state)? {
                    let c = problem.cost(&st);
                    if c.is_finite() && c < cost {
                        let rel = (cost - c) / cost.max(f64::MIN_POSITIVE);
                        let largest = step.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                        x = trial;
                        state = st;
                        cost = c;
                        lambda = (lambda / settings.decrease).max(settings.lambda_min);
                        accepted = true;
                        converged = rel < settings.rel_tol || largest < settings.step_tol;
                        break;
                    }
                }
            }
            lambda *= settings.increase;
        }
        if !accepted {
            converged = true;
        }
        if converged {
            break;
        }
    }
    Ok(LmOutcome {
        x,
        state,
        cost,
        iterations,
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock's valley as residuals: r = (10 (y - x^2), 1 - x); minimum 0 at (1, 1).
    struct Rosenbrock;

    impl LmProblem for Rosenbrock {
        type State = Vec<f64>;
        type Error = ();
        fn residual<'s>(&self, s: &'s Vec<f64>) -> &'s [f64] {
            s
        }
        fn jacobian(&mut self, x: &[f64], _: &Vec<f64>) -> Result<Vec<Vec<f64>>, ()> {
            Ok(vec![vec![-20.0 * x[0], -1.0], vec![10.0, 0.0]])
        }
        fn evaluate(&mut self, x: &[f64], _: &Vec<f64>) -> Result<Option<Vec<f64>>, ()> {
            Ok(Some(vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]))
        }
    }

    #[test]
    fn finds_the_rosenbrock_minimum_from_the_classic_start() {
        let x0 = vec![-1.2, 1.0];
        let s0 = Rosenbrock.evaluate(&x0, &vec![]).unwrap().unwrap();
        let o = minimize(&mut Rosenbrock, x0, s0, &LmSettings::default()).unwrap();
        assert!(
            (o.x[0] - 1.0).abs() < 1e-9 && (o.x[1] - 1.0).abs() < 1e-9,
            "{o:?}"
        );
        assert!(o.cost < 1e-20 && o.converged, "{o:?}");
    }

    /// y = a exp(-b t) sampled with a known perturbation; forward-difference Jacobian, a clamp
    /// that keeps b positive, and a region where the model refuses to evaluate.
    struct Decay {
        t: Vec<f64>,
        y: Vec<f64>,
        /// The model's prediction rounded to this (0: exact), like a discretised model's small
        /// steps in the cost.
        rounding: f64,
        /// Forward-difference step of the Jacobian.
        h: f64,
        /// Trial points evaluated.
        trials: usize,
    }

    impl Decay {
        /// Samples of 3 exp(-0.7 t) with a fixed perturbation of 1e-3.
        fn new(rounding: f64, h: f64) -> Self {
            let t: Vec<f64> = (0..40).map(|i| i as f64 * 0.1).collect();
            let y = t
                .iter()
                .enumerate()
                .map(|(i, t)| 3.0 * (-0.7 * t).exp() + 1e-3 * ((i * 7 % 5) as f64 - 2.0))
                .collect();
            Decay {
                t,
                y,
                rounding,
                h,
                trials: 0,
            }
        }

        fn model(&self, x: &[f64]) -> Vec<f64> {
            let r = self.rounding;
            self.t
                .iter()
                .zip(&self.y)
                .map(|(t, y)| {
                    let m = x[0] * (-x[1] * t).exp();
                    y - if r > 0.0 { (m / r).round() * r } else { m }
                })
                .collect()
        }
    }

    impl LmProblem for Decay {
        type State = Vec<f64>;
        type Error = String;
        fn residual<'s>(&self, s: &'s Vec<f64>) -> &'s [f64] {
            s
        }
        fn jacobian(&mut self, x: &[f64], s: &Vec<f64>) -> Result<Vec<Vec<f64>>, String> {
            (0..2)
                .map(|k| {
                    let mut q = x.to_vec();
                    q[k] += self.h;
                    if q[1] > 50.0 {
                        return Err("outside".to_string());
                    }
                    let rk = self.model(&q);
                    Ok(rk.iter().zip(s).map(|(a, b)| (a - b) / self.h).collect())
                })
                .collect()
        }
        fn propose(&self, x: &[f64], step: &[f64]) -> Vec<f64> {
            vec![x[0] + step[0], (x[1] + step[1]).max(1e-3)]
        }
        fn evaluate(&mut self, x: &[f64], _: &Vec<f64>) -> Result<Option<Vec<f64>>, String> {
            self.trials += 1;
            if x[1] > 50.0 {
                return Ok(None);
            }
            Ok(Some(self.model(x)))
        }
    }

    #[test]
    fn fits_a_decay_where_the_gradient_vanishes() {
        let mut p = Decay::new(0.0, 1e-7);
        let x0 = vec![1.0, 2.0];
        let s0 = p.evaluate(&x0, &vec![]).unwrap().unwrap();
        let o = minimize(&mut p, x0, s0, &LmSettings::default()).unwrap();
        assert!(o.converged);
        // At the optimum the gradient J^T r vanishes (to the finite differences' accuracy).
        let j = p.jacobian(&o.x, &o.state).unwrap();
        for col in &j {
            let g: f64 = col.iter().zip(&o.state).map(|(a, b)| a * b).sum();
            let scale: f64 = col.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!(g.abs() < 1e-7 * scale, "gradient {g}");
        }
        assert!(
            (o.x[0] - 3.0).abs() < 5e-3 && (o.x[1] - 0.7).abs() < 5e-3,
            "{o:?}"
        );
    }

    #[test]
    fn no_parameters_and_no_lower_cost_end_without_moving() {
        let mut p = Rosenbrock;
        let x0 = vec![1.0, 1.0];
        let s0 = p.evaluate(&x0, &vec![]).unwrap().unwrap();
        let o = minimize(&mut p, x0.clone(), s0, &LmSettings::default()).unwrap();
        assert_eq!(o.x, x0);
        assert_eq!(o.iterations, 1);
        assert!(o.converged);
    }

    #[test]
    fn a_predicted_gain_below_pred_tol_ends_without_trials() {
        // The decay with its prediction rounded to 1e-7 (a discretised model's small steps in
        // the cost) and forward differences at a step the rounding does not swamp.
        let run = |pred_tol: f64| {
            let mut p = Decay::new(1e-7, 1e-3);
            let x0 = vec![1.0, 2.0];
            let s0 = p.model(&x0);
            let settings = LmSettings {
                max_iter: 50,
                max_tries: 6,
                rel_tol: 1e-6,
                pred_tol,
                ..LmSettings::default()
            };
            let o = minimize(&mut p, x0, s0, &settings).unwrap();
            (o, p.trials)
        };
        let (plain, plain_trials) = run(0.0);
        let (pred, pred_trials) = run(1e-6);
        assert!(plain.converged && pred.converged);
        // The same minimum to the tolerance asked for, with fewer model evaluations (25 trials
        // in 12 iterations without the prediction, 13 in 10 with it).
        assert!(
            pred.cost <= plain.cost * (1.0 + 1e-5),
            "{} vs {}",
            pred.cost,
            plain.cost
        );
        assert!(
            pred_trials < plain_trials,
            "{pred_trials} vs {plain_trials} trials, {} vs {} iterations",
            pred.iterations,
            plain.iterations
        );
        // Stopping on the prediction never tries a step it predicts to gain less than asked.
        assert!(pred.iterations <= plain.iterations);
    }
}
