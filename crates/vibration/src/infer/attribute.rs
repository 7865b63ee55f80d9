//! Counterfactual attribution of the difference between two runs.
//!
//! Rule. A cause's *effect* on a run is the measured value minus the value the run would have
//! had without that cause: for σ1 (ripple at 1/pitch along Y of the after map) and CR(RMS),
//! the after map with the removal the cause added taken back (`after + ΔR_cause`, ΔR = the
//! forward model's removal with the cause minus without it, nm) is re-measured with the same
//! form terms removed. The difference between runs is B − A (the other run minus the first, as
//! `improvement_*`); a cause's share is `(effect_B − effect_A) / (value_B − value_A)`, so a cause
//! present with the same strength in both runs gets no share and a cause acting against the
//! difference gets a negative one. The unexplained share is 1 − Σ shares (σ1): non-additivity of
//! the causes, noise, and whatever no cause models. A cause is `significant` when, for σ1 or for
//! CR(RMS), its effect difference exceeds 1.96 times its standard deviation (the two runs' SDs in
//! quadrature) *and* its share is at least [`MATERIAL_SHARE`] (a precisely known but negligible
//! part of the difference is not reported as significant).
//! Causes are sorted by |share of the σ1 difference|, largest first.

use super::fit::ForcingFit;
use super::ForcingModel;
use crate::coupling::Mechanisms;
use crate::error::VibrationError;
use bonnetlab_spectrum::{ripple, PsdOptions};
use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};
use ndarray::Array2;
use serde::Serialize;

/// Smallest share of a difference a cause must have to be called significant.
pub const MATERIAL_SHARE: f64 = 0.05;

/// One cause's effect on one run (effect = value with the cause − value without it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CauseEffect {
    /// Effect kind (calibrate's names) or coupling mechanism name.
    pub cause: String,
    pub sigma1_nm: f64,
    pub sigma1_sd_nm: f64,
    /// Effect on CR(RMS), a fraction.
    pub cr_rms: f64,
    pub cr_rms_sd: f64,
}

/// A run's measured σ1 (after map, nm) and CR(RMS), with the effects of its causes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunEffects {
    pub name: String,
    pub sigma1_nm: f64,
    pub cr_rms: f64,
    pub causes: Vec<CauseEffect>,
}

/// One entry of `difference.causes` (shared/spec/interfaces.md, compare).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DifferenceCause {
    pub cause: String,
    pub share_of_sigma1_difference: f64,
    pub share_of_cr_rms_difference: f64,
    pub significant: bool,
}

/// The `difference` object of `compare`'s JSON for one pair (A = first run, B = other).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Difference {
    pub runs: [String; 2],
    /// σ1_B − σ1_A, nm.
    pub sigma1_difference_nm: f64,
    /// CR_B − CR_A (RMS), fraction.
    pub cr_rms_difference: f64,
    pub causes: Vec<DifferenceCause>,
    pub unexplained_share_of_sigma1_difference: f64,
}

