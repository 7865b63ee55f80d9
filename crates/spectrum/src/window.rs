//! Data windows for spectral estimation, in their *periodic* form (the DFT-even form: a length-n
//! window is the first n samples of the symmetric length-(n+1) window), which is what makes the
//! periodic Hann window's ENBW exactly 1.5 bins and its U exactly 0.375.
//!
//! For a window w of length n: U = mean(w^2) (the power correction of the PSD) and
//! ENBW = n sum(w^2) / (sum w)^2 in bins (the peak of a pure tone in the PSD is its power divided
//! by ENBW * df, which is why amplitudes must never be read off peak heights).

use std::f64::consts::PI;
use std::fmt;

use serde::{Serialize, Serializer};

use crate::error::SpectrumError;

/// A data window.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Window {
    /// Rectangular (no window): U = 1, ENBW = 1 bin.
    None,
    /// Periodic Hann: U = 0.375, ENBW = 1.5 bins. The default.
    #[default]
    Hann,
    /// Tukey (tapered cosine) with taper fraction alpha in [0, 1]: 0 is rectangular, 1 is Hann.
    Tukey(f64),
    /// Periodic Blackman (0.42, 0.5, 0.08): ENBW about 1.73 bins.
    Blackman,
    /// Periodic Welch (parabolic): ENBW 1.2 bins.
    Welch,
}

impl Window {
    /// Parses `hann`, `none`, `tukey` (alpha = `tukey_alpha`), `tukey:0.3`, `blackman`, `welch`.
    pub fn parse(s: &str, tukey_alpha: f64) -> Result<Window, SpectrumError> {
        let t = s.trim().to_ascii_lowercase();
        let w = match t.as_str() {
            "hann" | "hanning" => Window::Hann,
            "none" | "rect" | "rectangular" | "boxcar" => Window::None,
            "blackman" => Window::Blackman,
            "welch" => Window::Welch,
            "tukey" => Window::Tukey(tukey_alpha),
            _ => match t
                .strip_prefix("tukey:")
                .or_else(|| t.strip_prefix("tukey="))
            {
                Some(a) => Window::Tukey(a.parse::<f64>().map_err(|_| {
                    SpectrumError::InvalidArgument(format!("tukey alpha '{a}' is not a number"))
                })?),
                None => {
                    return Err(SpectrumError::InvalidArgument(format!(
                        "unknown window '{s}' (expected hann, none, tukey, blackman, welch)"
                    )))
                }
            },
        };
        w.validate()?;
        Ok(w)
    }

    /// Checks the parameter (Tukey alpha in [0, 1]).
    pub fn validate(&self) -> Result<(), SpectrumError> {
        if let Window::Tukey(a) = self {
            if !(a.is_finite() && (0.0..=1.0).contains(a)) {
                return Err(SpectrumError::InvalidArgument(format!(
                    "tukey alpha must be in [0, 1], got {a}"
                )));
            }
        }
        Ok(())
    }

    /// Name as printed and written to JSON: `hann`, `none`, `tukey(0.5)`, `blackman`, `welch`.
    pub fn name(&self) -> String {
        match self {
            Window::None => "none".into(),
            Window::Hann => "hann".into(),
            Window::Tukey(a) => format!("tukey({a})"),
            Window::Blackman => "blackman".into(),
            Window::Welch => "welch".into(),
        }
    }

    /// Window value at sample i of a length-n periodic window.
    pub fn value(&self, i: usize, n: usize) -> f64 {
        if n <= 1 {
            return 1.0;
        }
        let x = i as f64 / n as f64; // in [0, 1): periodic form
        match *self {
            Window::None => 1.0,
            Window::Hann => 0.5 - 0.5 * (2.0 * PI * x).cos(),
            Window::Blackman => 0.42 - 0.5 * (2.0 * PI * x).cos() + 0.08 * (4.0 * PI * x).cos(),
            Window::Welch => {
                let u = 2.0 * x - 1.0;
                1.0 - u * u
            }
            Window::Tukey(a) => {
                if a <= 0.0 {
                    1.0
                } else if x < a / 2.0 {
                    0.5 - 0.5 * (2.0 * PI * x / a).cos()
                } else if x > 1.0 - a / 2.0 {
                    0.5 - 0.5 * (2.0 * PI * (1.0 - x) / a).cos()
                } else {
                    1.0
                }
            }
        }
    }

