//! Seeded synthetic spot maps from the bonnet model: the dip a spot of `dwell_s` seconds leaves,
//! plus piston, tilt, white measurement noise and a centre away from the map's middle. Used by
//! the tests (where the truth is the model's own metrics) and for the committed sample sweep.
//!
//! Heights are point samples of the model at pixel centres (an interferometer pixel is far
//! smaller than the spot), origin (0, 0) at pixel (0, 0) as spec/interfaces.md says.

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::{Provenance, Surface};

use crate::error::SpotsError;
use crate::model::{BonnetModel, Factors};

/// Everything that defines one synthetic spot map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpotSpec {
    pub model: BonnetModel,
    pub factors: Factors,
    pub dwell_s: f64,
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// Spot centre minus the map's middle, mm.
    pub centre_offset_mm: (f64, f64),
    pub piston_nm: f64,
    /// Tilt along x and y, nm per mm.
    pub tilt_nm_per_mm: (f64, f64),
    /// Standard deviation of white noise, nm.
    pub noise_rms_nm: f64,
    pub seed: u64,
}

impl SpotSpec {
    /// Centre of the spot in map coordinates (mm).
    pub fn centre_mm(&self) -> (f64, f64) {
        (
            0.5 * (self.cols as f64 - 1.0) * self.dx_mm + self.centre_offset_mm.0,
            0.5 * (self.rows as f64 - 1.0) * self.dy_mm + self.centre_offset_mm.1,
        )
    }
}

/// Generates the height map (nm) of the spot.
pub fn generate_spot(spec: &SpotSpec) -> Result<Surface, SpotsError> {
    if spec.rows < 8 || spec.cols < 8 {
        return Err(SpotsError::Model(format!(
            "map {}x{} is too small",
            spec.rows, spec.cols
        )));
    }
    if !(spec.dx_mm > 0.0 && spec.dy_mm > 0.0 && spec.dwell_s > 0.0 && spec.noise_rms_nm >= 0.0) {
        return Err(SpotsError::Model(
            "pixel size and dwell must be positive, noise >= 0".into(),
        ));
    }
    let fp = spec.model.footprint(&spec.factors)?;
    let (cx, cy) = spec.centre_mm();
    let mut rng = Rng::new(spec.seed);
    let mut z = Array2::zeros((spec.rows, spec.cols));
    for ((i, j), v) in z.indexed_iter_mut() {
        let (x, y) = (j as f64 * spec.dx_mm, i as f64 * spec.dy_mm);
        let dip = fp.rate(x - cx, y - cy) * spec.dwell_s;
        *v = spec.piston_nm + spec.tilt_nm_per_mm.0 * x + spec.tilt_nm_per_mm.1 * y - dip
            + spec.noise_rms_nm * rng.normal();
    }
    let mut s = Surface::new(z, Some(spec.dx_mm), Some(spec.dy_mm))?;
    s.provenance = Provenance {
        format: "synthetic".into(),
        comment: Some(format!(
            "bonnetlab spot generator: R {} mm, k {} nm/(MPa mm), E {} MPa, seed {}",
            spec.model.radius_mm,
            spec.model.preston_nm_per_mpa_mm,
            spec.model.modulus_mpa,
            spec.seed
        )),
        ..Provenance::default()
    };
    Ok(s)
}
