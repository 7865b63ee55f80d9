//! Conversions of our PSDs to the conventions of peer tools (as options; our native form is
//! the one-sided P1(f) in nm^2 mm over f in cycles/mm, and the two-sided P2 in nm^2 mm^2).
//!
//! - Gwyddion: angular frequency K = 2 pi f (rad/mm); W1(K) = P1(f) / (4 pi), a density over
//!   both signs of K, so the mean square is the integral of W1 over -inf..inf;
//!   W(K) = P2 / (4 pi^2) in 2-D.
//! - SurfaceTopography: q = 2 pi f (rad/mm); C1D(q) = P1(f) / 2, with mean square
//!   (1/pi) * integral over 0..inf of C1D dq; C2D = P2 (and prysm's psd() is P2 as well).

use serde::Serialize;

use crate::psd1d::Psd1d;

/// A PSD expressed in another tool's convention.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConvertedPsd {
    /// `gwyddion-w1` or `surfacetopography-c1d`.
    pub convention: &'static str,
    /// Angular spatial frequency, rad/mm.
    pub q_rad_per_mm: Vec<f64>,
    /// Density values, nm^2 mm (per rad/mm of angular frequency, in that tool's sidedness).
    pub values_nm2_mm: Vec<f64>,
}

/// Gwyddion's W1(K), K = 2 pi f.
pub fn to_gwyddion_w1(psd: &Psd1d) -> ConvertedPsd {
    ConvertedPsd {
        convention: "gwyddion-w1",
        q_rad_per_mm: psd
            .freq_per_mm
            .iter()
            .map(|f| 2.0 * std::f64::consts::PI * f)
            .collect(),
        values_nm2_mm: psd
            .psd_nm2_mm
            .iter()
            .map(|p| p / (4.0 * std::f64::consts::PI))
            .collect(),
    }
}

/// SurfaceTopography's C1D(q), q = 2 pi f.
pub fn to_surfacetopography_c1d(psd: &Psd1d) -> ConvertedPsd {
    ConvertedPsd {
        convention: "surfacetopography-c1d",
        q_rad_per_mm: psd
            .freq_per_mm
            .iter()
            .map(|f| 2.0 * std::f64::consts::PI * f)
            .collect(),
        values_nm2_mm: psd.psd_nm2_mm.iter().map(|p| p / 2.0).collect(),
    }
}

/// Gwyddion's 2-D W(K) from our two-sided P2 (nm^2 mm^2 per (rad/mm)^2).
pub fn p2_to_gwyddion_w(p2_nm2_mm2: f64) -> f64 {
    p2_nm2_mm2 / (4.0 * std::f64::consts::PI * std::f64::consts::PI)
}

/// SurfaceTopography's C2D (and prysm's psd()) equal our P2.
pub fn p2_to_surfacetopography_c2d(p2_nm2_mm2: f64) -> f64 {
    p2_nm2_mm2
}
