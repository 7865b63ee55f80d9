//! The forcing fitted to a measured removal map through its one-sided X and Y PSDs.
//!
//! Model of the measured one-sided PSD along each axis a (nm² mm):
//! `P_a(f) = c² · PSD_a[R(F, S)](f) + m² · W_a`, where R(F, S) is the coupling's predicted removal
//! at spindle-harmonic amplitude F and broadband force RMS S ([`super::ForcingModel`]), c a free
//! removal-rate scale (the Preston rate is calibrated elsewhere; the forcing is read from the
//! *shape* of the spectrum: the imprint along the scan at excitation_hz / feed and its harmonics,
//! the rectified change of the raster ripple at 1/pitch, the broadband envelope), and W_a the
//! flat PSD level of unit white measurement noise on the run's mask (m = noise RMS, nm). All PSDs
//! are bonnetlab_spectrum's `psd_x` / `psd_y` with default options (Hann, piston and tilt removed),
//! over the unbiased bins up to Nyquist.
//!
//! Because the PSD machinery is linear in the map up to the squared transform, `PSD[Σ w_k C_k]` is
//! the quadratic form `Σ_kl w_k w_l Q_kl`; Q is built once by polarisation
//! (`Q_kl = (PSD[C_k + C_l] − PSD[C_k] − PSD[C_l]) / 2`) from the crate's own PSD.
//!
//! Bins: the spindle forcing is read where it has its own signature, the imprint band along the
//! scan (X bins where the PSD of the removal's linear response to F is within 20 dB of its
//! peak) with a flank on each side as wide as the band; c² is fixed on the bins where the
//! commanded path's removal is within 20 dB of its peak (both axes: part-scale figure, raster
//! ripple), m² (a flat local background: measurement noise, texture, path errors the model does
//! not have) on the band and flanks. Unmodelled broadband content therefore moves m², not F.
//! (Over every bin with a free c, the exact-deposition original sample run read 1.9 N clean and
//! 6.9 N with its servo lag, truth 5 N: tests/forcing_truth.rs.) The broadband force S has no
//! band: its profile (and interval) is from every unbiased bin of both axes with free c² and m².
//! Without an imprint band (harmonics beyond Nyquist) every bin is fitted with free c² and m².
//!
//! Fit: least squares in ln P. For each (F, S) on a grid, (c², m²) ≥ 0
//! come from iteratively reweighted linear fits; the SSR is turned into χ² with the residual
//! variance s² = SSR_min / (N − 4) and the window's ENBW (neighbouring bins are correlated:
//! χ² = SSR / (s² · ENBW)). Intervals are profile-likelihood intervals: **95 %** two-sided
//! (Δχ² = 3.84, one parameter); an upper bound is one-sided 95 % (Δχ² = 2.71). The forcing is
//! `constrained` when both ends of the 95 % interval are inside the searched range and the lower
//! end is above zero; otherwise the fit reports an upper bound (or none) and says why.

use super::{monomials, ForcingModel, N_MONO};
use crate::error::VibrationError;
use crate::params::{Bonnet, VibrationParams};
use crate::response::harmonic_phasors;
use bonnetlab_spectrum::{psd_xy, Psd1d, PsdOptions};
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use ndarray::Array2;
use serde::Serialize;
use std::f64::consts::PI;

/// Δχ² of a two-sided 95 % interval of one parameter.
pub const DCHI2_95: f64 = 3.841_458_820_694_124;
/// Δχ² of a one-sided 95 % upper bound of one parameter.
pub const DCHI2_95_ONE_SIDED: f64 = 2.705_543_454_095_404;

/// Width of the spindle-harmonic imprint band below the imprint's peak PSD, dB.
pub const IMPRINT_BAND_DB: f64 = 20.0;
/// Rate-scale bins: where the commanded path's removal PSD is within this of its peak, dB.
pub const SCALE_BINS_DB: f64 = 20.0;
/// Least width of each flank of the imprint band, bins.
pub const MIN_FLANK_BINS: usize = 4;

/// Search ranges of the forcing fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InferOptions {
    /// Spindle-harmonic amplitude searched over [0, fn_max_n] N in `fn_steps` equal steps.
    pub fn_max_n: f64,
    pub fn_steps: usize,
    /// Broadband force RMS searched over [0, noise_max_n] N in `noise_steps` equal steps.
    pub noise_max_n: f64,
    pub noise_steps: usize,
    /// Frequency band of the fit, cycles/mm (clipped to each axis' unbiased bins and Nyquist).
    pub band_per_mm: (f64, f64),
}

impl Default for InferOptions {
    fn default() -> Self {
        InferOptions {
            fn_max_n: 20.0,
            fn_steps: 160,
            noise_max_n: 5.0,
            noise_steps: 20,
            band_per_mm: (0.0, f64::INFINITY),
        }
    }
}

