//! The generator's "true" tool influence function: an analytic, deliberately non-Gaussian spot
//! (a Gaussian core with a shoulder, elliptical, with a compact smooth window), evaluated exactly
//! at any offset. The calibration never sees it: it sees a noisy measured spot map of it.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueTif {
    pub peak_nm_per_s: f64,
    /// Gaussian widths along x and y (mm).
    pub sigma_x_mm: f64,
    pub sigma_y_mm: f64,
    /// Shoulder strength: rate * (1 + shoulder * rho^2) / norm.
    pub shoulder: f64,
    /// Compact support radius (mm): smooth window (1 - (r / R)^2)^2.
    pub radius_mm: f64,
}

impl Default for TrueTif {
    fn default() -> Self {
        TrueTif {
            peak_nm_per_s: 30.0,
            sigma_x_mm: 2.0,
            sigma_y_mm: 1.8,
            shoulder: 0.25,
            radius_mm: 7.5,
        }
    }
}

impl TrueTif {
    /// Rate at offset (x, y) mm from the tool centre, for a spot widened by `scale`.
    pub fn rate(&self, x: f64, y: f64, scale: f64) -> f64 {
        let (x, y) = (x / scale, y / scale);
        let r2 = x * x + y * y;
        let rr = self.radius_mm * self.radius_mm;
        if r2 >= rr {
            return 0.0;
        }
        let rho2 = (x / self.sigma_x_mm).powi(2) + (y / self.sigma_y_mm).powi(2);
        let w = (1.0 - r2 / rr).powi(2);
        self.peak_nm_per_s * (-0.5 * rho2).exp() * (1.0 + self.shoulder * rho2) * w
    }
}