    /// The n window coefficients.
    pub fn coefficients(&self, n: usize) -> Vec<f64> {
        (0..n).map(|i| self.value(i, n)).collect()
    }

    /// Writes the n coefficients into `out` (resized), avoiding an allocation per segment.
    pub fn fill(&self, n: usize, out: &mut Vec<f64>) {
        out.clear();
        out.extend((0..n).map(|i| self.value(i, n)));
    }

    /// U = mean(w^2) for length n.
    pub fn power_correction(&self, n: usize) -> f64 {
        let w = self.coefficients(n);
        w.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64
    }

    /// Equivalent noise bandwidth in bins for length n: n sum(w^2) / (sum w)^2.
    pub fn enbw_bins(&self, n: usize) -> f64 {
        let w = self.coefficients(n);
        let s1: f64 = w.iter().sum();
        let s2: f64 = w.iter().map(|v| v * v).sum();
        n as f64 * s2 / (s1 * s1)
    }

    /// Half-width of the main lobe in bins (rounded up): the bins next to DC within it are
    /// biased by the removed mean / trend.
    pub fn main_lobe_half_width_bins(&self) -> usize {
        match self {
            Window::None => 1,
            Window::Hann | Window::Welch | Window::Tukey(_) => 2,
            Window::Blackman => 3,
        }
    }
}

impl fmt::Display for Window {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

impl Serialize for Window {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn hann_has_textbook_u_and_enbw() {
        for n in [8, 600, 1024] {
            assert_relative_eq!(Window::Hann.power_correction(n), 0.375, epsilon = 1e-12);
            assert_relative_eq!(Window::Hann.enbw_bins(n), 1.5, epsilon = 1e-12);
        }
        assert_relative_eq!(Window::None.enbw_bins(100), 1.0);
        // Blackman periodic: ENBW = (0.42^2 + 0.5^2/2 + 0.08^2/2) / 0.42^2 exactly.
        let b = (0.42f64.powi(2) + 0.125 + 0.0032) / 0.42f64.powi(2);
        assert_relative_eq!(Window::Blackman.enbw_bins(512), b, epsilon = 1e-12);
        // Welch periodic: mean(w) -> 2/3, mean(w^2) -> 8/15, ENBW -> 1.2 as n grows.
        assert_relative_eq!(Window::Welch.enbw_bins(4096), 1.2, epsilon = 1e-5);
    }

    #[test]
    fn tukey_limits_are_rect_and_hann() {
        let n = 64;
        let h = Window::Hann.coefficients(n);
        let t1 = Window::Tukey(1.0).coefficients(n);
        for (a, b) in h.iter().zip(&t1) {
            assert_relative_eq!(a, b, epsilon = 1e-12);
        }
        assert!(Window::Tukey(0.0).coefficients(n).iter().all(|&v| v == 1.0));
        assert!(Window::Tukey(1.5).validate().is_err());
    }

    #[test]
    fn parse_names() {
        assert_eq!(Window::parse("Hann", 0.5).unwrap(), Window::Hann);
        assert_eq!(Window::parse("tukey", 0.25).unwrap(), Window::Tukey(0.25));
        assert_eq!(Window::parse("tukey:0.1", 0.5).unwrap(), Window::Tukey(0.1));
        assert!(Window::parse("kaiser", 0.5).is_err());
        assert_eq!(Window::Tukey(0.5).name(), "tukey(0.5)");
    }
}
