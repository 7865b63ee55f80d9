//! The ripple check at the raster's grating spacing p (f0 = 1/p), read in the Y PSD (the feed
//! direction, across the raster tracks).
//!
//! - sigma_k = band RMS over |f - k f0| <= h with h = max(4 df, 0.1 f0), k = 1..=K (harmonics
//!   whose band centre lies below Nyquist); sigma_total = RMS over the union of those bands
//!   (each bin counted once: when few periods fit on the map the bands overlap, and
//!   sqrt(sum sigma_k^2) would count the same bins several times).
//! - Not resolvable (an error `NotResolvable` with the reason, never numbers): the pitch is
//!   longer than the Y field, f0 is above Nyquist, or the f0 band reaches the biased lowest
//!   bins (fewer than about b + 4 periods on the field, b = the window's biased bins).
//! - A_eq = sqrt(2) sigma_1, PV_eq = 2 sqrt(2) sigma_1 (never read amplitudes off peak heights:
//!   the peak scales with 1 / ENBW).
//! - Prominence (dB) = 10 log10(peak / background), peak = largest PSD value in the f0 band,
//!   background = median of the PSD in the flanking windows h < |f - f0| <= h + max(2h, 8 df),
//!   leaving out biased bins and every harmonic band. The median ignores a flank's own peaks.
//! - `detected` = prominence >= threshold (default 6 dB); `verdict` says so in words. On a
//!   ripple-free map averaged over
//!   many lines (>= 64) the prominence of noise is about 1 dB; with very few lines the PSD
//!   estimate itself fluctuates by several dB, so raise the threshold for those.
//! - y_over_x = sigma_1 from the Y PSD / band RMS of the X PSD over the same band (anisotropy);
//!   null with `y_over_x_reason` when that X band RMS is rounding residue ([`ROUNDING_FLOOR`]).
//! - `hint`: not detected along Y while X holds a detected ripple at f0 with sigma_1 along X
//!   >= 3 times Y's: the map's X and Y may be swapped.

use serde::Serialize;

use bonnetlab_surface::Surface;

use crate::band::band_rms;
use crate::error::SpectrumError;
use crate::psd1d::{psd_xy, Psd1d, PsdOptions};

/// Default detection threshold on the prominence, dB.
pub const PROMINENCE_THRESHOLD_DB: f64 = 6.0;

/// Options of the ripple check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RippleOptions {
    /// Highest harmonic considered (default 5); harmonics above Nyquist are skipped.
    pub harmonics: usize,
    /// Prominence at or above which a ripple is reported as detected, dB.
    pub prominence_threshold_db: f64,
}

impl Default for RippleOptions {
    fn default() -> Self {
        RippleOptions {
            harmonics: 5,
            prominence_threshold_db: PROMINENCE_THRESHOLD_DB,
        }
    }
}

/// One harmonic of the ripple.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Harmonic {
    pub k: usize,
    pub freq_per_mm: f64,
    pub sigma_nm: f64,
}

/// A band RMS at or below this fraction of the larger of the X and Y profiles' RMS is rounding
/// residue (f64 arithmetic leaves ~1e-16 of the RMS in every bin): never a detected ripple
/// along Y, never the denominator of `y_over_x` along X. One floor, `floor_nm` in
/// [`ripple_from_psds`], for both.
pub const ROUNDING_FLOOR: f64 = 1e-10;

/// Ripple metrics (field names as in shared/spec/interfaces.md `ripple`).

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ripple {
    pub pitch_mm: f64,
    pub f0_per_mm: f64,
    /// Half-width h of every harmonic band, mm^-1.
    pub band_halfwidth_per_mm: f64,
    pub sigma1_nm: f64,
    pub sigma_total_nm: f64,
    pub a_eq_nm: f64,
    pub pv_eq_nm: f64,
    pub prominence_db: f64,
    pub peak_nm2_mm: f64,
    pub background_nm2_mm: f64,
    pub prominence_threshold_db: f64,
    pub detected: bool,
    /// sigma_1 (Y) / band RMS of the X PSD over the same band; null when X has no power there
    /// (its band RMS is rounding residue), with `y_over_x_reason` beside it.
    pub y_over_x: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_over_x_reason: Option<String>,
    pub sigma1_x_nm: f64,
    /// The f0 band reaches into the biased lowest bins. Always false in a returned value:
    /// such a ripple is `NotResolvable` (kept for the JSON contract's readers).
    pub biased: bool,
    /// Why `detected` is what it is, in words (prominence against the threshold).
    pub verdict: String,
    pub harmonics: Vec<Harmonic>,
    /// Not detected along Y but a ripple at the pitch along X: the axes may be swapped.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hint: Option<String>,
}

