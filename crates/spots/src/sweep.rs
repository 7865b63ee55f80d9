//! A whole sweep: measure every spot of a manifest, fit the model per bonnet, predict every spot
//! with its bonnet's model, and build the trends and optimisation degrees.
//!
//! The model's RMS / PV of the polished region are obtained the way the measured ones are: a
//! noise-free model spot is rendered on the measured spot's pixel size and put through
//! `measure_spot`, so the two use the same region and terms.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use bonnetlab_surface::Surface;

use crate::error::SpotsError;
use crate::fit::{fit_model, FitStart, ModelFit, Observation};
use crate::generate::{generate_spot, SpotSpec};
use crate::manifest::{Manifest, SpotEntry};
use crate::metrics::{measure_spot, SpotAnalysis, SpotMetrics, SpotOptions};
use crate::model::{BonnetModel, Factor, Factors, ModelMetrics};
use crate::trend::{
    baseline, bonnet_order, optimisation, sweeps, trend, Optimisation, Trend, TrendMetric,
};

/// The bonnet other bonnets are compared with, when present.
pub const REFERENCE_BONNET: &str = "original";

/// The model's prediction for one spot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictedSpot {
    pub contact_radius_mm: f64,
    pub peak_rate_nm_per_s: f64,
    pub volume_rate_nm_mm2_per_s: f64,
    pub fwhm_x_mm: f64,
    pub fwhm_y_mm: f64,
    pub region_rms_nm: f64,
    pub region_pv_nm: f64,
}

/// One measured spot with its settings and prediction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpotRecord {
    pub file: String,
    pub line: usize,
    pub bonnet: String,
    pub factors: Factors,
    pub sweep: Option<Factor>,
    pub metrics: SpotMetrics,
    pub predicted: Option<PredictedSpot>,
    #[serde(skip)]
    pub pixel_mm: (f64, f64),
}

/// The fit of one bonnet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BonnetFit {
    pub bonnet: String,
    pub fit: Option<ModelFit>,
    pub error: Option<String>,
    /// Preston coefficient in m^2/N (= nm/(MPa mm) x 1e-12).
    pub preston_m2_per_n: Option<f64>,
    /// The settings the saved model refers to (the sweep's baseline) and the model there.
    pub baseline: Factors,
    pub baseline_prediction: Option<ModelMetrics>,
}

/// Everything the report shows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub reference_bonnet: String,
    pub baseline: Factors,
    pub spots: Vec<SpotRecord>,
    pub fits: Vec<BonnetFit>,
    pub sweeps: Vec<Factor>,
    pub trends: Vec<Trend>,
    pub optimisation: Vec<Optimisation>,
}

/// Measures every spot; on failure returns the index of the spot and the error.
pub fn measure_entries(
    manifest: &Manifest,
    maps: &[Surface],
) -> Result<Vec<(SpotRecord, SpotAnalysis)>, (usize, SpotsError)> {
    manifest
        .spots
        .par_iter()
        .zip(maps.par_iter())
        .enumerate()
        .map(|(k, (e, s))| measure_entry(manifest, e, s).map_err(|err| (k, err)))
        .collect()
}

fn measure_entry(
    manifest: &Manifest,
    e: &SpotEntry,
    s: &Surface,
) -> Result<(SpotRecord, SpotAnalysis), SpotsError> {
    let opt = SpotOptions {
        kind: e.kind,
        ring_inner_mm: manifest.ring_inner_mm,
        ring_outer_mm: manifest.ring_outer_mm,
    };
    let a = measure_spot(s, e.dwell_s, &opt)?;
    let pixel_mm = s.pixel_mm("spot analysis")?;
    Ok((
        SpotRecord {
            file: e.file.clone(),
            line: e.line,
            bonnet: e.bonnet.clone(),
            factors: e.factors,
            sweep: e.sweep,
            metrics: a.metrics.clone(),
            predicted: None,
            pixel_mm,
        },
        a,
    ))
}

/// The model's prediction of one spot, RMS / PV included (see the module doc).
pub fn predict_spot(
    model: &BonnetModel,
    factors: &Factors,
    dwell_s: f64,
    pixel_mm: (f64, f64),
) -> Result<PredictedSpot, SpotsError> {
    let mm = model.metrics(factors)?;
    let a = mm.contact_radius_mm;
    let n = |d: f64| ((4.4 * a / d).ceil() as usize).clamp(16, 2001) | 1;
    let spec = SpotSpec {
        model: *model,
        factors: *factors,
        dwell_s,
        rows: n(pixel_mm.1),
        cols: n(pixel_mm.0),
        dx_mm: pixel_mm.0,
        dy_mm: pixel_mm.1,
        centre_offset_mm: (0.0, 0.0),
        piston_nm: 0.0,
        tilt_nm_per_mm: (0.0, 0.0),
        noise_rms_nm: 0.0,
        seed: 0,
    };
    let m = measure_spot(&generate_spot(&spec)?, dwell_s, &SpotOptions::default())?.metrics;
    Ok(PredictedSpot {
        contact_radius_mm: a,
        peak_rate_nm_per_s: mm.peak_rate_nm_per_s,
        volume_rate_nm_mm2_per_s: mm.volume_rate_nm_mm2_per_s,
        fwhm_x_mm: mm.fwhm_x_mm,
        fwhm_y_mm: mm.fwhm_y_mm,
        region_rms_nm: m.region_rms_nm,
        region_pv_nm: m.region_pv_nm,
    })
}

/// Fits, predicts and tabulates a measured sweep.
pub fn analyse_sweep(mut spots: Vec<SpotRecord>, start: &FitStart) -> SweepReport {
    let bonnets = bonnet_order(&spots, REFERENCE_BONNET);
    let reference = bonnets.first().cloned().unwrap_or_default();
    let base = baseline(&spots);
    let mut fits = Vec::new();
    for b in &bonnets {
        let obs: Vec<Observation> = spots
            .iter()
            .filter(|r| &r.bonnet == b)
            .map(|r| Observation {
                factors: r.factors,
                metrics: &r.metrics,
            })
            .collect();
        match fit_model(&obs, start) {
            Ok(fit) => fits.push(BonnetFit {
                bonnet: b.clone(),
                preston_m2_per_n: Some(fit.model.preston_nm_per_mpa_mm * 1e-12),
                baseline: base,
                baseline_prediction: fit.model.metrics(&base).ok(),
                fit: Some(fit),
                error: None,
            }),
            Err(e) => fits.push(BonnetFit {
                bonnet: b.clone(),
                fit: None,
                error: Some(e.to_string()),
                preston_m2_per_n: None,
                baseline: base,
                baseline_prediction: None,
            }),
        }
    }
    let predictions: Vec<Option<PredictedSpot>> = spots
        .par_iter()
        .map(|r| {
            let fit = fits.iter().find(|f| f.bonnet == r.bonnet)?.fit.as_ref()?;
            predict_spot(&fit.model, &r.factors, r.metrics.dwell_s, r.pixel_mm).ok()
        })
        .collect();
    for (r, p) in spots.iter_mut().zip(predictions) {
        r.predicted = p;
    }
    let mut trends = Vec::new();
    let mut opt = Vec::new();
    let present = sweeps(&spots);
    for (f, members) in &present {
        for metric in TrendMetric::ALL {
            let t = trend(&spots, members, *f, metric, &bonnets);
            opt.extend(optimisation(&t));
            trends.push(t);
        }
    }
    SweepReport {
        reference_bonnet: reference,
        baseline: base,
        sweeps: present.iter().map(|p| p.0).collect(),
        spots,
        fits,
        trends,
        optimisation: opt,
    }
}
