//! Convergence ratios between a before and an after map, improvements between runs, and their
//! spread over repeat measurements.
//!
//! CR = (Q_before - Q_after) / Q_before for Q = RMS and PV, both maps restricted to their common
//! valid aperture and with the same terms removed from each (jointly, `form::remove_terms`).
//! Improvement of run b over run a = (CR_b - CR_a) / CR_a.
//!
//! Repeat measurements: each of before / after measured n >= 2 times on the same part. The
//! means are used, their standard errors (sample sd / sqrt n) are propagated to first order:
//!   sd(CR)^2 = (se_after / mean_before)^2 + (mean_after se_before / mean_before^2)^2,
//!   sd(I)^2  = (sd_b / CR_a)^2 + (CR_b sd_a / CR_a^2)^2.
//! Two runs differ beyond noise when |CR_b - CR_a| >= 2 sqrt(sd_a^2 + sd_b^2) (about 95 %
//! two-sided for normal errors); otherwise the verdict is "within noise".

use ndarray::Zip;
use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::form::{remove_terms, Term};
use crate::stats::height_stats;
use crate::surface::Surface;

/// (before - after) / before.
pub fn convergence_ratio(q_before: f64, q_after: f64) -> f64 {
    (q_before - q_after) / q_before
}

/// Why the convergence ratio of a before map is undefined, or None when it is defined:
/// CR = (before - after) / before needs a before map that is not flat (RMS and PV > 0) after
/// removing `removed`. The one statement of that rule and its words, for every command that
/// reports a CR.
pub fn undefined_convergence_reason(
    rms_before_nm: f64,
    pv_before_nm: f64,
    removed: &[Term],
) -> Option<String> {
    (!(rms_before_nm > 0.0 && pv_before_nm > 0.0 && rms_before_nm.is_finite())).then(|| {
        let terms: Vec<&str> = removed.iter().map(|t| t.name()).collect();
        format!(
            "the before map is flat after removing {} (RMS {} nm): the convergence ratio \
             (before - after) / before is undefined",
            if terms.is_empty() {
                "nothing".to_string()
            } else {
                terms.join(", ")
            },
            crate::format::sig(rms_before_nm, 4)
        )
    })
}

/// (cr_b - cr_a) / cr_a: the relative improvement of run b over run a.
pub fn improvement(cr_a: f64, cr_b: f64) -> f64 {
    (cr_b - cr_a) / cr_a
}

/// RMS and PV convergence of one run on the common aperture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Convergence {
    pub removed: Vec<Term>,
    /// Pixels valid in both maps (the aperture every number below uses).
    pub common_valid: usize,
    pub rms_before_nm: f64,
    pub rms_after_nm: f64,
    pub pv_before_nm: f64,
    pub pv_after_nm: f64,
    pub cr_rms: f64,
    pub cr_pv: f64,
}

/// Restricts both maps to their common valid aperture, removes `terms` from each and compares.
/// The grids must have the same shape (register the maps first).
pub fn convergence(
    before: &Surface,
    after: &Surface,
    terms: &[Term],
) -> Result<Convergence, SurfaceError> {
    if before.dim() != after.dim() {
        return Err(SurfaceError::GridMismatch(format!(
            "before {:?} vs after {:?}",
            before.dim(),
            after.dim()
        )));
    }
    let common = Zip::from(before.valid())
        .and(after.valid())
        .map_collect(|&a, &b| a && b);
    let b = before.with_valid(common.clone())?;
    let a = after.with_valid(common)?;
    let (b, _) = remove_terms(&b, terms)?;
    let (a, _) = remove_terms(&a, terms)?;
    let sb = height_stats(&b)?;
    let sa = height_stats(&a)?;
    Ok(Convergence {
        removed: terms.to_vec(),
        common_valid: sb.valid,
        rms_before_nm: sb.rms_nm,
        rms_after_nm: sa.rms_nm,
        pv_before_nm: sb.pv_nm,
        pv_after_nm: sa.pv_nm,
        cr_rms: convergence_ratio(sb.rms_nm, sa.rms_nm),
        cr_pv: convergence_ratio(sb.pv_nm, sa.pv_nm),
    })
}

/// Mean and sample standard deviation of repeat values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    pub n: usize,
    pub mean: f64,
    /// Sample standard deviation (n - 1 in the denominator).
    pub sd: f64,
}

impl Spread {
    /// Needs at least two finite values.
    pub fn of(values: &[f64]) -> Result<Spread, SurfaceError> {
        if values.len() < 2 {
            return Err(SurfaceError::TooFewPixels {
                what: "a repeat-measurement spread (values)".into(),
                needed: 2,
                have: values.len(),
            });
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(SurfaceError::InvalidArgument(
                "non-finite repeat value".into(),
            ));
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        Ok(Spread {
            n: values.len(),
            mean,
            sd: var.sqrt(),
        })
    }

    /// Standard error of the mean.
    pub fn se(&self) -> f64 {
        self.sd / (self.n as f64).sqrt()
    }
}

/// A convergence ratio from repeat measurements of Q before and after.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RepeatCr {
    pub before: Spread,
    pub after: Spread,
    /// CR of the means.
    pub cr: f64,
    /// Propagated standard deviation of `cr`.
    pub cr_sd: f64,
}

