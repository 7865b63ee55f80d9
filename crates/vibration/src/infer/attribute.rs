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
//! the causes, noise, and whatever no cause models (the same for CR(RMS)).
//!
//! Significance, for σ1 and for CR(RMS) separately (`significant_sigma1`,
//! `significant_cr_rms`; `significant` is either). A cause is significant for a quantity when
//! all of these hold:
//! - the difference itself stands beyond the maps' white noise: |B − A| > 1.96 times its SD
//!   ([`RunEffects::sigma1_noise_sd_nm`], [`RunEffects::cr_rms_noise_sd`] of both runs in
//!   quadrature; [`NoiseDraws`]). A difference the noise could make has no shares to name;
//! - the cause's effect difference exceeds 1.96 times its SD (the two runs' SDs in quadrature:
//!   the model's uncertainty and the maps' noise, [`CauseEffect`]);
//! - it exceeds the attribution's own remainder, |B − A − Σ effect differences|: the causes do
//!   not add exactly, and a part smaller than what they leave over is within that error;
//! - its share is at least [`MATERIAL_SHARE`] (a precisely known but negligible part of the
//!   difference is not reported as significant).
//!
//! None of this knows the run-to-run scatter of the process: only repeat runs measure it.
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
    /// SD of `sigma1_nm` (nm): the model's uncertainty and, when measured, the maps' white
    /// noise ([`NoiseDraws::effect_sd`]) in quadrature.
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
    /// SD of `sigma1_nm` (nm) from the maps' white noise ([`NoiseDraws::value_sd`]; 0: not
    /// measured).
    pub sigma1_noise_sd_nm: f64,
    /// SD of `cr_rms` from the maps' white noise (0: not measured).
    pub cr_rms_noise_sd: f64,
    pub causes: Vec<CauseEffect>,
}

/// One entry of `difference.causes` (shared/spec/interfaces.md, compare).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DifferenceCause {
    pub cause: String,
    pub share_of_sigma1_difference: f64,
    pub share_of_cr_rms_difference: f64,
    /// `significant_sigma1 || significant_cr_rms` (module docs).
    pub significant: bool,
    pub significant_sigma1: bool,
    pub significant_cr_rms: bool,
}