/// The `vibration_forcing` object of `compare`'s JSON (shared/spec/interfaces.md).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VibrationForcing {
    /// Fitted spindle-harmonic normal-force amplitude, N (None when not constrained).
    pub fn_n: Option<f64>,
    /// Two-sided 95 % profile-likelihood interval of `fn_n`, N.
    pub interval_n: Option<[f64; 2]>,
    /// One-sided 95 % upper bound, N (when the data cannot exclude zero forcing).
    pub upper_bound_n: Option<f64>,
    /// End-of-robot amplitude implied by `fn_n` (or by `upper_bound_n` when not constrained):
    /// semi-major axis of the holder's in-plane displacement ellipse at the spindle
    /// fundamental, mm.
    pub end_amplitude_mm: Option<f64>,
    pub constrained: bool,
    pub reason: String,
}

/// The quadratic-form PSD model of one run on its measured mask.
#[derive(Debug, Clone)]
pub struct SpectralModel {
    /// Per axis (X then Y): bin frequencies, Q matrices (row-major N_MONO²) and the white level.
    axes: [AxisModel; 2],
    enbw_bins: f64,
}

#[derive(Debug, Clone)]
struct AxisModel {
    freq: Vec<f64>,
    q: Vec<[f64; N_MONO * N_MONO]>,
    white: f64,
    first: usize,
}

fn psd_pair(s: &Surface) -> Result<(Psd1d, Psd1d), VibrationError> {
    psd_xy(s, &PsdOptions::default()).map_err(|e| VibrationError::InvalidArgument(e.to_string()))
}

