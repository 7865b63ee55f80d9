//! Least-squares fit of the bonnet model (`model`) to the measured spots of one bonnet.
//!
//! Data per spot: peak rate, volumetric rate, FWHM X and FWHM Y. Residuals are logarithmic
//! (ln(model / measured)), so every metric counts by its relative error whatever its unit.
//! Parameters are fitted in log space (they stay positive) by Levenberg-Marquardt with a
//! forward-difference Jacobian (the project's one driver, `bonnetlab_surface::lm`); the covariance
//! is inverted by nalgebra's LU.
//!
//! Identifiability: the bonnet radius `R` always shows in the spot width (a = sqrt(2Rh - h^2)).
//! The Preston coefficient `k` and the effective modulus `E` enter the rate as
//! `k (p_inner + 2/pi E a / R)`, so they separate only when the offset or the inner pressure
//! varies across the spots; otherwise `E` is held at its starting value and only `k R`-type
//! combinations are fitted (reported in `held`). The pressure exponent is never fitted.

use bonnetlab_surface::lm::{self, LmProblem, LmSettings};
use nalgebra::{DMatrix, LU};
use serde::{Deserialize, Serialize};

use crate::error::SpotsError;
use crate::metrics::SpotMetrics;
use crate::model::{BonnetModel, Factors, ModelMetrics};

/// One spot's settings and measured metrics, as the fit sees them.
#[derive(Debug, Clone, Copy)]
pub struct Observation<'a> {
    pub factors: Factors,
    pub metrics: &'a SpotMetrics,
}

/// A fitted model with what was fitted and how well.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFit {
    pub model: BonnetModel,
    /// Parameter names that were fitted (`radius_mm`, `preston_nm_per_mpa_mm`, `modulus_mpa`).
    pub fitted: Vec<String>,
    /// Parameter names held at their starting value, with why.
    pub held: Vec<String>,
    /// One-sigma relative standard errors of the fitted parameters (same order as `fitted`),
    /// from the Jacobian at the optimum and the residual variance.
    pub rel_std_err: Vec<f64>,
    /// RMS of the log residuals (about the relative misfit of a metric).
    pub rms_log_residual: f64,
    pub n_spots: usize,
    pub iterations: usize,
}

/// Starting values and the one thing that cannot be fitted here.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FitStart {
    pub radius_mm: f64,
    pub preston_nm_per_mpa_mm: f64,
    pub modulus_mpa: f64,
    pub pressure_exponent: f64,
}

impl Default for FitStart {
    /// A 20 mm bonnet (the recipe example's), k = 0.05 nm/(MPa mm) (5e-14 m^2/N, the order of
    /// bonnet polishing of SiC with diamond slurry), E = 2 MPa, gamma = 1 (parabolic).
    fn default() -> Self {
        FitStart {
            radius_mm: 20.0,
            preston_nm_per_mpa_mm: 0.05,
            modulus_mpa: 2.0,
            pressure_exponent: crate::model::DEFAULT_PRESSURE_EXPONENT,
        }
    }
}

fn residuals(model: &BonnetModel, obs: &[Observation]) -> Result<Vec<f64>, SpotsError> {
    let mut r = Vec::with_capacity(4 * obs.len());
    for o in obs {
        let p: ModelMetrics = model.metrics(&o.factors)?;
        let m = o.metrics;
        for (pred, meas) in [
            (p.peak_rate_nm_per_s, m.peak_rate_nm_per_s),
            (p.volume_rate_nm_mm2_per_s, m.volume_rate_nm_mm2_per_s),
            (p.fwhm_x_mm, m.fwhm_x_mm),
            (p.fwhm_y_mm, m.fwhm_y_mm),
        ] {
            if !(pred > 0.0 && meas > 0.0) {
                return Err(SpotsError::Fit(format!(
                    "non-positive metric (model {pred}, measured {meas})"
                )));
            }
            r.push((pred / meas).ln());
        }
    }
    Ok(r)
}

fn distinct(values: impl Iterator<Item = f64>) -> usize {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs().max(1e-12));
    v.len()
}

