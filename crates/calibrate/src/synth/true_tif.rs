//! The generator's true tool influence function: one of the process crate's analytic models
//! (a truncated Gaussian or the paper's precessing bonnet), evaluated exactly at any offset by
//! the exact deposition. The calibration never sees it: it sees a noisy measured spot map.

use bonnetlab_process::tif::bonnet::BonnetTif;
use bonnetlab_process::tif::{BonnetTifParams, GaussianTif, RateField};

use crate::error::CalibrateError;

#[derive(Debug, Clone, PartialEq)]
pub enum TrueTif {
    Gaussian(GaussianTif),
    Bonnet(BonnetTifParams),
}

impl Default for TrueTif {
    /// A Gaussian of sigma 2 mm, peak 30 nm/s, truncated at 7 mm radius.
    fn default() -> Self {
        TrueTif::Gaussian(GaussianTif {
            sigma_mm: 2.0,
            diameter_mm: 14.0,
            peak_rate_nm_per_s: 30.0,
        })
    }
}

impl TrueTif {
    /// The paper's precessing bonnet (R 20 mm, h 0.6 mm, 20 deg, Hertz) with a given volume
    /// rate (nm mm^2 / s).
    pub fn bonnet(volume_nm_mm2_per_s: f64) -> TrueTif {
        let mut p = BonnetTifParams::paper(1.0);
        p.scale = bonnetlab_process::tif::RateScale::VolumeNmMm2PerS(volume_nm_mm2_per_s);
        TrueTif::Bonnet(p)
    }

    /// The evaluable rate field.
    pub fn field(&self) -> Result<Box<dyn RateField>, CalibrateError> {
        let err = |e: bonnetlab_process::ProcessError| CalibrateError::InvalidInput(e.to_string());
        Ok(match self {
            TrueTif::Gaussian(g) => Box::new(
                GaussianTif::new(g.sigma_mm, g.diameter_mm, g.peak_rate_nm_per_s).map_err(err)?,
            ),
            TrueTif::Bonnet(p) => Box::new(BonnetTif::new(p).map_err(err)?),
        })
    }
}