/// Attributes B − A to the causes of both runs (a cause missing from a run has no effect there).
pub fn attribute_difference(a: &RunEffects, b: &RunEffects) -> Difference {
    let ds = b.sigma1_nm - a.sigma1_nm;
    let dc = b.cr_rms - a.cr_rms;
    let mut names: Vec<&str> = Vec::new();
    for c in a.causes.iter().chain(&b.causes) {
        if !names.contains(&c.cause.as_str()) {
            names.push(&c.cause);
        }
    }
    let find = |r: &RunEffects, n: &str| -> (f64, f64, f64, f64) {
        r.causes
            .iter()
            .filter(|c| c.cause == n)
            .fold((0.0, 0.0, 0.0, 0.0), |acc, c| {
                (
                    acc.0 + c.sigma1_nm,
                    (acc.1 * acc.1 + c.sigma1_sd_nm * c.sigma1_sd_nm).sqrt(),
                    acc.2 + c.cr_rms,
                    (acc.3 * acc.3 + c.cr_rms_sd * c.cr_rms_sd).sqrt(),
                )
            })
    };
    let share = |d: f64, total: f64| if total != 0.0 { d / total } else { 0.0 };
    let mut causes: Vec<DifferenceCause> = names
        .iter()
        .map(|&n| {
            let (sa, sda, ca, cda) = find(a, n);
            let (sb, sdb, cb, cdb) = find(b, n);
            let d_s = sb - sa;
            let d_c = cb - ca;
            let sd_s = (sda * sda + sdb * sdb).sqrt();
            let sd_c = (cda * cda + cdb * cdb).sqrt();
            let (sh_s, sh_c) = (share(d_s, ds), share(d_c, dc));
            DifferenceCause {
                cause: n.to_string(),
                share_of_sigma1_difference: sh_s,
                share_of_cr_rms_difference: sh_c,
                significant: (d_s != 0.0
                    && d_s.abs() > 1.96 * sd_s
                    && sh_s.abs() >= MATERIAL_SHARE)
                    || (d_c != 0.0 && d_c.abs() > 1.96 * sd_c && sh_c.abs() >= MATERIAL_SHARE),
            }
        })
        .collect();
    causes.sort_by(|x, y| {
        y.share_of_sigma1_difference
            .abs()
            .total_cmp(&x.share_of_sigma1_difference.abs())
            .then_with(|| x.cause.cmp(&y.cause))
    });
    let explained: f64 = causes.iter().map(|c| c.share_of_sigma1_difference).sum();
    Difference {
        runs: [a.name.clone(), b.name.clone()],
        sigma1_difference_nm: ds,
        cr_rms_difference: dc,
        unexplained_share_of_sigma1_difference: if ds != 0.0 { 1.0 - explained } else { 0.0 },
        causes,
    }
}

fn sigma1(s: &Surface, pitch_mm: f64) -> Result<f64, VibrationError> {
    ripple(s, pitch_mm, &PsdOptions::default())
        .map(|r| r.sigma1_nm)
        .map_err(|e| VibrationError::InvalidArgument(e.to_string()))
}

fn rms(s: &Surface, remove: &[Term]) -> Result<f64, VibrationError> {
    let (r, _) =
        remove_terms(s, remove).map_err(|e| VibrationError::InvalidArgument(e.to_string()))?;
    Ok(height_stats(&r)
        .map_err(|e| VibrationError::InvalidArgument(e.to_string()))?
        .rms_nm)
}

/// A cause's effect (σ1 in nm, CR(RMS) as a fraction) on a measured run: the cause added the
/// removal `added_removal_nm` (nm, the after map's grid); without it the after map would be
/// `after + added_removal_nm`. σ1 is the ripple at 1/`pitch_mm` along Y; RMS after removing
/// `remove` (compare's default: piston, tilt).
pub fn counterfactual_effect(
    before: &Surface,
    after: &Surface,
    added_removal_nm: &Array2<f64>,
    pitch_mm: f64,
    remove: &[Term],
) -> Result<(f64, f64), VibrationError> {
    if added_removal_nm.dim() != after.dim() {
        return Err(VibrationError::InvalidArgument(format!(
            "removal contribution is {:?}, the after map {:?}",
            added_removal_nm.dim(),
            after.dim()
        )));
    }
    let cf = after
        .with_heights(after.heights_nm() + added_removal_nm)
        .map_err(|e| VibrationError::InvalidArgument(e.to_string()))?;
    let rb = rms(before, remove)?;
    if rb <= 0.0 {
        return Err(VibrationError::InvalidArgument(
            "before map has zero RMS: no convergence ratio".into(),
        ));
    }
    let d_sigma = sigma1(after, pitch_mm)? - sigma1(&cf, pitch_mm)?;
    let d_cr = (rms(&cf, remove)? - rms(after, remove)?) / rb;
    Ok((d_sigma, d_cr))
}

