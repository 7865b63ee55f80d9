//! `tif_scale`: the working spot is the measured one widened by `scale` (`T_s(r) = T(r / s)`;
//! its peak rate is left to the global rate fit). Linearised column `(dK/ds) * D`.

use rayon::prelude::*;

use crate::effects::{Candidate, Current};
use crate::model::{
    evaluate, fit, fit_columns, Channel, Effect, Linear, Param, Problem, MAX_SCALE,
};

#[derive(Debug, Clone)]
pub struct TifScale {
    pub scale: f64,
}

impl Effect for TifScale {
    fn kind(&self) -> &'static str {
        "tif_scale"
    }
    fn key(&self) -> String {
        "tif_scale".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.scale]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.scale = v[0].clamp(0.5, MAX_SCALE);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.004]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn scale(&self) -> f64 {
        self.scale
    }
    fn implausible(&self, _p: &Problem, _lin: &Linear) -> Option<String> {
        (self.scale <= 0.5 || self.scale >= MAX_SCALE).then(|| {
            format!(
                "scale {:.3} is at the bound of the kernel frame [0.5, {MAX_SCALE}]",
                self.scale
            )
        })
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        vec![("scale".into(), Param::Num(self.scale))]
    }
}

/// Widening factors scanned before the linearised start (see [`candidates`]).
const SCAN: (f64, f64, f64) = (0.7, 1.45, 0.05);

/// Least in-sample reduction of the residual sum of squares by the derivative column, as a
/// fraction of it, for the scan to run. A fifth of the selection's `MIN_FRACTION`: pure noise
/// gives about 1 / (analysis pixels) (a few 1e-5), and a widening the selection could accept
/// (a held-out reduction of at least MIN_FRACTION) projects well above this on its own
/// derivative.
const SCAN_GATE: f64 = 0.2 * crate::selection::MIN_FRACTION;

/// Profiled residual sum of squares with the accepted effects and a widening `t`.
fn profiled_rss(cur: &Current, t: f64) -> Option<(f64, Vec<f64>)> {
    let mut e: Vec<Box<dyn Effect>> = cur.accepted.to_vec();
    e.push(Box::new(TifScale { scale: t }));
    let ev = evaluate(cur.p, &e, None).ok()?;
    let f = fit(&ev, &[]).ok()?;
    Some((f.rss, ev.cols[0].clone()))
}

/// The linearised candidate: the derivative column `(dK/ds) * D` at the current scale. The
/// selection may replace it by [`scanned`] (see there) before it picks the round's contenders.
pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("tif_scale") {
        return Vec::new();
    }
    vec![derivative_candidate(
        cur.plain_column(Channel::Ds),
        cur.ev.scale,
    )]
}

/// The candidate from a scan of the scale. The profiled residual is not convex in the scale:
/// on a raster the line-spacing ripple of the removal follows the spot's transfer function at
/// 1/pitch, which oscillates with the width, so the residual has local minima about 0.1 apart
/// in scale (on independent runs with the paper's bonnet at a 2 mm pitch the linearised start
/// and the refinement from it settled at 0.95-0.96 for true scales 0.8, 1.1 and 1.2). So the
/// scale is scanned (0.7 to 1.45 by 0.05, then 0.025 either side of the best), and the column
/// is the secant `R(t*) - R(1)` to the best scan point `t*`, whose coefficient interpolates
/// the scale between 1 and `t*`. None when the derivative column takes less than
/// [`SCAN_GATE`] of the residual sum of squares (no widening is worth the scan) or no scan
/// point fits better than the current scale.
pub fn scanned(cur: &Current) -> Option<Candidate> {
    if cur.has("tif_scale") {
        return None;
    }
    let s = cur.ev.scale;
    let base_rss = cur
        .resid
        .iter()
        .zip(&cur.ev.w)
        .map(|(r, w)| w * r * r)
        .sum::<f64>();
    let col = cur.plain_column(Channel::Ds);
    let lin_gain = fit(cur.ev, std::slice::from_ref(&col))
        .map(|f| base_rss - f.rss)
        .unwrap_or(0.0);
    if std::env::var_os("BONNETLAB_TRACE").is_some() {
        eprintln!(
            "tif_scale: derivative column takes {:.2e} of the residual (scan above {:.0e})",
            lin_gain / base_rss.max(1e-300),
            SCAN_GATE
        );
    }
    if lin_gain < SCAN_GATE * base_rss {
        return None;
    }
    let started = std::time::Instant::now();
    let (lo, hi, step) = SCAN;
    let n = ((hi - lo) / step).round() as usize;
    // Where the scan cannot be set up (its transformed dwell over the memory budget: many
    // accepted rate terms on a large map), each scale is evaluated in full.
    let scan = ScanResiduals::new(cur, (hi + 0.5 * step) * s);
    let rss_at = |t: f64| match &scan {
        Some(sc) => sc.rss(t * s),
        None => profiled_rss(cur, t).map(|(rss, _)| rss),
    };
    let mut best: Option<(f64, f64)> = None;
    // The scales of a pass are evaluated side by side and taken in the order given, so the
    // best is the one the sequential scan would keep.
    let consider = |ts: &[f64], best: &mut Option<(f64, f64)>| {
        let got: Vec<Option<f64>> = ts
            .par_iter()
            .map(|&t| {
                if (t - 1.0).abs() < 1e-9 || t * s < 0.5 || t * s > MAX_SCALE {
                    return None;
                }
                rss_at(t)
            })
            .collect();
        for (&t, g) in ts.iter().zip(got) {
            if let Some(rss) = g {
                if rss < base_rss && best.as_ref().is_none_or(|b| rss < b.1) {
                    *best = Some((t, rss));
                }
            }
        }
    };
    let grid: Vec<f64> = (0..=n).map(|k| lo + k as f64 * step).collect();
    consider(&grid, &mut best);
    if let Some(t0) = best.as_ref().map(|b| b.0) {
        consider(&[t0 - 0.5 * step, t0 + 0.5 * step], &mut best);
    }
    // The best scale in full (the secant's column is the model's own at that scale).
    let best = best.and_then(|(t, _)| {
        let (rss, col) = profiled_rss(cur, t)?;
        (rss < base_rss).then_some((t, rss, col))
    });
    if std::env::var_os("BONNETLAB_TRACE").is_some() {
        eprintln!(
            "tif_scale: scanned in {:?}, best scale {:?}",
            started.elapsed(),
            best.as_ref().map(|b| b.0)
        );
    }
    let (t, _, col) = best?;
    let secant: Vec<f64> = col
        .iter()
        .zip(&cur.ev.cols[0])
        .map(|(a, b)| a - b)
        .collect();
    Some(Candidate {
        key: "tif_scale".into(),
        kind: "tif_scale",
        extra: vec![secant],
        make: Box::new(move |c, s0| {
            Box::new(TifScale {
                scale: (1.0 + (t - 1.0) * c[0] / s0).clamp(0.5, MAX_SCALE),
            })
        }),
    })
}

