//! ISO 10110-8 style PSD limit line: PSD(f) <= A f^-B over [f1, f2] (A in nm^2 mm^(1-B) when
//! f is in mm^-1). Sidedness is explicit: a two-sided limit is compared with the two-sided
//! density S = P1 / 2 (P1 itself at DC and Nyquist). Biased low bins are never tested.

use serde::Serialize;

use crate::error::SpectrumError;
use crate::psd1d::Psd1d;

/// A limit line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LimitLine {
    pub a: f64,
    pub b: f64,
    pub f1_per_mm: f64,
    pub f2_per_mm: f64,
    /// true when A refers to a two-sided PSD.
    pub two_sided: bool,
}

/// The result of testing a PSD against a limit line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LimitCheck {
    pub line: LimitLine,
    pub sidedness: &'static str,
    /// max over tested bins of PSD / limit; <= 1 passes.
    pub worst_ratio: f64,
    pub worst_freq_per_mm: f64,
    pub bins_tested: usize,
    pub pass: bool,
}

/// Tests a one-sided PSD against the limit line.
pub fn check_limit(psd: &Psd1d, line: &LimitLine) -> Result<LimitCheck, SpectrumError> {
    if !(line.a.is_finite() && line.a > 0.0 && line.b.is_finite()) {
        return Err(SpectrumError::InvalidArgument(format!(
            "limit line needs A > 0 and finite B, got A = {}, B = {}",
            line.a, line.b
        )));
    }
    crate::band::check_band(line.f1_per_mm, line.f2_per_mm)?;
    let last = psd.len().saturating_sub(1);
    let nyquist_is_single = psd.spacing_mm > 0.0
        && ((psd.freq_per_mm.last().copied().unwrap_or(0.0) - 0.5 / psd.spacing_mm).abs()
            < 1e-9 * psd.df_per_mm);
    let (mut worst, mut at, mut n) = (0.0f64, f64::NAN, 0usize);
    for (k, (&f, &p)) in psd.freq_per_mm.iter().zip(&psd.psd_nm2_mm).enumerate() {
        if k < psd.biased_bins || f <= 0.0 || f < line.f1_per_mm || f > line.f2_per_mm {
            continue;
        }
        let single = k == last && nyquist_is_single;
        let value = if line.two_sided && !single {
            0.5 * p
        } else {
            p
        };
        let r = value / (line.a * f.powf(-line.b));
        n += 1;
        if r > worst || at.is_nan() {
            worst = r;
            at = f;
        }
    }
    if n == 0 {
        return Err(SpectrumError::InvalidArgument(format!(
            "no unbiased PSD bin in the limit band [{}, {}] mm^-1",
            line.f1_per_mm, line.f2_per_mm
        )));
    }
    Ok(LimitCheck {
        line: *line,
        sidedness: if line.two_sided {
            "two-sided"
        } else {
            "one-sided"
        },
        worst_ratio: worst,
        worst_freq_per_mm: at,
        bins_tested: n,
        pass: worst <= 1.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lines::Axis;
    use crate::window::Window;

    #[test]
    fn power_law_psd_sits_exactly_on_its_own_line() {
        let df = 0.01;
        let n = 200;
        let f: Vec<f64> = (0..n).map(|k| k as f64 * df).collect();
        let p: Vec<f64> = f
            .iter()
            .map(|&f| if f > 0.0 { 3.0 * f.powf(-1.5) } else { 0.0 })
            .collect();
        let psd = Psd1d {
            axis: Axis::Y,
            freq_per_mm: f,
            psd_nm2_mm: p,
            df_per_mm: df,
            spacing_mm: 0.25, // Nyquist 2 mm^-1 is not a bin here: every bin is doubled
            window: Window::Hann,
            enbw_bins: 1.5,
            n_lines: 1,
            n_segments: 1,
            biased_bins: 3,
            removed: vec![],
        };
        let one = LimitLine {
            a: 3.0,
            b: 1.5,
            f1_per_mm: 0.1,
            f2_per_mm: 1.0,
            two_sided: false,
        };
        let c = check_limit(&psd, &one).unwrap();
        assert!((c.worst_ratio - 1.0).abs() < 1e-12 && c.pass);
        assert_eq!(c.bins_tested, 91);
        let two = LimitLine {
            a: 1.0,
            two_sided: true,
            ..one
        };
        let c = check_limit(&psd, &two).unwrap();
        assert!((c.worst_ratio - 1.5).abs() < 1e-12 && !c.pass);
    }
}