impl SpectralModel {
    /// Builds the model of `model`'s removal on the valid pixels of `measured` (same grid).
    pub fn new(model: &ForcingModel, measured: &Surface) -> Result<SpectralModel, VibrationError> {
        let g = model.grid;
        if measured.dim() != (g.rows, g.cols) {
            return Err(VibrationError::InvalidArgument(format!(
                "measured removal map is {}x{}, the model grid {}x{}",
                measured.rows(),
                measured.cols(),
                g.rows,
                g.cols
            )));
        }
        let valid = measured.valid().clone();
        let surf = |map: Array2<f64>| {
            Surface::with_mask(map, valid.clone(), Some(g.dx_mm), Some(g.dy_mm))
                .map_err(|e| VibrationError::InvalidArgument(e.to_string()))
        };
        let c = model.total_coefficients();
        let mut diag: Vec<(Psd1d, Psd1d)> = Vec::with_capacity(N_MONO);
        for ck in &c {
            diag.push(psd_pair(&surf(ck.clone())?)?);
        }
        let mut qx = vec![[0.0; N_MONO * N_MONO]; diag[0].0.len()];
        let mut qy = vec![[0.0; N_MONO * N_MONO]; diag[0].1.len()];
        // Diagonal from PSD[C_k]; off-diagonal by polarisation from PSD[C_k + C_l].
        let put = |q: &mut [[f64; N_MONO * N_MONO]],
                   k: usize,
                   l: usize,
                   sum: &Psd1d,
                   pk: &Psd1d,
                   pl: &Psd1d| {
            for (b, qb) in q.iter_mut().enumerate() {
                let v = 0.5 * (sum.psd_nm2_mm[b] - pk.psd_nm2_mm[b] - pl.psd_nm2_mm[b]);
                qb[k * N_MONO + l] = v;
                qb[l * N_MONO + k] = v;
            }
        };
        for k in 0..N_MONO {
            for (b, qb) in qx.iter_mut().enumerate() {
                qb[k * N_MONO + k] = diag[k].0.psd_nm2_mm[b];
            }
            for (b, qb) in qy.iter_mut().enumerate() {
                qb[k * N_MONO + k] = diag[k].1.psd_nm2_mm[b];
            }
            for l in k + 1..N_MONO {
                let (px, py) = psd_pair(&surf(&c[k] + &c[l])?)?;
                put(&mut qx, k, l, &px, &diag[k].0, &diag[l].0);
                put(&mut qy, k, l, &py, &diag[k].1, &diag[l].1);
            }
        }
        // White-noise level: the crate's PSD of seeded unit-variance noise on the same mask,
        // averaged over the unbiased bins (flat in expectation).
        let mut rng = Rng::new(0x5eed_0f01_5300);
        let noise = Array2::from_shape_fn((g.rows, g.cols), |_| rng.normal());
        let (wx, wy) = psd_pair(&surf(noise)?)?;
        let level = |p: &Psd1d| {
            let v = &p.psd_nm2_mm[p.biased_bins.min(p.len())..];
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        let ax = AxisModel {
            freq: diag[0].0.freq_per_mm.clone(),
            q: qx,
            white: level(&wx),
            first: diag[0].0.biased_bins,
        };
        let ay = AxisModel {
            freq: diag[0].1.freq_per_mm.clone(),
            q: qy,
            white: level(&wy),
            first: diag[0].1.biased_bins,
        };
        Ok(SpectralModel {
            axes: [ax, ay],
            enbw_bins: diag[0].0.enbw_bins.max(1.0),
        })
    }

    /// The spindle-harmonic imprint band of the X (scan) axis: the unbiased X bins where the
    /// PSD of the removal's linear response to the forcing (`Q_11`, nm² mm per N²) is within
    /// [`IMPRINT_BAND_DB`] of its peak, as (first, last) bin; None when the model has no imprint
    /// (the harmonics fall beyond Nyquist).
    pub fn imprint_band(&self) -> Option<(usize, usize)> {
        let ax = &self.axes[0];
        let lin = |b: usize| ax.q[b][N_MONO + 1];
        let from = ax.first.max(1);
        let peak = (from..ax.freq.len()).map(lin).fold(0.0, f64::max);
        if !(peak > 0.0 && peak.is_finite()) {
            return None;
        }
        let level = peak * 10f64.powf(-IMPRINT_BAND_DB / 10.0);
        let inside: Vec<usize> = (from..ax.freq.len()).filter(|&b| lin(b) >= level).collect();
        Some((*inside.first()?, *inside.last()?))
    }

    /// Bins of the fit as (axis, bin), axis 0 = X, and how many of them lead as rate-scale
    /// bins. With an imprint band: first the bins of both axes where the commanded path's
    /// removal (`Q_00`) is within [`SCALE_BINS_DB`] of its peak on that axis (the raster ripple
    /// and the part-scale figure: they fix the removal-rate scale, far above any noise), then
    /// the X bins of the imprint band with a flank on each side as wide as the band (at least
    /// [`MIN_FLANK_BINS`]): the flanks fix the flat local background (measurement noise,
    /// texture, path errors the model does not have), the band the forcing. Without an imprint
    /// band: every unbiased bin of both axes, none leading (the scale and a white level are
    /// fitted over all of them).
    fn fit_bins(&self) -> (Vec<(usize, usize)>, Option<usize>) {
        let Some((lo, hi)) = self.imprint_band() else {
            let mut all = Vec::new();
            for (a, ax) in self.axes.iter().enumerate() {
                all.extend((ax.first.max(1)..ax.freq.len()).map(|b| (a, b)));
            }
            return (all, None);
        };
        let mut bins = Vec::new();
        for (a, ax) in self.axes.iter().enumerate() {
            let from = ax.first.max(1);
            let base = |b: usize| ax.q[b][0];
            let peak = (from..ax.freq.len()).map(base).fold(0.0, f64::max);
            let level = peak * 10f64.powf(-SCALE_BINS_DB / 10.0);
            bins.extend(
                (from..ax.freq.len())
                    .filter(|&b| peak > 0.0 && base(b) >= level)
                    .map(|b| (a, b)),
            );
        }
        let n_scale = bins.len();
        let x = &self.axes[0];
        let flank = (hi - lo).max(MIN_FLANK_BINS);
        let from = lo.saturating_sub(flank).max(x.first.max(1));
        let to = (hi + flank).min(x.freq.len() - 1);
        for b in from..=to {
            if !bins[..n_scale].contains(&(0, b)) {
                bins.push((0, b));
            }
        }
        (bins, Some(n_scale))
    }

    /// Model PSD of the removal (no scale, no noise) at forcing (F, S): X bins then Y bins.
    fn removal_psd(&self, fn_n: f64, noise_n: f64, bins: &[(usize, usize)], out: &mut Vec<f64>) {
        let w = monomials(fn_n, noise_n);
        out.clear();
        for &(a, b) in bins {
            let q = &self.axes[a].q[b];
            let mut acc = 0.0;
            for k in 0..N_MONO {
                let mut row = 0.0;
                for l in 0..N_MONO {
                    row += q[k * N_MONO + l] * w[l];
                }
                acc += w[k] * row;
            }
            out.push(acc.max(0.0));
        }
    }
}

/// The forcing fit of one run.
#[derive(Debug, Clone, Serialize)]
pub struct ForcingFit {
    pub bonnet: Bonnet,
    /// Best-fit spindle-harmonic amplitude, N (reported whether or not it is constrained).
    pub best_fn_n: f64,
    /// Best-fit broadband force RMS, N, and its 95 % interval (None when an end is not found).
    pub noise_force_rms_n: f64,
    pub noise_interval_n: Option<[f64; 2]>,
    /// Fitted removal-rate scale c (1 = the model's rate).
    pub rate_scale: f64,
    /// Fitted white measurement noise RMS of the removal map, nm.
    pub meas_noise_rms_nm: f64,
    /// Bins fitted (X + Y), residual variance of ln P, window ENBW (bins).
    pub bins: usize,
    pub residual_var: f64,
    pub enbw_bins: f64,
    /// χ²(F = 0, best S) − χ²_min: evidence for a spindle-harmonic imprint.
    pub delta_chi2_zero_fn: f64,
    pub forcing: VibrationForcing,
    pub fn_grid_n: Vec<f64>,
    pub noise_grid_n: Vec<f64>,
    /// SSR of ln P on the (fn, noise) grid, fn-major.
    #[serde(skip)]
    pub ssr_grid: Vec<f64>,
    #[serde(skip)]
    pub params: VibrationParams,
}

impl ForcingFit {
    /// χ² on the grid (SSR / (s² ENBW)).
    pub fn chi2_grid(&self) -> Vec<f64> {
        let d = self.residual_var * self.enbw_bins;
        self.ssr_grid.iter().map(|v| v / d).collect()
    }
}

fn grid(max: f64, steps: usize) -> Vec<f64> {
    let n = steps.max(1);
    (0..=n).map(|i| max * i as f64 / n as f64).collect()
}

/// Iteratively reweighted fit of P ≈ a M + b W (a, b ≥ 0) in ln P; returns (SSR, a, b).
fn fit_scale_noise(meas: &[f64], model: &[f64], white: &[f64]) -> (f64, f64, f64) {
    let mut wgt: Vec<f64> = meas.iter().map(|p| 1.0 / (p * p)).collect();
    let (mut a, mut b) = (0.0, 0.0);
    for _ in 0..4 {
        let (mut smm, mut smw, mut sww, mut smp, mut swp) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..meas.len() {
            let w = wgt[i];
            smm += w * model[i] * model[i];
            smw += w * model[i] * white[i];
            sww += w * white[i] * white[i];
            smp += w * model[i] * meas[i];
            swp += w * white[i] * meas[i];
        }
        let det = smm * sww - smw * smw;
        let (mut na, mut nb) = if det > 1e-300 * smm.max(1e-300) * sww.max(1e-300) {
            ((smp * sww - swp * smw) / det, (swp * smm - smp * smw) / det)
        } else {
            (-1.0, -1.0)
        };
        if na < 0.0 || nb < 0.0 {
            // Best of the two one-parameter fits.
            let a1 = if smm > 0.0 { (smp / smm).max(0.0) } else { 0.0 };
            let b1 = if sww > 0.0 { (swp / sww).max(0.0) } else { 0.0 };
            let r_a = ssr_log(meas, model, white, a1, 0.0);
            let r_b = ssr_log(meas, model, white, 0.0, b1);
            if r_a <= r_b {
                na = a1;
                nb = 0.0;
            } else {
                na = 0.0;
                nb = b1;
            }
        }
        a = na;
        b = nb;
        for i in 0..meas.len() {
            let p = (a * model[i] + b * white[i]).max(1e-300);
            wgt[i] = 1.0 / (p * p);
        }
    }
    (ssr_log(meas, model, white, a, b), a, b)
}

/// The fit with an imprint band: the rate scale a from the first `n_scale` bins (where the
/// commanded path's removal dominates; a white level is fitted with it there), then the
/// flat background b ≥ 0 from the band and its flanks by an iteratively reweighted fit of
/// P ≈ a M + b W in ln P with a held; returns (SSR over all bins, a, b).
fn fit_scale_then_background(
    meas: &[f64],
    model: &[f64],
    white: &[f64],
    n_scale: usize,
) -> (f64, f64, f64) {
    let (_, a, _) = fit_scale_noise(&meas[..n_scale], &model[..n_scale], &white[..n_scale]);
    let mut b = 0.0;
    for _ in 0..6 {
        let (mut sww, mut swr) = (0.0, 0.0);
        for i in n_scale..meas.len() {
            let q = (a * model[i] + b * white[i]).max(meas[i] * 1e-6);
            let w = 1.0 / (q * q);
            sww += w * white[i] * white[i];
            swr += w * white[i] * (meas[i] - a * model[i]);
        }
        b = if sww > 0.0 { (swr / sww).max(0.0) } else { 0.0 };
    }
    (ssr_log(meas, model, white, a, b), a, b)
}

fn ssr_log(meas: &[f64], model: &[f64], white: &[f64], a: f64, b: f64) -> f64 {
    meas.iter()
        .zip(model.iter().zip(white))
        .map(|(&p, (&m, &w))| {
            let q = (a * m + b * w).max(1e-300);
            let r = p.ln() - q.ln();
            r * r
        })
        .sum()
}

/// End-of-robot amplitude at spindle-harmonic amplitude `fn_n`: the semi-major axis of the
/// holder's in-plane displacement ellipse at the fundamental n/60 Hz, mm
/// (sqrt((|X1|² + |X2|² + |X1² + X2²|) / 2) of the principal phasors).
pub fn end_amplitude_mm(p: &VibrationParams, bonnet: Bonnet, fn_n: f64) -> f64 {
    let h = harmonic_phasors(p, bonnet, p.excitation_hz(), fn_n);
    let s = h.x[0].norm_sqr() + h.x[1].norm_sqr();
    let c = (h.x[0] * h.x[0] + h.x[1] * h.x[1]).norm();
    (0.5 * (s + c)).sqrt()
}

/// Crossing of `prof` (values over `xs`) above `level` walking from index `from` in direction
/// `dir`; None when the grid ends first.
fn crossing(xs: &[f64], prof: &[f64], from: usize, dir: isize, level: f64) -> Option<f64> {
    let mut i = from as isize;
    loop {
        let j = i + dir;
        if j < 0 || j as usize >= xs.len() {
            return None;
        }
        let (pi, pj) = (prof[i as usize], prof[j as usize]);
        if pj > level {
            let t = if pj > pi {
                (level - pi) / (pj - pi)
            } else {
                0.0
            };
            let (xi, xj) = (xs[i as usize], xs[j as usize]);
            return Some(xi + t.clamp(0.0, 1.0) * (xj - xi));
        }
        i = j;
    }
}

/// Minimum of a sampled profile refined by a parabola through the neighbours.
fn refine_min(xs: &[f64], prof: &[f64]) -> (usize, f64) {
    let (imin, _) =
        prof.iter().enumerate().fold(
            (0, f64::INFINITY),
            |acc, (i, &v)| if v < acc.1 { (i, v) } else { acc },
        );
    if imin == 0 || imin + 1 >= xs.len() {
        return (imin, xs[imin]);
    }
    let (a, b, c) = (prof[imin - 1], prof[imin], prof[imin + 1]);
    let den = a - 2.0 * b + c;
    let h = xs[imin + 1] - xs[imin];
    let off = if den > 0.0 { 0.5 * (a - c) / den } else { 0.0 };
    (imin, xs[imin] + off.clamp(-0.5, 0.5) * h)
}

/// The `vibration_forcing` verdict from a χ² profile over the fn grid.
fn verdict(
    fn_grid: &[f64],
    prof: &[f64],
    p: &VibrationParams,
    bonnet: Bonnet,
    what: &str,
) -> (f64, VibrationForcing) {
    let (imin, best) = refine_min(fn_grid, prof);
    let min = prof[imin];
    let fmax = *fn_grid.last().unwrap_or(&0.0);
    let zero_excluded = prof[0] - min > DCHI2_95;
    let lo = crossing(fn_grid, prof, imin, -1, min + DCHI2_95);
    let hi = crossing(fn_grid, prof, imin, 1, min + DCHI2_95);
    let amp = |f: f64| end_amplitude_mm(p, bonnet, f);
    let forcing = match (zero_excluded, lo, hi) {
        (true, lo, Some(hi)) => VibrationForcing {
            fn_n: Some(best),
            interval_n: Some([lo.unwrap_or(0.0), hi]),
            upper_bound_n: None,
            end_amplitude_mm: Some(amp(best)),
            constrained: true,
            reason: format!(
                "{what}: spindle-harmonic imprint detected (zero forcing excluded, Δχ² = {:.1}); \
                 95 % profile-likelihood interval",
                prof[0] - min
            ),
        },
        (true, _, None) => VibrationForcing {
            fn_n: None,
            interval_n: None,
            upper_bound_n: None,
            end_amplitude_mm: None,
            constrained: false,
            reason: format!(
                "{what}: a forcing imprint is detected but not bounded within the searched \
                 0-{fmax} N: the spectrum does not fix its size"
            ),
        },
        (false, _, _) => {
            let ub = crossing(fn_grid, prof, imin, 1, min + DCHI2_95_ONE_SIDED);
            VibrationForcing {
                fn_n: None,
                interval_n: None,
                upper_bound_n: ub,
                end_amplitude_mm: ub.map(amp),
                constrained: false,
                reason: match ub {
                    Some(u) => format!(
                        "{what}: no spindle-harmonic imprint above the noise floor and the \
                         raster ripple (zero forcing fits within Δχ² = {:.2}); one-sided 95 % \
                         upper bound {u:.3} N (end amplitude given at the bound)",
                        prof[0] - min
                    ),
                    None => format!(
                        "{what}: the spectrum cannot constrain the forcing: no imprint and no \
                         upper bound within the searched 0-{fmax} N"
                    ),
                },
            }
        }
    };
    (best, forcing)
}

/// Fits the forcing of one run to its measured removal map (nm, positive = removed, the model's
/// grid; invalid pixels masked).
pub fn infer_forcing(
    model: &ForcingModel,
    measured_removal: &Surface,
    opts: &InferOptions,
) -> Result<ForcingFit, VibrationError> {
    let spec = SpectralModel::new(model, measured_removal)?;
    let (mx, my) = psd_pair(measured_removal)?;
    let meas_axes = [&mx, &my];
    let mut bins = Vec::new();
    let mut meas = Vec::new();
    let mut white = Vec::new();
    let (candidates, n_lead) = spec.fit_bins();
    let mut n_scale = n_lead.map(|_| 0);
    for (i, &(a, b)) in candidates.iter().enumerate() {
        let f = spec.axes[a].freq[b];
        let p = meas_axes[a].psd_nm2_mm[b];
        if f >= opts.band_per_mm.0 && f <= opts.band_per_mm.1 && p > 0.0 && p.is_finite() {
            bins.push((a, b));
            meas.push(p);
            white.push(spec.axes[a].white);
            if let (Some(n), Some(lead)) = (n_scale.as_mut(), n_lead) {
                if i < lead {
                    *n += 1;
                }
            }
        }
    }
    if bins.len() < 8 || n_scale == Some(0) {
        return Err(VibrationError::InvalidArgument(format!(
            "only {} PSD bins in the fit band: the map is too small",
            bins.len()
        )));
    }
    if !(opts.fn_max_n > 0.0 && opts.noise_max_n >= 0.0) {
        return Err(VibrationError::InvalidArgument(
            "forcing search ranges must be positive".into(),
        ));
    }
    let fn_grid = grid(opts.fn_max_n, opts.fn_steps);
    let noise_grid = grid(opts.noise_max_n, opts.noise_steps);
    let (ssr, scale) = grid_fit(
        &spec,
        (&bins, &meas, &white, n_scale),
        &fn_grid,
        &noise_grid,
    );
    let (kmin, &ssr_min) =
        ssr.iter().enumerate().fold(
            (0, &f64::INFINITY),
            |acc, (k, v)| if v < acc.1 { (k, v) } else { acc },
        );
    let dof = (bins.len() as f64 - 4.0).max(1.0);
    let residual_var = (ssr_min / dof).max(1e-30);
    let chi = |v: f64| v / (residual_var * spec.enbw_bins);
    let ns = noise_grid.len();
    let prof_fn: Vec<f64> = (0..fn_grid.len())
        .map(|i| {
            chi(ssr[i * ns..(i + 1) * ns]
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min))
        })
        .collect();
    // The broadband force has no band of its own: its imprint is flat along both axes, under
    // the measurement noise. Its profile comes from every unbiased bin of both axes (a free
    // rate scale and white level), as the joint fit gives it; the spindle forcing's does not.
    let prof_noise: Vec<f64> = match n_scale {
        None => (0..ns)
            .map(|j| {
                chi((0..fn_grid.len())
                    .map(|i| ssr[i * ns + j])
                    .fold(f64::INFINITY, f64::min))
            })
            .collect(),
        Some(_) => {
            let (mut fb, mut fm, mut fw) = (Vec::new(), Vec::new(), Vec::new());
            for (a, ax) in spec.axes.iter().enumerate() {
                for b in ax.first.max(1)..ax.freq.len() {
                    let (f, p) = (ax.freq[b], meas_axes[a].psd_nm2_mm[b]);
                    if f >= opts.band_per_mm.0
                        && f <= opts.band_per_mm.1
                        && p > 0.0
                        && p.is_finite()
                    {
                        fb.push((a, b));
                        fm.push(p);
                        fw.push(ax.white);
                    }
                }
            }
            let (full, _) = grid_fit(&spec, (&fb, &fm, &fw, None), &fn_grid, &noise_grid);
            let min = full.iter().copied().fold(f64::INFINITY, f64::min);
            let var = (min / (fb.len() as f64 - 4.0).max(1.0)).max(1e-30);
            (0..ns)
                .map(|j| {
                    (0..fn_grid.len())
                        .map(|i| full[i * ns + j])
                        .fold(f64::INFINITY, f64::min)
                        / (var * spec.enbw_bins)
                })
                .collect()
        }
    };
    let (best_fn, forcing) = verdict(&fn_grid, &prof_fn, &model.params, model.bonnet, "run");
    let (jmin, best_noise) = refine_min(&noise_grid, &prof_noise);
    let nmin = prof_noise[jmin];
    let noise_interval = match (
        crossing(&noise_grid, &prof_noise, jmin, -1, nmin + DCHI2_95),
        crossing(&noise_grid, &prof_noise, jmin, 1, nmin + DCHI2_95),
    ) {
        (lo, Some(hi)) => Some([lo.unwrap_or(0.0), hi]),
        _ => None,
    };
    let (a, b) = scale[kmin];
    Ok(ForcingFit {
        bonnet: model.bonnet,
        best_fn_n: best_fn,
        noise_force_rms_n: best_noise,
        noise_interval_n: noise_interval,
        rate_scale: a.sqrt(),
        meas_noise_rms_nm: b.sqrt(),
        bins: bins.len(),
        residual_var,
        enbw_bins: spec.enbw_bins,
        delta_chi2_zero_fn: prof_fn[0] - prof_fn.iter().copied().fold(f64::INFINITY, f64::min),
        forcing,
        fn_grid_n: fn_grid,
        noise_grid_n: noise_grid,
        ssr_grid: ssr,
        params: model.params.clone(),
    })
}

