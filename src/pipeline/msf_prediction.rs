//! The vibration coupling's predicted MSF per bonnet on a run matching the bundled sample (the
//! demo report's "Predicted MSF per bonnet" section and the `predicted_msf` array of its
//! report.json; rendered by `crate::report::msf_prediction`).
//!
//! Conventions: band RMS values are along Y (feed), from one-sided Y PSDs, in nm; `share` is a
//! fraction of the summed band power of the mechanisms and their interaction (as the vibration
//! crate defines it); the band edges are in cycles/mm with the upper edge clipped to Nyquist.

use serde::Serialize;

use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::tif::bonnet::BonnetTifParams;
use bonnetlab_vibration::coupling::predict::{BonnetPrediction, MechanismResult};
use bonnetlab_vibration::coupling::{predict_both, CouplingCase, CouplingOptions};
use bonnetlab_vibration::error::VibrationError;
use bonnetlab_vibration::params::VibrationParams;

use super::samples::{SAMPLE_N, SAMPLE_PITCH_MM, SAMPLE_PIXEL_MM};
use super::Error;

/// The run the prediction was made for (what a reader needs to reproduce it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictionRun {
    pub part_mm: (f64, f64),
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// TIF model, e.g. "paper bonnet (R 20 mm, Hertz pressure, four-step precession)".
    pub tif: String,
    pub tif_peak_rate_nm_per_s: f64,
    pub pitch_mm: f64,
    pub feed_mm_per_s: f64,
    pub spindle_rpm: f64,
    pub offset_mm: f64,
    pub precession_deg: f64,
    pub inner_pressure_mpa: f64,
    pub sample_hz: f64,
    pub seed: u64,
}

/// One bonnet's entry of `predicted_msf`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictedMsf {
    pub bonnet: String,
    pub run: PredictionRun,
    /// MSF band along Y, cycles/mm (upper edge clipped to Nyquist).
    pub msf_band_per_mm: (f64, f64),
    /// σ1 at 1/pitch along Y of the predicted and of the baseline removal, nm.
    pub ripple_sigma1_nm: Option<f64>,
    pub baseline_ripple_sigma1_nm: Option<f64>,
    /// MSF band RMS (Y) of the predicted removal, of the baseline and of the induced part, nm.
    pub removal_msf_band_rms_nm: f64,
    pub baseline_msf_band_rms_nm: f64,
    pub induced_msf_band_rms_nm: f64,
    pub mechanisms: Vec<MechanismResult>,
    pub assumptions: String,
}

/// The model's assumptions, stated once for the HTML and the JSON (values from the vibration
/// crate's documented defaults, bonnetlab_vibration::params).
pub const ASSUMPTIONS: &str = "The robot is modelled as two principal modes from the paper's \
stiffness matrix (k1 = 1.476e3, k2 = 3.289e2 N/mm, theta = 13.2 deg) with equivalent masses from \
the measured natural frequencies and the vibration crate's documented default modal damping, \
driven by the contact force F_n (mu, 1) sin(wt) at the spindle frequency (default force and \
friction coefficient), its harmonics, seeded broadband force noise and the ring-down after each \
raster line reversal executed at the acceleration limit. The suppression bonnet adds damping \
zeta_e = eta / 2 = 0.0575 in both principal directions and a series compliance (wave spring \
50 N/mm, assumed) in front of the inflated bonnet's contact stiffness. Removal depends on the \
offset non-linearly (spot radius and peak pressure grow with offset, Hertzian exponent 0.5); the \
four mechanisms (normal offset, lateral spot jitter, slow envelope, acceleration-limited dwell \
execution) are computed with the fast expansion of the vibration crate (second order, the \
offset to fourth), which is \
validated against direct deposition of the instantaneous TIF. Shares are band powers over the \
summed power of the mechanisms and their interaction, so they describe uncorrelated parts; the \
prediction is for a uniform raster of the whole part (no dwell correction), not a fit to the \
measured maps.";

