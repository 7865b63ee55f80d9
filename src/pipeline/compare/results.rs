//! The typed results of a comparison (what `report.json` holds): per-band convergence ratios,
//! per-run results with their spread and improvement, and the settings as reported.

use serde::Serialize;

use bonnetlab_spectrum::{ArealBands, Psd1d, Ripple};
use bonnetlab_surface::Surface;

/// One band's RMS before / after and its convergence ratio. A value that cannot be computed
/// is `None` (JSON null) and `reason` says why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandCr {
    /// `figure`, `msf`, `fine` or `ripple`.
    pub band: String,
    /// Edges in mm^-1 as used (clipped to the measured range; for `ripple`: f0 - h to
    /// K f0 + h, in harmonic bands only).
    pub f1_per_mm: f64,
    pub f2_per_mm: f64,
    /// How the band RMS is measured.
    pub method: String,
    pub rms_before_nm: Option<f64>,
    pub rms_after_nm: Option<f64>,
    pub cr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

impl BandCr {
    /// A band with before / after values (means over repeats) or the reason they are absent.
    pub(super) fn new(
        band: &str,
        edges: (f64, f64),
        method: String,
        before: Result<f64, String>,
        after: Result<f64, String>,
    ) -> Self {
        let (rms_before_nm, rms_after_nm, reason) = match (before, after) {
            (Ok(b), Ok(a)) => (Some(b), Some(a), None),
            (Err(e), _) | (_, Err(e)) => (None, None, Some(e)),
        };
        let (cr, reason) = match (rms_before_nm, rms_after_nm) {
            (Some(b), Some(a)) if b > 0.0 => (Some((b - a) / b), reason),
            (Some(_), Some(_)) => (
                None,
                Some("no CR: the band RMS before is 0 nm (nothing to converge)".to_string()),
            ),
            _ => (None, reason),
        };
        BandCr {
            band: band.into(),
            f1_per_mm: edges.0,
            f2_per_mm: edges.1,
            method,
            rms_before_nm,
            rms_after_nm,
            cr,
            reason,
        }
    }
}

/// The areal band RMS of every map of a run, in the order given.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunBandRms {
    pub before: Vec<ArealBands>,
    pub after: Vec<ArealBands>,
}

/// Spread of a run's metrics over its repeat measurements (sample sd; CR sd propagated).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunSpread {
    pub n_before: usize,
    pub n_after: usize,
    pub rms_before_sd_nm: f64,
    pub rms_after_sd_nm: f64,
    pub pv_before_sd_nm: f64,
    pub pv_after_sd_nm: f64,
    pub cr_rms_sd: f64,
    pub cr_pv_sd: f64,
}

/// A run compared with the first run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Improvement {
    pub reference: String,
    pub improvement_cr_rms: f64,
    pub improvement_cr_pv: f64,
    /// Present when both runs have repeats before and after.
    pub noise: Option<NoiseVerdict>,
}

/// Whether CR differences between two runs exceed the repeat-measurement noise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseVerdict {
    pub improvement_cr_rms_sd: f64,
    pub improvement_cr_pv_sd: f64,
    pub cr_rms_difference: f64,
    pub cr_rms_difference_sd: f64,
    pub cr_pv_difference: f64,
    pub cr_pv_difference_sd: f64,
    pub rms_within_noise: bool,
    pub pv_within_noise: bool,
}

/// Everything computed for one run (serialised into `report.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunResult {
    pub name: String,
    pub before_files: Vec<String>,
    pub after_files: Vec<String>,
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: Option<f64>,
    pub dy_mm: Option<f64>,
    /// Pixels valid in every map of the run: the aperture all numbers use.
    pub common_valid: usize,
    pub removed: Vec<String>,
    pub rms_before_nm: f64,
    pub rms_after_nm: f64,
    pub pv_before_nm: f64,
    pub pv_after_nm: f64,
    pub cr_rms: f64,
    pub cr_pv: f64,
    /// Per-map values (in the order given) so the repeat spread can be checked.
    pub rms_before_each_nm: Vec<f64>,
    pub rms_after_each_nm: Vec<f64>,
    pub pv_before_each_nm: Vec<f64>,
    pub pv_after_each_nm: Vec<f64>,
    pub spread: Option<RunSpread>,
    /// Why there is no `spread` (fewer than two before or two after maps); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spread_reason: Option<String>,
    /// figure, MSF (areal band RMS, means over repeats) and ripple.
    pub bands: Vec<BandCr>,
    /// The fine band (above F2) of the same areal split.
    pub band_fine: BandCr,
    /// Every map's areal band RMS object (as `stats --bands` writes it).
    pub band_rms: RunBandRms,
    /// figure / MSF by the 2-D PSD's annulus sums (windowed): a labelled PSD quantity.
    pub bands_psd: Vec<BandCr>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_before: Option<Ripple>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_after: Option<Ripple>,
    /// With a pitch the maps cannot resolve: why there is no ripple.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_reason: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub improvement_cr_rms: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub improvement_cr_pv: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub improvement: Option<Improvement>,
    /// Why there is no improvement over the reference run (its convergence ratio is 0, so
    /// a change relative to it is undefined); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub improvement_reason: Option<String>,
    /// Averaged one-sided PSDs (not serialised: written as CSV).
    #[serde(skip)]
    pub psd: RunPsds,
    /// Maps for the pictures: first before / after map on the aperture with the terms removed,
    /// and their difference (removal = before - after). Not serialised.
    #[serde(skip)]
    pub maps: Option<RunMaps>,
}

/// Averaged PSDs of a run (one-sided, nm^2 mm).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunPsds {
    pub x_before: Option<Psd1d>,
    pub x_after: Option<Psd1d>,
    pub y_before: Option<Psd1d>,
    pub y_after: Option<Psd1d>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RunMaps {
    pub before: Surface,
    pub after: Surface,
    pub removal: Surface,
}

/// The whole comparison (the `report.json` document).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    pub tool: String,
    pub version: String,
    pub settings: SettingsReport,
    pub runs: Vec<RunResult>,
    /// Notes for the user (stderr, not the report): a `--pixel-mm` a file's own pixel size
    /// overrides.
    #[serde(skip)]
    pub notes: Vec<String>,
}

/// Settings as written to the report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettingsReport {
    pub removed: Vec<String>,
    pub window: String,
    pub pitch_mm: Option<f64>,
    pub psd: String,
    /// How the band RMS values of `bands` are measured.
    pub band_method: String,
    pub figure_band_per_mm: (f64, f64),
    pub msf_band_per_mm: (f64, f64),
    pub harmonics: usize,
    pub aperture: String,
    pub noise_rule: String,
}