/// Bins of a fit: (axis, bin), measured PSD, white level, leading rate-scale bins.
type FitBins<'a> = (&'a [(usize, usize)], &'a [f64], &'a [f64], Option<usize>);

/// SSR of ln P and the fitted (rate scale², white level) on the (fn, noise) grid, fn-major.
fn grid_fit(
    spec: &SpectralModel,
    (bins, meas, white, n_scale): FitBins<'_>,
    fn_grid: &[f64],
    noise_grid: &[f64],
) -> (Vec<f64>, Vec<(f64, f64)>) {
    let mut ssr = vec![0.0; fn_grid.len() * noise_grid.len()];
    let mut scale = vec![(0.0, 0.0); ssr.len()];
    let mut buf = Vec::with_capacity(bins.len());
    for (i, &f) in fn_grid.iter().enumerate() {
        for (j, &s) in noise_grid.iter().enumerate() {
            spec.removal_psd(f, s, bins, &mut buf);
            let (r, a, b) = match n_scale {
                Some(n) => fit_scale_then_background(meas, &buf, white, n),
                None => fit_scale_noise(meas, &buf, white),
            };
            ssr[i * noise_grid.len() + j] = r;
            scale[i * noise_grid.len() + j] = (a, b);
        }
    }
    (ssr, scale)
}