/// Fits the model to the spots of one bonnet.
pub fn fit_model(obs: &[Observation], start: &FitStart) -> Result<ModelFit, SpotsError> {
    if obs.is_empty() {
        return Err(SpotsError::Fit("no spot to fit".into()));
    }
    let separable = distinct(obs.iter().map(|o| o.factors.offset_mm)) > 1
        || distinct(obs.iter().map(|o| o.factors.inner_pressure_mpa)) > 1;
    let mut names = vec!["radius_mm", "preston_nm_per_mpa_mm"];
    let mut held = vec![format!(
        "pressure_exponent = {} (shape, not fitted)",
        start.pressure_exponent
    )];
    if separable {
        names.push("modulus_mpa");
    } else {
        held.push(format!(
            "modulus_mpa = {} (offset and inner pressure do not vary: not separable from the Preston coefficient)",
            start.modulus_mpa
        ));
    }
    let np = names.len();
    let build = |q: &[f64]| {
        let mut m = BonnetModel {
            radius_mm: q[0].exp(),
            preston_nm_per_mpa_mm: q[1].exp(),
            modulus_mpa: start.modulus_mpa,
            pressure_exponent: start.pressure_exponent,
        };
        if np == 3 {
            m.modulus_mpa = q[2].exp();
        }
        m
    };
    let mut q: Vec<f64> = vec![start.radius_mm.ln(), start.preston_nm_per_mpa_mm.ln()];
    if np == 3 {
        q.push(start.modulus_mpa.max(1e-3).ln());
    }
    // Better start: the width fixes R, then the mean rate ratio fixes k.
    q = initial_guess(q, obs, &build)?;

    let r0 = residuals(&build(&q), obs)?;
    let mut problem = SpotProblem { obs, build: &build };
    let settings = LmSettings {
        max_iter: 200,
        max_tries: 30,
        lambda0: 1e-3,
        increase: 10.0,
        decrease: 1.0 / 0.3,
        lambda_min: 1e-12,
        rel_tol: 1e-15,
        step_tol: 1e-10,
        pred_tol: 0.0,
        diag_floor: 1e-12,
    };
    let out = lm::minimize(&mut problem, q, r0, &settings)?;
    let (q, r, c, iterations) = (out.x, out.state, out.cost, out.iterations);
    let jac = problem.jacobian(&q, &r)?;
    let n = r.len();
    let dof = n.saturating_sub(np).max(1) as f64;
    let s2 = c / dof;
    let (jtj, _) = normal(&jac, &r, np);
    let rel_std_err = match invert(&jtj, np) {
        Some(inv) => (0..np)
            .map(|k| (s2 * inv[k * np + k]).max(0.0).sqrt())
            .collect(),
        None => vec![f64::INFINITY; np],
    };
    Ok(ModelFit {
        model: build(&q),
        fitted: names.iter().map(|s| s.to_string()).collect(),
        held,
        rel_std_err,
        rms_log_residual: (c / n as f64).sqrt(),
        n_spots: obs.len(),
        iterations,
    })
}

/// The fit as the project's one Levenberg-Marquardt driver sees it: log parameters, log
/// residuals, steps clamped to a factor e per iteration.
struct SpotProblem<'a, 'o, F: Fn(&[f64]) -> BonnetModel> {
    obs: &'a [Observation<'o>],
    build: &'a F,
}

impl<F: Fn(&[f64]) -> BonnetModel> LmProblem for SpotProblem<'_, '_, F> {
    type State = Vec<f64>;
    type Error = SpotsError;

    fn residual<'s>(&self, state: &'s Vec<f64>) -> &'s [f64] {
        state
    }

    fn jacobian(&mut self, q: &[f64], r: &Vec<f64>) -> Result<Vec<Vec<f64>>, SpotsError> {
        jacobian(q, r, self.obs, self.build)
    }

    fn propose(&self, q: &[f64], step: &[f64]) -> Vec<f64> {
        q.iter()
            .zip(step)
            .map(|(a, b)| a + b.clamp(-1.0, 1.0))
            .collect()
    }

    fn evaluate(&mut self, q: &[f64], _: &Vec<f64>) -> Result<Option<Vec<f64>>, SpotsError> {
        // A trial the model cannot evaluate is a rejected trial, not a failed fit.
        Ok(residuals(&(self.build)(q), self.obs).ok())
    }
}

