//! From mechanism maps to the numbers a run report needs: MSF band RMS along Y (feed) of each
//! mechanism's removal, its share, the Y ripple σ1 at 1/pitch of the predicted removal, per
//! bonnet; and the spindle-speed sweep.
//!
//! Conventions: PSDs are bonnetlab_spectrum's one-sided Y PSDs (Hann window, piston and tilt
//! removed, over the valid pixels); the band is `CouplingOptions::msf_band_per_mm`, upper edge
//! clipped to Nyquist. A mechanism's `share` is its band power over the summed band power of all
//! mechanisms and the interaction term (powers add when the contributions are uncorrelated; the
//! total's own band RMS is reported beside them so a correlated sum can be seen).

use super::fast::fast_maps;
use super::{CouplingInput, CouplingOptions, MechanismMaps, Mechanisms};
use crate::error::VibrationError;
use crate::params::{Bonnet, VibrationParams};
use crate::response::forced_response;
use bonnetlab_spectrum::{band_rms, psd_y, ripple, PsdOptions};
use bonnetlab_surface::Surface;
use ndarray::Array2;
use serde::Serialize;

/// One mechanism's part of the predicted MSF.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MechanismResult {
    pub name: String,
    pub enabled: bool,
    /// Band RMS (Y, MSF band) of this mechanism's removal contribution, nm.
    pub msf_band_rms_nm: f64,
    /// Band power share among the mechanisms and their interaction (sums to 1 when any is > 0).
    pub share: f64,
}

/// The coupling's prediction for one bonnet.
#[derive(Debug, Clone, Serialize)]
pub struct BonnetPrediction {
    pub bonnet: Bonnet,
    pub spindle_rpm: f64,
    pub msf_band_per_mm: (f64, f64),
    /// MSF band RMS of the predicted removal, of the baseline (no vibration, commanded dwell) and
    /// of their difference, nm.
    pub removal_msf_band_rms_nm: f64,
    pub baseline_msf_band_rms_nm: f64,
    pub induced_msf_band_rms_nm: f64,
    /// σ1 at 1/pitch along Y of the predicted and of the baseline removal, nm (None without a
    /// pitch or when the map is too short for the ripple band).
    pub ripple_sigma1_nm: Option<f64>,
    pub baseline_ripple_sigma1_nm: Option<f64>,
    pub mechanisms: Vec<MechanismResult>,
    #[serde(skip)]
    pub maps: MechanismMaps,
}

impl BonnetPrediction {
    /// The predicted removal map (nm, the map grid).
    pub fn removal_nm(&self) -> Array2<f64> {
        self.maps.total()
    }
}

fn surface(input: &CouplingInput<'_>, map: &Array2<f64>) -> Result<Surface, VibrationError> {
    let valid = match input.valid {
        Some(v) => v.clone(),
        None => Array2::from_elem(map.dim(), true),
    };
    Surface::with_mask(
        map.clone(),
        valid,
        Some(input.grid.dx_mm),
        Some(input.grid.dy_mm),
    )
    .map_err(|e| VibrationError::InvalidArgument(e.to_string()))
}

/// MSF band RMS along Y of a map on the input's grid, nm.
pub fn msf_band_rms_y(
    input: &CouplingInput<'_>,
    map: &Array2<f64>,
    band: (f64, f64),
) -> Result<f64, VibrationError> {
    if map.iter().all(|&v| v == 0.0) {
        return Ok(0.0);
    }
    let s = surface(input, map)?;
    let psd = psd_y(&s, &PsdOptions::default())
        .map_err(|e| VibrationError::InvalidArgument(e.to_string()))?;
    let nyq = 0.5 / input.grid.dy_mm;
    Ok(band_rms(&psd, band.0, band.1.min(nyq)))
}

fn sigma1(input: &CouplingInput<'_>, map: &Array2<f64>) -> Option<f64> {
    let pitch = input.pitch_mm?;
    let s = surface(input, map).ok()?;
    ripple(&s, pitch, &PsdOptions::default())
        .ok()
        .map(|r| r.sigma1_nm)
}