/// One forcing for several runs (each with its own bonnet damping and series compliance).
#[derive(Debug, Clone, Serialize)]
pub struct SharedForcing {
    /// The shared fit's verdict, with the end amplitude of each run's bonnet.
    pub forcing: Vec<VibrationForcing>,
    pub best_fn_n: f64,
    pub best_noise_force_rms_n: f64,
    /// Σ χ² of the runs at the shared optimum and at their separate optima.
    pub chi2_shared: f64,
    pub chi2_separate: f64,
    /// Degrees of freedom of the difference: 2 (F, S) per extra run.
    pub dof: usize,
    /// P(χ²_dof ≥ chi2_shared − chi2_separate): the probability of a worse mismatch if one
    /// forcing acts on every run.
    pub p_value: f64,
    /// p_value ≥ 0.05.
    pub consistent: bool,
    /// Mean normal force p π (2 R h − h²) of the first run's bonnet, N; a fluctuation larger
    /// than the mean force would lift the bonnet off the part.
    pub mean_normal_force_n: f64,
    /// consistent and the shared amplitude (or its upper bound) below the mean normal force.
    pub plausible: bool,
    pub reason: String,
}

/// χ²_k survival function: closed forms, the odd ones from erfc (recurrence over k in steps
/// of 2: Q_{k+2}(x) = Q_k(x) + (x/2)^{k/2} e^{-x/2} / Γ(k/2 + 1)).
fn chi2_sf(x: f64, k: usize) -> f64 {
    if x <= 0.0 || k == 0 {
        return 1.0;
    }
    let h = 0.5 * x;
    let (mut sum, mut term, mut order) = if k.is_multiple_of(2) {
        ((-h).exp(), (-h).exp(), 2)
    } else {
        let t = (h.sqrt() * (-h).exp()) / (0.5 * std::f64::consts::PI.sqrt());
        (libm_erfc(h.sqrt()), t, 1)
    };
    if !k.is_multiple_of(2) && k >= 3 {
        sum += term;
        order = 3;
    }
    while order < k {
        // term for going from order to order + 2: previous term times h / (order / 2).
        term *= h / (0.5 * order as f64);
        sum += term;
        order += 2;
    }
    sum.min(1.0)
}