/// The profiled residual sum of squares of the current model at other TIF scales, from one
/// [`bonnetlab_process::channels::ScaleScan`] of its value-channel terms (the baseline and the
/// accepted rate terms, centred on their dwell means as `evaluate` centres them): their dwell
/// is walked, splatted and transformed once, and each scale costs its kernels and an inverse
/// transform per term. Equal to [`profiled_rss`] up to rounding (test
/// `scan_residuals_are_the_full_models`).
struct ScanResiduals<'a> {
    cur: &'a Current<'a>,
    scan: bonnetlab_process::channels::ScaleScan,
    nuisance: Vec<&'a [f64]>,
}

impl<'a> ScanResiduals<'a> {
    /// For scales up to `max_scale`; `None` when the scan cannot be set up.
    fn new(cur: &'a Current<'a>, max_scale: f64) -> Option<Self> {
        let p = cur.p;
        let exec = &cur.ev.exec;
        let centred: Vec<Vec<f64>> = cur
            .accepted
            .iter()
            .flat_map(|e| e.rate_terms(p))
            .map(|(_, g)| p.samples.centred(&g))
            .collect();
        let terms: Vec<(&crate::path::PathLog, Option<&[f64]>)> = std::iter::once((exec, None))
            .chain(centred.iter().map(|g| (exec, Some(g.as_slice()))))
            .collect();
        let nuisance = cur
            .ev
            .names
            .iter()
            .zip(&cur.ev.cols)
            .filter(|(n, _)| n.starts_with("nuisance"))
            .map(|(_, c)| c.as_slice())
            .collect();
        let scan = p.scale_scan(max_scale, &terms).ok()?;
        Some(ScanResiduals {
            cur,
            scan,
            nuisance,
        })
    }

    /// The residual sum of squares with the TIF widened by `scale` (absolute).
    fn rss(&self, scale: f64) -> Option<f64> {
        let (p, ev) = (self.cur.p, self.cur.ev);
        let maps = self.scan.removals(scale).ok()?;
        let cols: Vec<Vec<f64>> = maps.iter().map(|m| p.compress(m)).collect();
        let all: Vec<&[f64]> = cols
            .iter()
            .map(|c| c.as_slice())
            .chain(self.nuisance.iter().copied())
            .collect();
        fit_columns(&all, &ev.m, &ev.w).ok().map(|f| f.rss)
    }
}

/// The linearised candidate: the derivative column `(dK/ds) * D` at the current scale `s`.
fn derivative_candidate(col: Vec<f64>, s: f64) -> Candidate {
    Candidate {
        key: "tif_scale".into(),
        kind: "tif_scale",
        extra: vec![col],
        make: Box::new(move |c, s0| {
            Box::new(TifScale {
                scale: (s + c[0] / s0).clamp(0.5, MAX_SCALE),
            })
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::rate_drift::RateDrift;
    use crate::synth::{generate, Injected, SynthConfig};

    /// The scan's residuals are the full model's (`profiled_rss`: a channel set and a forward
    /// model per scale) to rounding, with the baseline alone and with an accepted rate term
    /// (a drift, whose column is centred), on a run whose working spot is 12 % wider.
    #[test]
    fn scan_residuals_are_the_full_models() {
        let run = generate(&SynthConfig {
            effects: vec![Injected::TifScale { scale: 1.12 }],
            ..SynthConfig::default()
        })
        .unwrap();
        let p = run.problem().unwrap();
        for accepted in [vec![], vec![Box::new(RateDrift) as Box<dyn Effect>]] {
            let ev = evaluate(&p, &accepted, None).unwrap();
            let f = fit(&ev, &[]).unwrap();
            let cur = Current {
                p: &p,
                ev: &ev,
                resid: &f.resid,
                accepted: &accepted,
                matched_cache: Default::default(),
            };
            let scan = ScanResiduals::new(&cur, 1.475).unwrap();
            let mut rss = Vec::new();
            for t in [0.75, 1.1, 1.12, 1.4] {
                let (want, _) = profiled_rss(&cur, t).unwrap();
                let got = scan.rss(t).unwrap();
                assert!(
                    (got - want).abs() <= 1e-9 * want,
                    "{} accepted, scale {t}: {got} vs {want}",
                    accepted.len()
                );
                rss.push(want);
            }
            // The scale the run was made with fits better than the others scanned here.
            assert!(rss[2] < rss[0] && rss[2] < rss[3], "{rss:?}");
        }
    }
}