impl PredictedMsf {
    pub fn new(run: PredictionRun, p: &BonnetPrediction) -> PredictedMsf {
        let bonnet = match p.bonnet {
            bonnetlab_vibration::params::Bonnet::Original => "original",
            bonnetlab_vibration::params::Bonnet::Suppression => "suppression",
        };
        PredictedMsf {
            bonnet: bonnet.to_string(),
            run,
            msf_band_per_mm: p.msf_band_per_mm,
            ripple_sigma1_nm: p.ripple_sigma1_nm,
            baseline_ripple_sigma1_nm: p.baseline_ripple_sigma1_nm,
            removal_msf_band_rms_nm: p.removal_msf_band_rms_nm,
            baseline_msf_band_rms_nm: p.baseline_msf_band_rms_nm,
            induced_msf_band_rms_nm: p.induced_msf_band_rms_nm,
            mechanisms: p.mechanisms.clone(),
            assumptions: ASSUMPTIONS.to_string(),
        }
    }
}

/// Peak removal rate of the paper-bonnet TIF in the prediction, nm/s (scales every band RMS
/// linearly; chosen so a 100 mm raster removes of the order of a micrometre).
pub const PREDICTION_TIF_PEAK_NM_PER_S: f64 = 10.0;
/// Feed of the prediction's raster, mm/s (the paper's).
pub const PREDICTION_FEED_MM_PER_S: f64 = 1.6;

/// Inner pressure of the prediction's bonnet, MPa.
pub const PREDICTION_INNER_PRESSURE_MPA: f64 = 0.25;

/// The prediction's run: the 100 x 100 mm part on the sample's grid, the paper's bonnet TIF,
/// a 3 mm bidirectional raster at the paper's feed, the vibration crate's defaults at
/// [`PREDICTION_INNER_PRESSURE_MPA`] with the TIF's spindle speed and offset.
pub fn prediction_case() -> Result<CouplingCase, VibrationError> {
    let (n, d) = (SAMPLE_N, SAMPLE_PIXEL_MM);
    let tif_params = BonnetTifParams::paper(PREDICTION_TIF_PEAK_NM_PER_S);
    let params = VibrationParams::from_parts(
        None,
        Some(tif_params.spindle_rpm),
        Some(tif_params.offset_mm),
        Some(PREDICTION_INNER_PRESSURE_MPA),
        None,
    )?;
    CouplingCase::square_raster(
        &TifSource::Bonnet(tif_params),
        params,
        n,
        d,
        0.5 * d,
        n as f64 * d,
        SAMPLE_PITCH_MM,
        PREDICTION_FEED_MM_PER_S,
        0.0,
    )
}

/// The vibration coupling for both bonnets on a run matching the sample: the 100 x 100 mm part
/// on the sample's grid, the paper's bonnet TIF (R 20 mm, offset 0.6 mm, precession 20 deg,
/// 1000 rpm), a 3 mm bidirectional raster and the vibration crate's defaults at 0.25 MPa.
pub fn predicted_msf() -> Result<Vec<PredictedMsf>, Error> {
    let perr = |e: &dyn std::fmt::Display| Error {
        code: 1,
        message: format!("demo: predicted MSF: {e}"),
    };
    let case = prediction_case().map_err(|e| perr(&e))?;
    let (n, d) = (SAMPLE_N, SAMPLE_PIXEL_MM);
    let part_mm = n as f64 * d;
    let tif_params = BonnetTifParams::paper(PREDICTION_TIF_PEAK_NM_PER_S);
    let inner_pressure_mpa = PREDICTION_INNER_PRESSURE_MPA;
    let input = case.input();
    let opts = CouplingOptions::default();
    let preds = predict_both(&input, &opts).map_err(|e| perr(&e))?;
    let run = PredictionRun {
        part_mm: (part_mm, part_mm),
        rows: n,
        cols: n,
        dx_mm: d,
        dy_mm: d,
        tif: "paper bonnet (R 20 mm, Hertz pressure, four-step precession)".into(),
        tif_peak_rate_nm_per_s: PREDICTION_TIF_PEAK_NM_PER_S,
        pitch_mm: SAMPLE_PITCH_MM,
        feed_mm_per_s: PREDICTION_FEED_MM_PER_S,
        spindle_rpm: tif_params.spindle_rpm,
        offset_mm: tif_params.offset_mm,
        precession_deg: tif_params.precession_deg,
        inner_pressure_mpa,
        sample_hz: opts.sample_hz,
        seed: opts.seed,
    };
    Ok(preds
        .iter()
        .map(|p| PredictedMsf::new(run.clone(), p))
        .collect())
}
