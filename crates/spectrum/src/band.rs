//! Band-limited RMS by bin sums: sigma = sqrt(sum over bins with f1 <= f_k <= f2 of P1[k] df).
//! Bin sums (not trapezoids) make adjacent bands add up exactly in power. The MSF band has
//! configurable edges, which are always reported with the value.

use serde::Serialize;

use crate::error::SpectrumError;
use crate::psd1d::Psd1d;

/// Default mid-spatial-frequency band edges, mm^-1 (periods 33 mm down to 0.12 mm); the same
/// edges as the areal split (`areal::BAND_EDGES_DEFAULT_PER_MM`, source stated there).
pub const MSF_DEFAULT_PER_MM: (f64, f64) = crate::areal::BAND_EDGES_DEFAULT_PER_MM;

/// A number with 4 significant digits, for reasons and captions (no exponent for the
/// magnitudes of frequencies and lengths met here; outside [1e-4, 1e7) the workspace's
/// formatter, `bonnetlab_surface::format::sig`, so 1e300 is never 301 digits).
pub fn fmt_sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    if !(1e-4..1e7).contains(&v.abs()) {
        return bonnetlab_surface::format::sig(v, 4);
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    format!("{v:.digits$}")
}

pub(crate) fn check_band(f1: f64, f2: f64) -> Result<(), SpectrumError> {
    if !(f1.is_finite() && f2.is_finite() && f1 >= 0.0 && f2 >= f1) {
        return Err(SpectrumError::InvalidArgument(format!(
            "band edges must satisfy 0 <= f1 <= f2, got [{f1}, {f2}] mm^-1"
        )));
    }
    Ok(())
}

/// [`fmt_sig`] without trailing zeros ("3", "0.07", "8.333"), for reasons in prose.
pub fn fmt_short(v: f64) -> String {
    let s = fmt_sig(v);
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Band RMS (nm) of a one-sided 1-D PSD over [f1, f2] mm^-1, edges inclusive.
pub fn band_rms(psd: &Psd1d, f1_per_mm: f64, f2_per_mm: f64) -> f64 {
    band_power(psd, f1_per_mm, f2_per_mm).sqrt()
}

/// Band power (nm^2) = sum of P1 df over the bins in [f1, f2].
pub fn band_power(psd: &Psd1d, f1_per_mm: f64, f2_per_mm: f64) -> f64 {
    // A tolerance of 1e-9 bins keeps edges that are exact multiples of df inside the band
    // despite rounding in f_k = k df.
    let eps = 1e-9 * psd.df_per_mm;
    psd.freq_per_mm
        .iter()
        .zip(&psd.psd_nm2_mm)
        .filter(|(f, _)| **f >= f1_per_mm - eps && **f <= f2_per_mm + eps)
        .map(|(_, p)| p * psd.df_per_mm)
        .sum()
}

/// A PSD-integrated band RMS with the edges that define it (requested and as clipped to the
/// PSD's range). A band outside the PSD's unbiased range has no value and says why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandRms {
    pub f1_per_mm: f64,
    pub f2_per_mm: f64,
    /// The edges actually covered by the PSD's bins (clipped to [first unbiased bin, Nyquist]);
    /// `None` when the band lies outside that range.
    pub f1_used_per_mm: Option<f64>,
    pub f2_used_per_mm: Option<f64>,
    /// sqrt(sum of P1 df over the bins in the used edges), nm; `None` when not computed.
    pub rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// Band RMS with its edges clipped to the usable range of the PSD (biased bins excluded).
pub fn band(psd: &Psd1d, f1_per_mm: f64, f2_per_mm: f64) -> Result<BandRms, SpectrumError> {
    check_band(f1_per_mm, f2_per_mm)?;
    let f_lo = psd.first_unbiased_freq_per_mm();
    let nyq = psd.freq_per_mm.last().copied().unwrap_or(0.0);
    let lo = f1_per_mm.max(f_lo);
    let hi = f2_per_mm.min(nyq);
    // At least one bin must lie inside the clipped band.
    let eps = 1e-9 * psd.df_per_mm;
    let has_bin = hi >= lo
        && psd
            .freq_per_mm
            .iter()
            .any(|f| *f >= lo - eps && *f <= hi + eps);
    if has_bin {
        return Ok(BandRms {
            f1_per_mm,
            f2_per_mm,
            f1_used_per_mm: Some(lo),
            f2_used_per_mm: Some(hi),
            rms_nm: Some(band_rms(psd, lo, hi)),
            reason: None,
        });
    }
    let reason = if f2_per_mm < f_lo {
        format!(
            "not resolvable: the band [{}, {}] 1/mm lies below this PSD's first unbiased \
             frequency {} 1/mm (lines {} mm long)",
            fmt_short(f1_per_mm),
            fmt_short(f2_per_mm),
            fmt_short(f_lo),
            fmt_short(1.0 / psd.df_per_mm)
        )
    } else if f1_per_mm > nyq {
        format!(
            "not resolvable: the band [{}, {}] 1/mm lies above the Nyquist frequency {} 1/mm \
             (sample spacing {} mm)",
            fmt_short(f1_per_mm),
            fmt_short(f2_per_mm),
            fmt_short(nyq),
            fmt_short(psd.spacing_mm)
        )
    } else {
        format!(
            "not resolvable: no PSD bin (df {} 1/mm) falls inside [{}, {}] 1/mm",
            fmt_short(psd.df_per_mm),
            fmt_short(f1_per_mm),
            fmt_short(f2_per_mm)
        )
    };
    Ok(BandRms {
        f1_per_mm,
        f2_per_mm,
        f1_used_per_mm: None,
        f2_used_per_mm: None,
        rms_nm: None,
        reason: Some(reason),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lines::Axis;
    use crate::window::Window;

    fn flat(n: usize, df: f64, level: f64) -> Psd1d {
        Psd1d {
            axis: Axis::X,
            freq_per_mm: (0..n).map(|k| k as f64 * df).collect(),
            psd_nm2_mm: vec![level; n],
            df_per_mm: df,
            spacing_mm: 1.0,
            window: Window::None,
            enbw_bins: 1.0,
            n_lines: 1,
            n_segments: 1,
            biased_bins: 2,
            removed: vec![],
        }
    }

    #[test]
    fn adjacent_bands_add_in_power_and_edges_are_inclusive() {
        let p = flat(101, 0.1, 2.0);
        // [0.3, 0.5] holds bins 3, 4, 5: 3 * 2.0 * 0.1
        assert!((band_power(&p, 0.3, 0.5) - 0.6).abs() < 1e-12);
        let whole = band_power(&p, 0.0, 10.0);
        let parts = band_power(&p, 0.0, 4.95) + band_power(&p, 5.0, 10.0);
        assert!((whole - parts).abs() < 1e-12);
        let b = band(&p, 0.0, 100.0).unwrap();
        assert!((b.f1_used_per_mm.unwrap() - 0.2).abs() < 1e-12);
        assert!((b.f2_used_per_mm.unwrap() - 10.0).abs() < 1e-12);
        assert!(band(&p, 2.0, 1.0).is_err());
        // Outside the range: no value, a reason (never 0.0).
        let below = band(&p, 0.0, 0.1).unwrap();
        assert!(below.rms_nm.is_none() && below.reason.unwrap().contains("below"));
        let above = band(&p, 20.0, 30.0).unwrap();
        assert!(above.rms_nm.is_none() && above.reason.unwrap().contains("Nyquist"));
    }
}