/// Ripple from an existing pair of one-sided PSDs (X and Y).
pub fn ripple_from_psds(
    x: &Psd1d,
    y: &Psd1d,
    pitch_mm: f64,
    ropts: &RippleOptions,
) -> Result<Ripple, SpectrumError> {
    if !(pitch_mm.is_finite() && pitch_mm > 0.0) {
        return Err(SpectrumError::InvalidArgument(format!(
            "pitch must be positive, got {pitch_mm} mm"
        )));
    }
    let f0 = 1.0 / pitch_mm;
    let df = y.df_per_mm;
    let nyq = y.freq_per_mm.last().copied().unwrap_or(0.0);
    let field = 1.0 / df;
    let sig = crate::band::fmt_short;
    if pitch_mm > field {
        return Err(SpectrumError::NotResolvable(format!(
            "the {} mm pitch is longer than the {} mm field (Y lines)",
            sig(pitch_mm),
            sig(field)
        )));
    }
    if f0 > nyq {
        return Err(SpectrumError::NotResolvable(format!(
            "the {} mm pitch is shorter than two Y pixels: 1/pitch = {} 1/mm is above the \
             Nyquist frequency {} 1/mm",
            sig(pitch_mm),
            sig(f0),
            sig(nyq)
        )));
    }
    let h = (4.0 * df).max(0.1 * f0);
    let f_lo = y.first_unbiased_freq_per_mm();
    if f0 - h < f_lo - 1e-9 * df {
        return Err(SpectrumError::NotResolvable(format!(
            "the {} mm pitch fits only {:.1} times in the {} mm Y field: its band {} +/- {} 1/mm \
             reaches the lowest {} PSD bins, which the detrend and window bias",
            sig(pitch_mm),
            field / pitch_mm,
            sig(field),
            sig(f0),
            sig(h),
            y.biased_bins
        )));
    }
    let harmonics: Vec<Harmonic> = (1..=ropts.harmonics.max(1))
        .map(|k| k as f64 * f0)
        .take_while(|&fk| fk <= nyq)
        .enumerate()
        .map(|(i, fk)| Harmonic {
            k: i + 1,
            freq_per_mm: fk,
            sigma_nm: band_rms(y, fk - h, fk + h),
        })
        .collect();
    let sigma1 = harmonics[0].sigma_nm;
    let eps = 1e-9 * df;
    let in_band = |f: f64, c: f64| (f - c).abs() <= h + eps;
    // Union of the harmonic bands, each bin once.
    let sigma_total = y
        .freq_per_mm
        .iter()
        .zip(&y.psd_nm2_mm)
        .filter(|(f, _)| harmonics.iter().any(|m| in_band(**f, m.freq_per_mm)))
        .map(|(_, p)| p * df)
        .sum::<f64>()
        .sqrt();

    let n_harm = ropts.harmonics.max(2);
    let (peak, background, prominence_db) =
        prominence(y, f0, h, n_harm, f_lo).ok_or_else(|| {
            SpectrumError::TooSmall(format!(
                "no PSD bins flank the grating band around {f0} mm^-1 to estimate a background"
            ))
        })?;
    let sigma1_x = band_rms(x, f0 - h, f0 + h);
    // A peak is a ripple only above the arithmetic's own floor: a map with nothing along Y
    // still leaves rounding residue of ~1e-16 of its RMS in every bin, and a ratio of two such
    // residues can be any number of dB.
    // The floor is relative to the larger of the two profiles' RMS: a map with nothing along
    // one direction has residue for that profile's whole RMS too.
    let (x_rms, y_rms) = (profile_rms_nm(x), profile_rms_nm(y));
    let floor_nm = ROUNDING_FLOOR * x_rms.max(y_rms);
    let y_above = sigma1 > floor_nm;
    let detected = y_above && prominence_db >= ropts.prominence_threshold_db;
    let verdict = if y_above {
        format!(
            "{}: prominence {:.1} dB {} the {} dB threshold",
            if detected { "detected" } else { "not detected" },
            prominence_db,
            if detected { ">=" } else { "<" },
            ropts.prominence_threshold_db
        )
    } else {
        format!(
            "not detected: sigma_1 {sigma1:.3e} nm is rounding residue (under {ROUNDING_FLOOR:e} of \
             the larger profile RMS, {:.3e} nm)",
            x_rms.max(y_rms)
        )
    };
    // The ratio needs an X band above X's own rounding residue: a map with nothing along X
    // leaves ~1e-16 of its RMS there, and sigma_1 over that is a meaningless 1e30.
    let (y_over_x, y_over_x_reason) = if sigma1_x > floor_nm {
        (Some(sigma1 / sigma1_x), None)
    } else {
        (
            None,
            Some(format!(
                "no X power at f0: the X band RMS {sigma1_x:.3e} nm is rounding residue (under \
                 {floor_nm:.3e} nm, {ROUNDING_FLOOR:e} of the larger profile RMS)"
            )),
        )
    };
    let hint =
        (!detected && x_ripple_detected(x, f0, sigma1, sigma1_x, floor_nm, ropts)).then(|| {
            format!(
                "a ripple at the pitch is along X (sigma_1 along X {sigma1_x:.3e} nm, along Y \
             {sigma1:.3e} nm): are X (scan, along columns) and Y (feed, along rows) swapped?"
            )
        });
    Ok(Ripple {
        pitch_mm,
        f0_per_mm: f0,
        band_halfwidth_per_mm: h,
        sigma1_nm: sigma1,
        sigma_total_nm: sigma_total,
        a_eq_nm: std::f64::consts::SQRT_2 * sigma1,
        pv_eq_nm: 2.0 * std::f64::consts::SQRT_2 * sigma1,
        prominence_db,
        peak_nm2_mm: peak,
        background_nm2_mm: background,
        prominence_threshold_db: ropts.prominence_threshold_db,
        detected,
        y_over_x,
        y_over_x_reason,
        sigma1_x_nm: sigma1_x,
        biased: false,
        verdict,
        harmonics,
        hint,
    })
}

