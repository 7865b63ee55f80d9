//! The effect library: one file per physical effect, each with its own model, detection
//! (linearised columns about the current state, with initial parameters from their
//! coefficients) and reporting. Selection (`selection`) decides which are accepted.
//!
//! Linearisations used (s0 = baseline rate scale, K the TIF, `K * D_g` the forward model's
//! removal of the executed path with rate weights g; see `model`):
//! - rate effects are exactly linear: column `K * D_g`;
//! - a path displacement e(t) of the executed spot: `K(x - p - e) ~ K - e . grad K`, column
//!   `-(dK/dx) * D_{e_x} - (dK/dy) * D_{e_y}` per unit displacement;
//! - TIF width: column `(dK/ds) * D`;
//! - registration: column `grad(after) . dT/dtheta` (see `registration`).
//!
//! `fallback` adds kinds no library entry names (rate per direction, per raster line, per time
//! window, a smooth rate map), built on the run's own structure and offered last.

pub mod direction_lag;
pub mod fallback;
pub mod path_offset;
pub mod periodic_path_error;
pub mod rate_covariate;
pub mod rate_drift;
pub mod rate_oscillation;
pub mod rate_profile;
pub mod rate_step;
pub mod registration;
pub mod tif_scale;

use ndarray::Array2;

use rayon::prelude::*;

use bonnetlab_process::removal::Fidelity;

use crate::model::{Channel, Effect, Eval, Problem};

/// A candidate effect: its linearised columns and how to turn their fitted coefficients into
/// the effect's initial state.
pub struct Candidate {
    pub key: String,
    pub kind: &'static str,
    pub extra: Vec<Vec<f64>>,
    /// (coefficients of `extra`, s0) -> effect.
    pub make: MakeEffect,
}

/// Builds an effect from the coefficients of a candidate's extra columns and s0.
pub type MakeEffect = Box<dyn Fn(&[f64], f64) -> Box<dyn Effect> + Send + Sync>;

/// Everything detection needs about the current state.
pub struct Current<'a> {
    pub p: &'a Problem,
    pub ev: &'a Eval,
    /// Current residual on the analysis pixels.
    pub resid: &'a [f64],
    pub accepted: &'a [Box<dyn Effect>],
    /// Matched filters already computed for this state (see [`Self::matched`]).
    pub matched_cache: MatchedCache,
}

/// Matched filters of one state by channel: several kinds ask for the same one in a round
/// (the rate channel's by the oscillation, the step and the fallback). Never waited on: two
/// callers that miss at once both compute it (a caller waiting for another could be the thread
/// that other one's parallel transform is waiting for).
#[derive(Default)]
pub struct MatchedCache(std::sync::Mutex<Vec<(Channel, std::sync::Arc<Vec<f64>>)>>);

impl Current<'_> {
    pub fn has(&self, key: &str) -> bool {
        self.accepted.iter().any(|e| e.key() == key)
    }

    /// Residual as a full map (0 off the aperture).
    pub fn resid_map(&self) -> Array2<f64> {
        self.p.expand(self.resid, &self.ev.w).0
    }

    /// Matched filter of the residual along the path: `h_k = dt_k * sum_x r(x) K'(x - p_k)`, the
    /// residual's projection on a unit rate (or displacement) impulse at sample k for the
    /// forward model's channel `ch` (K' = the TIF or one of its derivatives). A channel that
    /// cannot be evaluated gives zeros (no candidate can come of it).
    pub fn matched(&self, ch: Channel) -> Vec<f64> {
        let known = |c: &MatchedCache| {
            let v = c.0.lock().ok()?;
            v.iter().find(|(k, _)| *k == ch).map(|(_, h)| h.clone())
        };
        if let Some(h) = known(&self.matched_cache) {
            return h.as_ref().clone();
        }
        let h = self.matched_uncached(ch);
        if let Ok(mut v) = self.matched_cache.0.lock() {
            if !v.iter().any(|(k, _)| *k == ch) {
                v.push((ch, std::sync::Arc::new(h.clone())));
            }
        }
        h
    }

    fn matched_uncached(&self, ch: Channel) -> Vec<f64> {
        let r = self.resid_map();
        let h = self.ev.kernels.matched(ch, &r, &self.ev.exec).ok();
        match h {
            Some(h) => h
                .iter()
                .zip(&self.p.samples.dt_s)
                .map(|(v, dt)| v * dt)
                .collect(),
            None => vec![0.0; self.p.samples.len()],
        }
    }

    /// Column `sum_m R_{ch_m}(exec, g_m)` (the forward model through channel `ch_m` of the
    /// executed path with rate weights `g_m`), on the analysis pixels; zeros when a channel
    /// cannot be evaluated (no candidate can come of it). At screening fidelity: a candidate's
    /// columns only score it and start its fit, which the full model then refines.
    pub fn column(&self, terms: &[(&[f64], Channel)]) -> Vec<f64> {
        let t: Vec<(Channel, Option<&[f64]>)> =
            terms.iter().map(|(g, ch)| (*ch, Some(*g))).collect();
        self.p
            .column_at(Fidelity::Screening, &self.ev.kernels, &self.ev.exec, &t)
            .unwrap_or_else(|_| vec![0.0; self.p.idx.len()])
    }

    /// Column of the rate term `g` centred on its dwell mean, at screening fidelity (see
    /// [`Problem::rate_term_column`]); zeros when it cannot be evaluated.
    pub fn rate_term_column(&self, g: &[f64]) -> Vec<f64> {
        self.p
            .rate_term_column(Fidelity::Screening, &self.ev.kernels, &self.ev.exec, g)
            .map(|(c, _)| c)
            .unwrap_or_else(|_| vec![0.0; self.p.idx.len()])
    }

    /// Column of the plain executed path through channel `ch` (no rate weights).
    pub fn plain_column(&self, ch: Channel) -> Vec<f64> {
        self.p
            .column_at(
                Fidelity::Screening,
                &self.ev.kernels,
                &self.ev.exec,
                &[(ch, None)],
            )
            .unwrap_or_else(|_| vec![0.0; self.p.idx.len()])
    }

    /// Baseline column's coefficient scale (for turning column coefficients into parameters).
    pub fn s0(&self) -> f64 {
        1.0
    }
}

