//! Gaussian TIF truncated to a disc: rate = peak exp(-r^2 / (2 sigma^2)) for r <= d/2, else 0.
//! The model of the public dwell-time cases (`shared/data/dwell`) and of ion-beam figuring.

use serde::{Deserialize, Serialize};

use super::RateField;
use crate::error::ProcessError;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GaussianTif {
    pub sigma_mm: f64,
    pub diameter_mm: f64,
    pub peak_rate_nm_per_s: f64,
}

impl GaussianTif {
    pub fn new(
        sigma_mm: f64,
        diameter_mm: f64,
        peak_rate_nm_per_s: f64,
    ) -> Result<GaussianTif, ProcessError> {
        for (name, v) in [("sigma_mm", sigma_mm), ("diameter_mm", diameter_mm)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ProcessError::invalid(format!(
                    "{name} must be positive, got {v}"
                )));
            }
        }
        if !(peak_rate_nm_per_s.is_finite() && peak_rate_nm_per_s >= 0.0) {
            return Err(ProcessError::invalid("peak_rate_nm_per_s must be >= 0"));
        }
        Ok(GaussianTif {
            sigma_mm,
            diameter_mm,
            peak_rate_nm_per_s,
        })
    }
}

impl RateField for GaussianTif {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        let r2 = dx_mm * dx_mm + dy_mm * dy_mm;
        let rad = self.diameter_mm / 2.0;
        if r2 > rad * rad * (1.0 + 1e-12) {
            0.0
        } else {
            self.peak_rate_nm_per_s * (-r2 / (2.0 * self.sigma_mm * self.sigma_mm)).exp()
        }
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        (self.diameter_mm / 2.0, self.diameter_mm / 2.0)
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        let s2 = self.sigma_mm * self.sigma_mm;
        let r2 = self.diameter_mm * self.diameter_mm / 4.0;
        Some(
            2.0 * std::f64::consts::PI
                * s2
                * self.peak_rate_nm_per_s
                * (1.0 - (-r2 / (2.0 * s2)).exp()),
        )
    }
}