/// The `difference` object of `compare`'s JSON for one pair (A = first run, B = other).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Difference {
    pub runs: [String; 2],
    /// σ1_B − σ1_A, nm.
    pub sigma1_difference_nm: f64,
    /// Its SD from the two runs' white map noise (nm; 0: not measured).
    pub sigma1_difference_sd_nm: f64,
    /// CR_B − CR_A (RMS), fraction.
    pub cr_rms_difference: f64,
    /// Its SD from the two runs' white map noise (0: not measured).
    pub cr_rms_difference_sd: f64,
    /// |σ1 difference| > 1.96 x its SD: beyond the maps' white noise (not the process's
    /// run-to-run scatter, which only repeats measure).
    pub sigma1_difference_beyond_noise: bool,
    pub cr_rms_difference_beyond_noise: bool,
    pub causes: Vec<DifferenceCause>,
    pub unexplained_share_of_sigma1_difference: f64,
    pub unexplained_share_of_cr_rms_difference: f64,
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
    // Per cause: (difference, SD) for σ1 and CR.
    let diffs: Vec<(f64, f64, f64, f64)> = names
        .iter()
        .map(|&n| {
            let (sa, sda, ca, cda) = find(a, n);
            let (sb, sdb, cb, cdb) = find(b, n);
            (sb - sa, sda.hypot(sdb), cb - ca, cda.hypot(cdb))
        })
        .collect();
    let ds_sd = a.sigma1_noise_sd_nm.hypot(b.sigma1_noise_sd_nm);
    let dc_sd = a.cr_rms_noise_sd.hypot(b.cr_rms_noise_sd);
    let real_s = ds != 0.0 && ds.abs() > 1.96 * ds_sd;
    let real_c = dc != 0.0 && dc.abs() > 1.96 * dc_sd;
    let rest_s = (ds - diffs.iter().map(|d| d.0).sum::<f64>()).abs();
    let rest_c = (dc - diffs.iter().map(|d| d.2).sum::<f64>()).abs();
    let sig = |real: bool, d: f64, sd: f64, rest: f64, sh: f64| {
        real && d != 0.0 && d.abs() > 1.96 * sd && d.abs() > rest && sh.abs() >= MATERIAL_SHARE
    };
    let mut causes: Vec<DifferenceCause> = names
        .iter()
        .zip(&diffs)
        .map(|(&n, &(d_s, sd_s, d_c, sd_c))| {
            let (sh_s, sh_c) = (share(d_s, ds), share(d_c, dc));
            let significant_sigma1 = sig(real_s, d_s, sd_s, rest_s, sh_s);
            let significant_cr_rms = sig(real_c, d_c, sd_c, rest_c, sh_c);
            DifferenceCause {
                cause: n.to_string(),
                share_of_sigma1_difference: sh_s,
                share_of_cr_rms_difference: sh_c,
                significant: significant_sigma1 || significant_cr_rms,
                significant_sigma1,
                significant_cr_rms,
            }
        })
        .collect();
    causes.sort_by(|x, y| {
        y.share_of_sigma1_difference
            .abs()
            .total_cmp(&x.share_of_sigma1_difference.abs())
            .then_with(|| x.cause.cmp(&y.cause))
    });
    let explained_s: f64 = causes.iter().map(|c| c.share_of_sigma1_difference).sum();
    let explained_c: f64 = causes.iter().map(|c| c.share_of_cr_rms_difference).sum();
    Difference {
        runs: [a.name.clone(), b.name.clone()],
        sigma1_difference_nm: ds,
        sigma1_difference_sd_nm: ds_sd,
        cr_rms_difference: dc,
        cr_rms_difference_sd: dc_sd,
        sigma1_difference_beyond_noise: real_s,
        cr_rms_difference_beyond_noise: real_c,
        unexplained_share_of_sigma1_difference: if ds != 0.0 { 1.0 - explained_s } else { 0.0 },
        unexplained_share_of_cr_rms_difference: if dc != 0.0 { 1.0 - explained_c } else { 0.0 },
        causes,
    }
}

/// Seeded re-draws of a run's white measurement noise, to give the SD the maps' noise puts on
/// σ1, CR(RMS) and each cause's counterfactual effect (a parametric bootstrap): each draw adds
/// fresh white noise of the maps' level to the before and the after map, and a statistic's
/// spread over the draws is the spread its own noise gives it (to first order in the noise).
#[derive(Debug, Clone)]
pub struct NoiseDraws {
    before: Surface,
    after: Surface,
    pairs: Vec<(Surface, Surface)>,
    pitch_mm: f64,
    remove: Vec<Term>,
}

impl NoiseDraws {
    /// `draws` pairs with white noise of `sigma_map_nm` (nm RMS per map) on both maps, from a
    /// fixed `seed` (deterministic). `sigma_map_nm` <= 0 or `draws` < 2 give no draws (SDs 0).
    pub fn new(
        before: &Surface,
        after: &Surface,
        sigma_map_nm: f64,
        draws: usize,
        seed: u64,
        pitch_mm: f64,
        remove: &[Term],
    ) -> Result<NoiseDraws, VibrationError> {
        let mut pairs = Vec::new();
        if sigma_map_nm.is_finite() && sigma_map_nm > 0.0 && draws >= 2 {
            let mut rng = bonnetlab_surface::rng::Rng::new(seed);
            let mut noisy = |s: &Surface| {
                let z = s.heights_nm().mapv(|v| v + sigma_map_nm * rng.normal());
                s.with_heights(z)
                    .map_err(|e| VibrationError::InvalidArgument(e.to_string()))
            };
            for _ in 0..draws {
                let b = noisy(before)?;
                let a = noisy(after)?;
                pairs.push((b, a));
            }
        }
        Ok(NoiseDraws {
            before: before.clone(),
            after: after.clone(),
            pairs,
            pitch_mm,
            remove: remove.to_vec(),
        })
    }