/// Complementary error function (Abramowitz-Stegun 7.1.26, |error| < 1.5e-7).
fn libm_erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let y = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))))
        * (-z * z).exp();
    if x >= 0.0 {
        y
    } else {
        2.0 - y
    }
}

/// Does one forcing explain every run? The runs' fits must share their search grids
/// (the same [`InferOptions`]).
pub fn shared_forcing(fits: &[&ForcingFit]) -> Result<SharedForcing, VibrationError> {
    let first = fits
        .first()
        .ok_or_else(|| VibrationError::InvalidArgument("no runs to share a forcing".into()))?;
    for f in fits {
        if f.fn_grid_n != first.fn_grid_n || f.noise_grid_n != first.noise_grid_n {
            return Err(VibrationError::InvalidArgument(
                "runs fitted on different forcing grids".into(),
            ));
        }
    }
    let n = first.ssr_grid.len();
    let chis: Vec<Vec<f64>> = fits.iter().map(|f| f.chi2_grid()).collect();
    let total: Vec<f64> = (0..n).map(|k| chis.iter().map(|c| c[k]).sum()).collect();
    let sep: f64 = chis
        .iter()
        .map(|c| c.iter().copied().fold(f64::INFINITY, f64::min))
        .sum();
    let (kmin, &shared) =
        total.iter().enumerate().fold(
            (0, &f64::INFINITY),
            |acc, (k, v)| if v < acc.1 { (k, v) } else { acc },
        );
    let ns = first.noise_grid_n.len();
    let prof_fn: Vec<f64> = (0..first.fn_grid_n.len())
        .map(|i| {
            total[i * ns..(i + 1) * ns]
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let mut forcing = Vec::new();
    let mut best = 0.0;
    for f in fits {
        let (b, v) = verdict(
            &first.fn_grid_n,
            &prof_fn,
            &f.params,
            f.bonnet,
            "shared forcing",
        );
        best = b;
        forcing.push(v);
    }
    let dof = 2 * (fits.len() - 1);
    let delta = (shared - sep).max(0.0);
    let p_value = if dof == 0 { 1.0 } else { chi2_sf(delta, dof) };
    let consistent = p_value >= 0.05;
    let p = &first.params;
    let h = p.offset_mm;
    let mean_force = p.inner_pressure_mpa * PI * (2.0 * p.bonnet_radius_mm * h - h * h);
    let size = forcing[0].fn_n.or(forcing[0].upper_bound_n);
    let plausible = consistent && size.is_some_and(|s| s <= mean_force);
    let reason = format!(
        "one forcing for {} runs: Δχ² = {delta:.2} on {dof} dof (p = {p_value:.3}) against \
         separate forcings: {}; the shared amplitude {} the mean normal force {mean_force:.1} N",
        fits.len(),
        if consistent {
            "consistent"
        } else {
            "rejected (the runs need different forcings)"
        },
        match size {
            Some(s) if s <= mean_force => format!("({s:.2} N) is below"),
            Some(s) => format!("({s:.2} N) exceeds"),
            None => "is not bounded against".to_string(),
        }
    );
    Ok(SharedForcing {
        forcing,
        best_fn_n: best,
        best_noise_force_rms_n: first.noise_grid_n[kmin % ns],
        chi2_shared: shared,
        chi2_separate: sep,
        dof,
        p_value,
        consistent,
        mean_normal_force_n: mean_force,
        plausible,
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_survival_matches_known_values() {
        assert!((chi2_sf(5.991_464_547, 2) - 0.05).abs() < 1e-9);
        assert!((chi2_sf(9.487_729, 4) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(DCHI2_95, 1) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(7.814_727_903, 3) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(11.070_497_69, 5) - 0.05).abs() < 1e-6);
    }

    #[test]
    fn scale_noise_fit_recovers_a_two_component_spectrum() {
        let model: Vec<f64> = (1..50).map(|k| 100.0 / (k * k) as f64).collect();
        let white = vec![1.0; model.len()];
        let meas: Vec<f64> = model.iter().map(|m| 2.5 * m + 0.3).collect();
        let (ssr, a, b) = fit_scale_noise(&meas, &model, &white);
        assert!(ssr < 1e-12 && (a - 2.5).abs() < 1e-6 && (b - 0.3).abs() < 1e-6);
    }

    #[test]
    fn end_amplitude_is_the_larger_axis_for_in_phase_motion() {
        // Far below resonance both axes move in phase: the ellipse degenerates to a line of
        // length sqrt(X1² + X2²).
        let p = VibrationParams {
            spindle_rpm: 1.0,
            ..Default::default()
        };
        let h = harmonic_phasors(&p, Bonnet::Original, p.excitation_hz(), 3.0);
        let a = end_amplitude_mm(&p, Bonnet::Original, 3.0);
        let line = (h.x[0].norm_sqr() + h.x[1].norm_sqr()).sqrt();
        assert!((a - line).abs() < 1e-6 * line, "{a} {line}");
    }
}