/// CR of repeated before / after values of one quantity (RMS or PV, nm).
pub fn repeat_cr(before: &[f64], after: &[f64]) -> Result<RepeatCr, SurfaceError> {
    let b = Spread::of(before)?;
    let a = Spread::of(after)?;
    if b.mean == 0.0 {
        return Err(SurfaceError::InvalidArgument(
            "mean before value is 0".into(),
        ));
    }
    let cr = convergence_ratio(b.mean, a.mean);
    let cr_sd = ((a.se() / b.mean).powi(2) + (a.mean * b.se() / (b.mean * b.mean)).powi(2)).sqrt();
    Ok(RepeatCr {
        before: b,
        after: a,
        cr,
        cr_sd,
    })
}

/// Run b compared with run a.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunComparison {
    pub cr_a: f64,
    pub cr_b: f64,
    /// (cr_b - cr_a) / cr_a.
    pub improvement: f64,
    pub improvement_sd: f64,
    /// cr_b - cr_a and its standard deviation sqrt(sd_a^2 + sd_b^2).
    pub difference: f64,
    pub difference_sd: f64,
    /// True when |difference| < 2 difference_sd.
    pub within_noise: bool,
}

/// Compares two runs' repeat CRs (see the module doc for the rule).
pub fn compare_runs(a: &RepeatCr, b: &RepeatCr) -> RunComparison {
    let difference = b.cr - a.cr;
    let difference_sd = a.cr_sd.hypot(b.cr_sd);
    let improvement_sd =
        ((b.cr_sd / a.cr).powi(2) + (b.cr * a.cr_sd / (a.cr * a.cr)).powi(2)).sqrt();
    RunComparison {
        cr_a: a.cr,
        cr_b: b.cr,
        improvement: improvement(a.cr, b.cr),
        improvement_sd,
        difference,
        difference_sd,
        within_noise: difference.abs() < 2.0 * difference_sd,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn propagated_spread_matches_monte_carlo() {
        // True before 100 nm, after 80 nm, each measured 5 times with sd 3 nm.
        let mut rng = Rng::new(17);
        let trials = 20_000;
        let mut crs = Vec::with_capacity(trials);
        let mut sds = 0.0;
        for _ in 0..trials {
            let b: Vec<f64> = (0..5).map(|_| 100.0 + 3.0 * rng.normal()).collect();
            let a: Vec<f64> = (0..5).map(|_| 80.0 + 3.0 * rng.normal()).collect();
            let r = repeat_cr(&b, &a).unwrap();
            crs.push(r.cr);
            sds += r.cr_sd;
        }
        let m = crs.iter().sum::<f64>() / trials as f64;
        let sd_mc = (crs.iter().map(|c| (c - m).powi(2)).sum::<f64>() / (trials - 1) as f64).sqrt();
        // Analytic first-order sd with the true values: se = 3 / sqrt 5.
        let se = 3.0 / 5f64.sqrt();
        let sd_true = ((se / 100.0).powi(2) + (80.0 * se / 1e4).powi(2)).sqrt();
        assert!((m - 0.2).abs() < 0.001, "mean CR {m}");
        assert!(
            (sd_mc / sd_true - 1.0).abs() < 0.03,
            "MC sd {sd_mc} vs {sd_true}"
        );
        // The per-trial estimate pools two 4-dof sample variances (about 8 dof), so its mean
        // sits a little below the truth: E[s] / sigma = 0.97 for 8 dof.
        let mean_est = sds / trials as f64;
        let ratio = mean_est / sd_true;
        assert!((0.94..1.0).contains(&ratio), "{mean_est} vs {sd_true}");
    }

    #[test]
    fn verdict_and_improvement_arithmetic() {
        let a = RepeatCr {
            before: Spread {
                n: 3,
                mean: 1.0,
                sd: 0.0,
            },
            after: Spread {
                n: 3,
                mean: 0.9,
                sd: 0.0,
            },
            cr: 0.10,
            cr_sd: 0.01,
        };
        let mut b = a;
        b.cr = 0.13;
        let c = compare_runs(&a, &b);
        assert!((c.improvement - 0.3).abs() < 1e-12);
        assert!((c.difference_sd - 0.01 * 2f64.sqrt()).abs() < 1e-15);
        assert!(!c.within_noise, "0.03 > 2 * 0.0141");
        b.cr = 0.12;
        assert!(compare_runs(&a, &b).within_noise, "0.02 < 0.0283");
        // sd(I) by finite differences of I(cr_a, cr_b) = cr_b / cr_a - 1.
        let h = 1e-7;
        let di_da = (improvement(0.1 + h, 0.12) - improvement(0.1 - h, 0.12)) / (2.0 * h);
        let di_db = (improvement(0.1, 0.12 + h) - improvement(0.1, 0.12 - h)) / (2.0 * h);
        let want = ((di_da * 0.01).powi(2) + (di_db * 0.01).powi(2)).sqrt();
        assert!((compare_runs(&a, &b).improvement_sd - want).abs() < 1e-6);
        assert!(Spread::of(&[1.0]).is_err());
        assert!(Spread::of(&[1.0, f64::NAN]).is_err());
        let s = Spread::of(&[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert!((s.sd - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
    }
}