/// Predicted removal and per-mechanism MSF for one bonnet (fast method).
pub fn predict(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
) -> Result<BonnetPrediction, VibrationError> {
    let maps = fast_maps(input, bonnet, opts)?;
    let band = opts.msf_band_per_mm;
    let total = maps.total();
    let mut mechanisms = Vec::new();
    for name in Mechanisms::NAMES
        .iter()
        .chain(std::iter::once(&"interaction"))
    {
        let map = maps
            .by_name(name)
            .ok_or_else(|| VibrationError::InvalidArgument(name.to_string()))?;
        let enabled = *name == "interaction" || opts.mechanisms.is_on(name);
        mechanisms.push(MechanismResult {
            name: name.to_string(),
            enabled,
            msf_band_rms_nm: msf_band_rms_y(input, map, band)?,
            share: 0.0,
        });
    }
    let power: f64 = mechanisms
        .iter()
        .map(|m| m.msf_band_rms_nm * m.msf_band_rms_nm)
        .sum();
    if power > 0.0 {
        for m in &mut mechanisms {
            m.share = m.msf_band_rms_nm * m.msf_band_rms_nm / power;
        }
    }
    Ok(BonnetPrediction {
        bonnet,
        spindle_rpm: input.params.spindle_rpm,
        msf_band_per_mm: (band.0, band.1.min(0.5 / input.grid.dy_mm)),
        removal_msf_band_rms_nm: msf_band_rms_y(input, &total, band)?,
        baseline_msf_band_rms_nm: msf_band_rms_y(input, &maps.baseline, band)?,
        induced_msf_band_rms_nm: msf_band_rms_y(input, &maps.induced(), band)?,
        ripple_sigma1_nm: sigma1(input, &total),
        baseline_ripple_sigma1_nm: sigma1(input, &maps.baseline),
        mechanisms,
        maps,
    })
}

/// [`predict`] for the original and the suppression bonnet.
pub fn predict_both(
    input: &CouplingInput<'_>,
    opts: &CouplingOptions,
) -> Result<Vec<BonnetPrediction>, VibrationError> {
    Bonnet::ALL
        .iter()
        .map(|&b| predict(input, b, opts))
        .collect()
}

/// One row of the spindle-speed sweep.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepRow {
    pub spindle_rpm: f64,
    pub bonnet: Bonnet,
    pub x1_amplitude_mm: f64,
    pub x2_amplitude_mm: f64,
    pub offset_amplitude_mm: f64,
    pub induced_msf_band_rms_nm: f64,
    pub ripple_sigma1_nm: Option<f64>,
    pub mechanisms: Vec<MechanismResult>,
}

/// Default sweep speeds: 250 to 2000 rpm in steps of 125 rpm.
pub fn default_sweep_rpm() -> Vec<f64> {
    (0..=14).map(|k| 250.0 + 125.0 * k as f64).collect()
}

/// Runs [`predict`] at each spindle speed for each bonnet (rows ordered by speed, then bonnet).
pub fn spindle_sweep(
    input: &CouplingInput<'_>,
    opts: &CouplingOptions,
    rpms: &[f64],
) -> Result<Vec<SweepRow>, VibrationError> {
    let mut rows = Vec::new();
    for &rpm in rpms {
        let params = VibrationParams {
            spindle_rpm: rpm,
            ..input.params.clone()
        };
        params.validate()?;
        let inp = CouplingInput {
            params: &params,
            ..*input
        };
        for bonnet in Bonnet::ALL {
            let pred = predict(&inp, bonnet, opts)?;
            let r = forced_response(&params, bonnet, rpm);
            rows.push(SweepRow {
                spindle_rpm: rpm,
                bonnet,
                x1_amplitude_mm: r.x1_amplitude_mm,
                x2_amplitude_mm: r.x2_amplitude_mm,
                offset_amplitude_mm: r.offset_amplitude_mm,
                induced_msf_band_rms_nm: pred.induced_msf_band_rms_nm,
                ripple_sigma1_nm: pred.ripple_sigma1_nm,
                mechanisms: pred.mechanisms,
            });
        }
    }
    Ok(rows)
}