    /// SD over the draws of (σ1 of the after map (nm), CR(RMS)).
    pub fn value_sd(&self) -> Result<(f64, f64), VibrationError> {
        let mut s1 = Vec::with_capacity(self.pairs.len());
        let mut cr = Vec::with_capacity(self.pairs.len());
        for (b, a) in &self.pairs {
            s1.push(sigma1(a, self.pitch_mm)?);
            let rb = rms(b, &self.remove)?;
            cr.push(if rb > 0.0 {
                (rb - rms(a, &self.remove)?) / rb
            } else {
                0.0
            });
        }
        Ok((sd(&s1), sd(&cr)))
    }

    /// SD over the draws of a cause's counterfactual effect ([`counterfactual_effect`]) with
    /// the removal `added_removal_nm`: (σ1 nm, CR(RMS)).
    pub fn effect_sd(&self, added_removal_nm: &Array2<f64>) -> Result<(f64, f64), VibrationError> {
        let mut s1 = Vec::with_capacity(self.pairs.len());
        let mut cr = Vec::with_capacity(self.pairs.len());
        for (b, a) in &self.pairs {
            let (ds, dc) =
                counterfactual_effect(b, a, added_removal_nm, self.pitch_mm, &self.remove)?;
            s1.push(ds);
            cr.push(dc);
        }
        Ok((sd(&s1), sd(&cr)))
    }
}

impl NoiseDraws {
    /// The cause `name` that added `added_removal_nm` to the measured run: its counterfactual
    /// effect on the measured maps, with an SD of `rel` x |effect| (the cause's own relative
    /// uncertainty) and the maps' noise ([`Self::effect_sd`]) in quadrature.
    pub fn cause_effect(
        &self,
        name: &str,
        added_removal_nm: &Array2<f64>,
        rel: f64,
    ) -> Result<CauseEffect, VibrationError> {
        let (ds, dc) = counterfactual_effect(
            &self.before,
            &self.after,
            added_removal_nm,
            self.pitch_mm,
            &self.remove,
        )?;
        let (ns, nc) = self.effect_sd(added_removal_nm)?;
        Ok(CauseEffect {
            cause: name.to_string(),
            sigma1_nm: ds,
            sigma1_sd_nm: (ds.abs() * rel).hypot(ns),
            cr_rms: dc,
            cr_rms_sd: (dc.abs() * rel).hypot(nc),
        })
    }
}

/// Sample standard deviation (0 with fewer than two values).
fn sd(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0)).sqrt()
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
    vibration_effects_with_noise(model, fit, before, after, remove, None)
}