/// The coupling mechanisms' effects on a measured run at its fitted forcing (rate scale
/// applied): for each mechanism, the counterfactual without that mechanism's removal. The SD
/// is half the spread of the effect between the ends of the 95 % interval of `fn_n` divided by
/// 1.96; when the forcing is not constrained the range is zero to the upper bound (or to the
/// searched maximum), so an unconstrained forcing cannot make a mechanism significant.
pub fn vibration_effects(
    model: &ForcingModel,
    fit: &ForcingFit,
    before: &Surface,
    after: &Surface,
    remove: &[Term],
) -> Result<Vec<CauseEffect>, VibrationError> {
    let pitch = model.pitch_mm.ok_or_else(|| {
        VibrationError::InvalidArgument("attribution needs the raster pitch".into())
    })?;
    let s = fit.noise_force_rms_n;
    let c = fit.rate_scale;
    let at = |f: f64| -> Result<Vec<(f64, f64)>, VibrationError> {
        let maps = model.maps(f, s);
        Mechanisms::NAMES
            .iter()
            .chain(std::iter::once(&"interaction"))
            .map(|n| {
                let m = maps.by_name(n).unwrap_or(&maps.interaction) * c;
                counterfactual_effect(before, after, &m, pitch, remove)
            })
            .collect()
    };
    let grid_max = *fit.fn_grid_n.last().unwrap_or(&fit.best_fn_n);
    let (lo, hi) = match (fit.forcing.interval_n, fit.forcing.upper_bound_n) {
        (Some([l, h]), _) => (l, h),
        // Not constrained: anything from zero to the bound (or the searched range) is allowed.
        (None, Some(u)) => (0.0, u),
        (None, None) => (0.0, grid_max),
    };
    let best = fit.forcing.fn_n.unwrap_or(fit.best_fn_n).clamp(lo, hi);
    let mid = at(best)?;
    let e_lo = at(lo)?;
    let e_hi = at(hi)?;
    Ok(Mechanisms::NAMES
        .iter()
        .chain(std::iter::once(&"interaction"))
        .enumerate()
        .map(|(k, n)| CauseEffect {
            cause: n.to_string(),
            sigma1_nm: mid[k].0,
            sigma1_sd_nm: (e_hi[k].0 - e_lo[k].0).abs() / (2.0 * 1.96),
            cr_rms: mid[k].1,
            cr_rms_sd: (e_hi[k].1 - e_lo[k].1).abs() / (2.0 * 1.96),
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eff(cause: &str, s: f64, c: f64) -> CauseEffect {
        CauseEffect {
            cause: cause.into(),
            sigma1_nm: s,
            sigma1_sd_nm: 0.01,
            cr_rms: c,
            cr_rms_sd: 0.001,
        }
    }

    #[test]
    fn shares_and_unexplained_add_to_one_sorted_by_magnitude() {
        let a = RunEffects {
            name: "original".into(),
            sigma1_nm: 7.0,
            cr_rms: 0.1,
            causes: vec![eff("normal_offset", 3.0, -0.05), eff("tif_scale", 0.0, 0.0)],
        };
        let b = RunEffects {
            name: "suppression".into(),
            sigma1_nm: 3.0,
            cr_rms: 0.16,
            causes: vec![
                eff("normal_offset", 0.5, -0.01),
                eff("rate_drift", -0.4, 0.0),
            ],
        };
        let d = attribute_difference(&a, &b);
        assert_eq!(d.sigma1_difference_nm, -4.0);
        assert_eq!(d.causes[0].cause, "normal_offset");
        assert!((d.causes[0].share_of_sigma1_difference - 0.625).abs() < 1e-12);
        assert!((d.causes[0].share_of_cr_rms_difference - 0.04 / 0.06).abs() < 1e-12);
        assert!(d.causes[0].significant);
        let tif = d.causes.iter().find(|c| c.cause == "tif_scale").unwrap();
        assert!(!tif.significant && tif.share_of_sigma1_difference == 0.0);
        let sum: f64 = d.causes.iter().map(|c| c.share_of_sigma1_difference).sum();
        assert!((sum + d.unexplained_share_of_sigma1_difference - 1.0).abs() < 1e-12);
        assert!((d.unexplained_share_of_sigma1_difference - (1.0 - 0.625 - 0.1)).abs() < 1e-12);
    }
}