/// Periods with the most power in `h` as a function of coordinate `q` (binned on a uniform
/// grid, zero-padded x4, periodogram), between `p_min` and `p_max` (units of q), local maxima
/// only, refined by parabolic interpolation of the log power. Returns up to `n` (period, power).
pub fn spectral_peaks(q: &[f64], h: &[f64], p_min: f64, p_max: f64, n: usize) -> Vec<(f64, f64)> {
    if q.is_empty() || p_min.is_nan() || p_min <= 0.0 || p_max <= p_min {
        return Vec::new();
    }
    let (lo, hi) = q.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
        (a.0.min(v), a.1.max(v))
    });
    let bin = p_min / 4.0;
    let nb = (((hi - lo) / bin).ceil() as usize + 1).min(1 << 20);
    if nb < 8 {
        return Vec::new();
    }
    let mut binned = vec![0.0; nb];
    for (&qk, &hk) in q.iter().zip(h) {
        let b = (((qk - lo) / bin) as usize).min(nb - 1);
        binned[b] += hk;
    }
    let nfft = bonnetlab_process::fft::fast_len(4 * nb);
    let fft = bonnetlab_process::fft::real_forward(nfft);
    let mut input = vec![0.0; nfft];
    input[..nb].copy_from_slice(&binned);
    let mut out = fft.make_output_vec();
    if fft.process(&mut input, &mut out).is_err() {
        return Vec::new();
    }
    let pw: Vec<f64> = out.iter().map(|c| c.norm_sqr()).collect();
    let df = 1.0 / (nfft as f64 * bin);
    let kmin = ((1.0 / p_max) / df).ceil().max(2.0) as usize;
    let kmax = (((1.0 / p_min) / df).floor() as usize).min(pw.len().saturating_sub(2));
    let mut peaks = Vec::new();
    for k in kmin.max(1)..=kmax {
        if pw[k] > pw[k - 1] && pw[k] >= pw[k + 1] {
            let (a, b, c) = (
                pw[k - 1].max(1e-300).ln(),
                pw[k].max(1e-300).ln(),
                pw[k + 1].max(1e-300).ln(),
            );
            let den = a - 2.0 * b + c;
            let d = if den.abs() > 1e-300 {
                (0.5 * (a - c) / den).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            peaks.push(((k as f64 + d) * df, pw[k]));
        }
    }
    peaks.sort_by(|x, y| y.1.total_cmp(&x.1));
    // Keep well-separated peaks (zero-padding makes side lobes 4 bins apart).
    let mut kept: Vec<(f64, f64)> = Vec::new();
    for (f, pwr) in peaks {
        if kept.iter().all(|(g, _)| (f - g).abs() > 6.0 * df) {
            kept.push((f, pwr));
        }
        if kept.len() >= n {
            break;
        }
    }
    kept.into_iter().map(|(f, pwr)| (1.0 / f, pwr)).collect()
}

/// A kind's candidate builder.
type KindCandidates = fn(&Current) -> Vec<Candidate>;

/// All candidates of the library for the current state; the kinds no library entry names
/// ([`fallback`]) last.
pub fn candidates(cur: &Current) -> Vec<Candidate> {
    let kinds: [(&str, KindCandidates); 11] = [
        ("registration", registration::candidates),
        ("rate_drift", rate_drift::candidates),
        ("tif_scale", tif_scale::candidates),
        ("direction_lag", direction_lag::candidates),
        ("path_offset", path_offset::candidates),
        ("periodic_path_error", periodic_path_error::candidates),
        ("rate_covariate", rate_covariate::candidates),
        ("rate_oscillation", rate_oscillation::candidates),
        ("rate_step", rate_step::candidates),
        ("rate_profile", rate_profile::candidates),
        // Last: kinds no library entry names, offered only past a stricter held-out bar.
        ("fallback", fallback::candidates),
    ];
    let trace = std::env::var_os("BONNETLAB_TRACE").is_some();
    // The kinds side by side (each column takes an idle forward-model workspace of its
    // channel or builds one: see `Channels`), collected in the order above.
    kinds
        .par_iter()
        .map(|(name, make)| {
            let t0 = std::time::Instant::now();
            let v = make(cur);
            if trace {
                eprintln!("  candidates {name}: {:?}", t0.elapsed());
            }
            v
        })
        .collect::<Vec<_>>()
        .into_iter()
        .flatten()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_period_of_a_sampled_sine() {
        let q: Vec<f64> = (0..5000).map(|k| k as f64 * 0.37).collect();
        let h: Vec<f64> = q
            .iter()
            .map(|x| (2.0 * std::f64::consts::PI * x / 23.0).sin())
            .collect();
        let p = spectral_peaks(&q, &h, 2.0, 500.0, 2);
        assert!((p[0].0 - 23.0).abs() < 0.1, "{:?}", p);
    }
}