/// RMS (nm) of a profile from its one-sided PSD: sqrt(sum P1 df) over every bin.
fn profile_rms_nm(p: &Psd1d) -> f64 {
    p.psd_nm2_mm
        .iter()
        .map(|v| v * p.df_per_mm)
        .sum::<f64>()
        .sqrt()
}

/// sigma_1 along X at least this many times sigma_1 along Y, with a detected peak along X,
/// suggests the map's axes are swapped.
const SWAP_HINT_RATIO: f64 = 3.0;

/// Whether the X PSD holds a ripple at f0 by the same test as Y (above rounding, prominence
/// over the flanks >= threshold, each in X's own band width) and well above Y's sigma_1.
fn x_ripple_detected(
    x: &Psd1d,
    f0: f64,
    sigma1_y: f64,
    sigma1_x: f64,
    floor_nm: f64,
    ropts: &RippleOptions,
) -> bool {
    let nyq = x.freq_per_mm.last().copied().unwrap_or(0.0);
    let h = (4.0 * x.df_per_mm).max(0.1 * f0);
    let f_lo = x.first_unbiased_freq_per_mm();
    if f0 > nyq || f0 - h < f_lo - 1e-9 * x.df_per_mm {
        return false;
    }
    let sigma_x = band_rms(x, f0 - h, f0 + h);
    sigma_x > floor_nm
        && sigma1_x >= SWAP_HINT_RATIO * sigma1_y
        && prominence(x, f0, h, ropts.harmonics.max(2), f_lo)
            .is_some_and(|(_, _, db)| db >= ropts.prominence_threshold_db)
}

/// (peak, background, prominence dB) of a PSD at f0: peak = largest value in |f - f0| <= h,
/// background = median over the flanks h < |f - f0| <= h + max(2h, 8 df) above `f_lo`, leaving
/// out the harmonic bands 2..=n_harm; None when no bin flanks the band.
fn prominence(p: &Psd1d, f0: f64, h: f64, n_harm: usize, f_lo: f64) -> Option<(f64, f64, f64)> {
    let df = p.df_per_mm;
    let eps = 1e-9 * df;
    let in_band = |f: f64, c: f64| (f - c).abs() <= h + eps;
    let peak = p
        .freq_per_mm
        .iter()
        .zip(&p.psd_nm2_mm)
        .filter(|(f, _)| in_band(**f, f0))
        .map(|(_, v)| *v)
        .fold(0.0, f64::max);
    let flank = (2.0 * h).max(8.0 * df);
    let mut bg: Vec<f64> = p
        .freq_per_mm
        .iter()
        .zip(&p.psd_nm2_mm)
        .filter(|(f, _)| {
            let d = (**f - f0).abs();
            d > h + eps
                && d <= h + flank + eps
                && **f >= f_lo - eps
                && !(2..=n_harm).any(|k| in_band(**f, k as f64 * f0))
        })
        .map(|(_, v)| *v)
        .collect();
    if bg.is_empty() {
        return None;
    }
    bg.sort_by(f64::total_cmp);
    let mid = bg.len() / 2;
    let background = if bg.len() % 2 == 1 {
        bg[mid]
    } else {
        0.5 * (bg[mid - 1] + bg[mid])
    };
    let db = if background > 0.0 && peak > 0.0 {
        10.0 * (peak / background).log10()
    } else if peak > 0.0 {
        f64::MAX.log10() * 10.0 // a peak over an exactly zero background (noise-free data)
    } else {
        0.0
    };
    Some((peak, background, db))
}

/// Ripple of a map: both PSDs (one form removal) then `ripple_from_psds` with default options.
pub fn ripple(s: &Surface, pitch_mm: f64, opts: &PsdOptions) -> Result<Ripple, SpectrumError> {
    let (x, y) = psd_xy(s, opts)?;
    ripple_from_psds(&x, &y, pitch_mm, &RippleOptions::default())
}