fn initial_guess(
    mut q: Vec<f64>,
    obs: &[Observation],
    build: &impl Fn(&[f64]) -> BonnetModel,
) -> Result<Vec<f64>, SpotsError> {
    // Width: scale R so the mean FWHM matches (FWHM scales roughly like a ~ sqrt(R)).
    for _ in 0..3 {
        let m = build(&q);
        let mut lr = 0.0;
        for o in obs {
            let p = m.metrics(&o.factors)?;
            lr += (o.metrics.fwhm_x_mm * o.metrics.fwhm_y_mm / (p.fwhm_x_mm * p.fwhm_y_mm)).ln();
        }
        q[0] += lr / obs.len() as f64;
    }
    let m = build(&q);
    let mut lk = 0.0;
    for o in obs {
        let p = m.metrics(&o.factors)?;
        lk += (o.metrics.volume_rate_nm_mm2_per_s / p.volume_rate_nm_mm2_per_s).ln();
    }
    q[1] += lk / obs.len() as f64;
    Ok(q)
}

fn jacobian(
    q: &[f64],
    r0: &[f64],
    obs: &[Observation],
    build: &impl Fn(&[f64]) -> BonnetModel,
) -> Result<Vec<Vec<f64>>, SpotsError> {
    let h = 1e-6;
    let mut cols = Vec::with_capacity(q.len());
    for k in 0..q.len() {
        let mut qk = q.to_vec();
        qk[k] += h;
        let rk = residuals(&build(&qk), obs)?;
        cols.push(rk.iter().zip(r0).map(|(a, b)| (a - b) / h).collect());
    }
    Ok(cols)
}

fn normal(cols: &[Vec<f64>], r: &[f64], np: usize) -> (Vec<f64>, Vec<f64>) {
    let mut jtj = vec![0.0; np * np];
    let mut jtr = vec![0.0; np];
    for a in 0..np {
        jtr[a] = cols[a].iter().zip(r).map(|(x, y)| x * y).sum();
        for b in 0..np {
            jtj[a * np + b] = cols[a].iter().zip(&cols[b]).map(|(x, y)| x * y).sum();
        }
    }
    (jtj, jtr)
}

/// LU factors (nalgebra, partial pivoting) of the row-major n x n matrix `a`; `None` when a
/// pivot is below 1e-14 of the matrix's largest entry (singular at its scale) or not finite.
fn lu_checked(a: &[f64], n: usize) -> Option<LU<f64, nalgebra::Dyn, nalgebra::Dyn>> {
    let m = DMatrix::from_row_slice(n, n, a);
    let scale = m.amax();
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let lu = m.lu();
    let tiny = lu
        .u()
        .diagonal()
        .iter()
        .any(|p| p.is_nan() || p.abs() <= 1e-14 * scale);
    (!tiny).then_some(lu)
}

/// The inverse of the row-major n x n matrix `a`, row-major.
fn invert(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let inv = lu_checked(a, n)?.try_inverse()?;
    inv.iter()
        .all(|v| v.is_finite())
        .then(|| inv.transpose().as_slice().to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverts_a_permuted_system_and_rejects_singular() {
        let a = [0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0];
        let inv = invert(&a, 3).unwrap();
        for r in 0..3 {
            for c in 0..3 {
                let v: f64 = (0..3).map(|k| a[r * 3 + k] * inv[k * 3 + c]).sum();
                assert!((v - f64::from(u8::from(r == c))).abs() < 1e-12);
            }
        }
        assert!(invert(&[1.0, 2.0, 2.0, 4.0], 2).is_none());
        assert!(invert(&[1.0, 2.0, 2.0, 4.0 + 1e-16], 2).is_none());
    }
}