/// [`vibration_effects`], with each effect's SD also holding the maps' white noise (the spread
/// of its counterfactual over `noise`'s draws, at the fitted forcing) in quadrature.
pub fn vibration_effects_with_noise(
    model: &ForcingModel,
    fit: &ForcingFit,
    before: &Surface,
    after: &Surface,
    remove: &[Term],
    noise: Option<&NoiseDraws>,
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
    let noise_sd: Vec<(f64, f64)> = match noise {
        Some(d) => {
            let maps = model.maps(best, s);
            Mechanisms::NAMES
                .iter()
                .chain(std::iter::once(&"interaction"))
                .map(|n| d.effect_sd(&(maps.by_name(n).unwrap_or(&maps.interaction) * c)))
                .collect::<Result<_, _>>()?
        }
        None => vec![(0.0, 0.0); mid.len()],
    };
    Ok(Mechanisms::NAMES
        .iter()
        .chain(std::iter::once(&"interaction"))
        .enumerate()
        .map(|(k, n)| CauseEffect {
            cause: n.to_string(),
            sigma1_nm: mid[k].0,
            sigma1_sd_nm: ((e_hi[k].0 - e_lo[k].0).abs() / (2.0 * 1.96)).hypot(noise_sd[k].0),
            cr_rms: mid[k].1,
            cr_rms_sd: ((e_hi[k].1 - e_lo[k].1).abs() / (2.0 * 1.96)).hypot(noise_sd[k].1),
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
            sigma1_noise_sd_nm: 0.0,
            cr_rms_noise_sd: 0.0,
            causes: vec![eff("normal_offset", 3.0, -0.05), eff("tif_scale", 0.0, 0.0)],
        };
        let b = RunEffects {
            name: "suppression".into(),
            sigma1_nm: 3.0,
            cr_rms: 0.16,
            sigma1_noise_sd_nm: 0.0,
            cr_rms_noise_sd: 0.0,
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

    fn run(
        name: &str,
        sigma1: f64,
        cr: f64,
        noise: (f64, f64),
        causes: Vec<CauseEffect>,
    ) -> RunEffects {
        RunEffects {
            name: name.into(),
            sigma1_nm: sigma1,
            cr_rms: cr,
            sigma1_noise_sd_nm: noise.0,
            cr_rms_noise_sd: noise.1,
            causes,
        }
    }

    /// A difference the maps' white noise could make has no significant cause, however well
    /// each cause's own effect is known; the same causes with quiet maps are significant.
    #[test]
    fn a_difference_within_the_noise_names_no_significant_cause() {
        let causes_a = vec![eff("normal_offset", 3.0, -0.05)];
        let causes_b = vec![eff("normal_offset", 2.8, -0.045)];
        // sigma1 differs by 0.2 nm, CR by 0.005; noise SDs 0.1 nm and 0.002 per run: the
        // differences are 1.41 and 1.77 of their SDs, under 1.96.
        let a = run("a", 7.0, 0.1, (0.1, 0.002), causes_a.clone());
        let b = run("b", 6.8, 0.105, (0.1, 0.002), causes_b.clone());
        let d = attribute_difference(&a, &b);
        assert!(!d.sigma1_difference_beyond_noise && !d.cr_rms_difference_beyond_noise);
        assert!((d.sigma1_difference_sd_nm - 0.1 * 2f64.sqrt()).abs() < 1e-12);
        assert!(d.causes.iter().all(|c| !c.significant), "{d:?}");
        let quiet = attribute_difference(
            &run("a", 7.0, 0.1, (0.01, 0.0002), causes_a),
            &run("b", 6.8, 0.105, (0.01, 0.0002), causes_b),
        );
        assert!(quiet.sigma1_difference_beyond_noise);
        assert!(quiet.causes[0].significant_sigma1 && quiet.causes[0].significant_cr_rms);
    }

    /// A cause whose effect difference is smaller than what the causes leave over (they do not
    /// add exactly) is not significant, even with a tiny SD and a share above 5 %; the CR
    /// column's remainder is reported as the sigma1 one is.
    #[test]
    fn a_cause_under_the_attribution_remainder_is_not_significant() {
        let tight = |n: &str, c: f64| CauseEffect {
            cr_rms_sd: 0.0001,
            ..eff(n, 0.0, c)
        };
        let mut small_a = eff("dwell_execution", 0.0, 0.001);
        small_a.cr_rms_sd = 0.0;
        let mut small_b = eff("dwell_execution", 0.0, 0.0011);
        small_b.cr_rms_sd = 0.0;
        let a = run(
            "a",
            7.0,
            0.100,
            (0.0, 0.0),
            vec![tight("path_offset", 0.0), small_a],
        );
        let b = run(
            "b",
            7.0,
            0.102,
            (0.0, 0.0),
            vec![tight("path_offset", 0.0015), small_b],
        );
        let d = attribute_difference(&a, &b);
        let c = d
            .causes
            .iter()
            .find(|c| c.cause == "dwell_execution")
            .unwrap();
        // Share 5 % of the CR difference, remainder 0.0004 > its 0.0001.
        assert!((c.share_of_cr_rms_difference - 0.05).abs() < 1e-9);
        assert!(!c.significant_cr_rms, "{d:?}");
        let p = d.causes.iter().find(|c| c.cause == "path_offset").unwrap();
        assert!(p.significant_cr_rms && p.significant);
        assert!(
            (d.unexplained_share_of_cr_rms_difference - 0.2).abs() < 1e-9,
            "{d:?}"
        );
    }
}
