//! ISO 25178-2 style height parameters on the valid pixels, about their mean.
//!
//! Sq (RMS) and Sa are about the mean of the valid heights; Sp / Sv are the highest peak and
//! deepest valley from that mean; Sz = Sp + Sv = PV. Sku is the plain fourth moment ratio
//! (3 for a Gaussian surface; Gwyddion prints the excess, 0). Invalid pixels are ignored.

use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::surface::Surface;

/// Height parameters of a map (nm unless dimensionless).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HeightStats {
    /// Not serialized (nor `mean_nm`): a report states the count beside what was removed and
    /// the parameters from `pv_nm` on (`stats --json`, flattening this struct).
    #[serde(skip_serializing, default)]
    pub valid: usize,
    #[serde(skip_serializing, default)]
    pub mean_nm: f64,
    pub pv_nm: f64,
    pub rms_nm: f64,
    pub sa_nm: f64,
    pub sp_nm: f64,
    pub sv_nm: f64,
    pub sz_nm: f64,
    /// Skewness and kurtosis: `None` for a flat map (RMS 0), where they are 0 / 0.
    pub ssk: Option<f64>,
    pub sku: Option<f64>,
}

/// Computes the height parameters of the valid pixels (after whatever form was removed).
pub fn height_stats(s: &Surface) -> Result<HeightStats, SurfaceError> {
    let n = s.valid_count();
    if n == 0 {
        return Err(SurfaceError::NoValidPixel);
    }
    let nf = n as f64;
    // Two passes (mean, then central moments) for accuracy on maps with a large piston.
    let mean = s.valid_heights().sum::<f64>() / nf;
    let (mut m2, mut m3, mut m4, mut sa) = (0.0, 0.0, 0.0, 0.0);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for h in s.valid_heights() {
        let d = h - mean;
        let d2 = d * d;
        m2 += d2;
        m3 += d2 * d;
        m4 += d2 * d2;
        sa += d.abs();
        lo = lo.min(d);
        hi = hi.max(d);
    }
    let var = m2 / nf;
    let rms = var.sqrt();
    let (ssk, sku) = if var > 0.0 {
        (Some(m3 / nf / (var * rms)), Some(m4 / nf / (var * var)))
    } else {
        (None, None)
    };
    Ok(HeightStats {
        valid: n,
        mean_nm: mean,
        pv_nm: hi - lo,
        rms_nm: rms,
        sa_nm: sa / nf,
        sp_nm: hi,
        // + 0.0: a flat map's valley is 0, not -0.
        sv_nm: -lo + 0.0,
        sz_nm: hi - lo,
        ssk,
        sku,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat map: RMS 0, skewness and kurtosis undefined (None, not 0), no -0 valley.
    #[test]
    fn a_flat_map_has_no_shape_moments() {
        let s = Surface::new(Array2::from_elem((4, 5), 7.0), Some(1.0), Some(1.0)).unwrap();
        let st = height_stats(&s).unwrap();
        assert_eq!((st.rms_nm, st.ssk, st.sku), (0.0, None, None));
        assert!(st.sv_nm == 0.0 && st.sv_nm.is_sign_positive());
    }
    use ndarray::Array2;
    use std::f64::consts::PI;

    #[test]
    fn sine_has_analytic_parameters() {
        // Whole periods: 60 mm at 3 mm pitch, 600 samples.
        let a = 10.0;
        let z = Array2::from_shape_fn((8, 600), |(_, j)| {
            a * (2.0 * PI * j as f64 * 0.1 / 3.0).sin()
        });
        let s = Surface::new(z, Some(0.1), Some(0.1)).unwrap();
        let st = height_stats(&s).unwrap();
        assert!((st.rms_nm - a / 2f64.sqrt()).abs() < 1e-9);
        assert!(st.ssk.unwrap().abs() < 1e-9);
        assert!((st.sku.unwrap() - 1.5).abs() < 1e-9);
        // Sa and PV of the sampled sine, by brute force over one period of 30 samples.
        let samples: Vec<f64> = (0..30)
            .map(|j| a * (2.0 * PI * j as f64 / 30.0).sin())
            .collect();
        let sa = samples.iter().map(|v| v.abs()).sum::<f64>() / 30.0;
        let pv = samples.iter().cloned().fold(f64::MIN, f64::max)
            - samples.iter().cloned().fold(f64::MAX, f64::min);
        assert!((st.sa_nm - sa).abs() < 1e-9, "{} vs {sa}", st.sa_nm);
        assert!((st.pv_nm - pv).abs() < 1e-9);
        assert!((st.sa_nm - 2.0 * a / PI).abs() < 0.01 * a);
    }

    #[test]
    fn empty_map_is_an_error() {
        let s = Surface::new(Array2::from_elem((2, 2), f64::NAN), None, None).unwrap();
        assert_eq!(height_stats(&s), Err(SurfaceError::NoValidPixel));
    }
}
