//! `simulate`: the predicted after map of a polishing run from its recipe (the before map, the
//! TIF as a measured spot or a model, the path log), with the vibration coupling of its bonnet.
//!
//! Figures: RMS / PV of the before and predicted after maps with piston and tilt removed
//! (jointly, over the before map's valid pixels); CR = (before - after) / before; the Y-direction
//! `ripple` object of the predicted after map at the recipe's pitch (as `psd` prints it); and a
//! `mechanisms` array, each entry the MSF-band RMS (Y PSD, band `msf_band_per_mm`) a coupling
//! mechanism imprints and its share of the summed band power. Without vibration coupling the only
//! mechanism is `nominal_raster`: the MSF content of the predicted removal itself (the raster
//! imprint of the TIF at the pitch). Vibration mechanisms are appended to the same array.
//!
//! Vibration coupling (bonnetlab_vibration::coupling, fast method) runs when the recipe has a
//! `[process]` or `[vibration]` table or `--bonnet` is given, unless `--no-vibration`: its
//! predicted removal replaces the nominal one, `nominal_raster` becomes the band RMS of the
//! coupling's baseline (commanded path, no vibration) and the mechanisms `normal_offset`,
//! `lateral_jitter`, `envelope`, `dwell_execution` and their `interaction` follow. Every `share`
//! in the array is that entry's band power over the summed band power of all entries
//! (`mechanism_share_basis` says so in the JSON); `vibration_share` is the library's share among
//! the vibration entries only. `--sweep-rpm` adds the spindle-speed sweep (both bonnets):
//! `spindle_sweep.csv`, a `spindle_sweep` JSON array and `spindle_sweep.png` (σ1 vs rpm).

use std::path::Path;

use bonnetlab_process::recipe::{Recipe, TifSource};
use bonnetlab_process::simulate::{predict, Mode, Prediction, ToolModel};
use bonnetlab_process::{Grid, ProcessError};
use bonnetlab_spectrum::{
    band_rms, psd_xy, ripple_from_psds, Psd1d, PsdOptions, Ripple, RippleOptions, SpectrumError,
    MSF_DEFAULT_PER_MM,
};
use bonnetlab_surface::convergence::{convergence_ratio, undefined_convergence_reason};
use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};
use bonnetlab_vibration::coupling::predict::default_sweep_rpm;
use bonnetlab_vibration::coupling::{self, CouplingInput, CouplingOptions, SweepRow};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use serde::Serialize;

use super::error::vibration_error;
use super::{read_map, Error, Progress};

/// What to simulate beyond the recipe (the `simulate` flags).
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Bonnet type (overrides the recipe's `[process] bonnet`).
    pub bonnet: Option<Bonnet>,
    /// Exact time-domain deposition instead of the fast FFT method.
    pub exact: bool,
    /// Leave the vibration coupling out (nominal removal only).
    pub no_vibration: bool,
    /// Also sweep the spindle speed for both bonnets.
    pub sweep_rpm: bool,
}

/// One coupling mechanism's contribution to the predicted MSF band.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Mechanism {
    pub name: String,
    pub msf_band_rms_nm: f64,
    /// Fraction of the summed MSF band power of all entries (shares add up to 1).
    pub share: f64,
    pub enabled: bool,
    /// The coupling library's share among the vibration entries only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vibration_share: Option<f64>,
}

/// Builds the mechanisms array from (name, band RMS) pairs: shares are power fractions.
pub fn mechanisms(parts: &[(&str, f64)]) -> Vec<Mechanism> {
    let total: f64 = parts.iter().map(|(_, r)| r * r).sum();
    parts
        .iter()
        .map(|&(name, r)| Mechanism {
            name: name.to_string(),
            msf_band_rms_nm: r,
            share: if total > 0.0 { r * r / total } else { 0.0 },
            enabled: true,
            vibration_share: None,
        })
        .collect()
}

/// The JSON written to `simulation.json` (contract fields: `rms_after_nm`, `pv_after_nm`,
/// `cr_rms`, `ripple`, `mechanisms`).
#[derive(Debug, Clone, Serialize)]
pub struct SimulationReport {
    pub recipe: String,
    pub mode: String,
    pub bonnet: String,
    pub removed: Vec<Term>,
    pub rms_before_nm: f64,
    pub pv_before_nm: f64,
    pub rms_after_nm: f64,
    pub pv_after_nm: f64,
    /// (before - after) / before; null for a flat before map, with `cr_reason` beside it.
    pub cr_rms: Option<f64>,
    pub cr_pv: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cr_reason: Option<String>,
    pub removal_mean_nm: f64,
    pub removal_rms_nm: f64,
    pub path_duration_s: f64,
    pub path_length_mm: f64,
    pub tif_peak_rate_nm_per_s: f64,
    pub tif_volume_rate_nm_mm2_per_s: f64,
    pub pitch_mm: Option<f64>,
    /// Ripple of the predicted after map along Y at the pitch (null without a pitch).
    pub ripple: Option<Ripple>,
    /// Why `ripple` is null (no pitch in the recipe); absent when there is a ripple.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_reason: Option<String>,
    pub msf_band_per_mm: (f64, f64),
    pub mechanisms: Vec<Mechanism>,
    /// What each mechanism's `share` is a fraction of.
    pub mechanism_share_basis: String,
    /// The coupling's figures for the simulated bonnet (null without vibration).
    pub vibration: Option<VibrationSummary>,
    /// Spindle-speed sweep rows (only with `--sweep-rpm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spindle_sweep: Option<Vec<SweepRow>>,
    pub notes: Vec<String>,
    /// How the predicted maps' pixels sample the removal (the recipe's `[measurement] pixels`:
    /// `point`, values at the pixel centres; `area`, means over each pixel).
    pub pixels: String,
}

/// The vibration coupling's prediction for the simulated bonnet.
#[derive(Debug, Clone, Serialize)]
pub struct VibrationSummary {
    pub bonnet: String,
    pub spindle_rpm: f64,
    pub msf_band_per_mm: (f64, f64),
    /// Y ripple of the predicted after map (σ1 at 1/pitch, harmonics; as `psd`).
    pub ripple: Option<Ripple>,
    /// MSF band RMS (Y) of the predicted removal, of the baseline and of the induced part, nm.
    pub removal_msf_band_rms_nm: f64,
    pub baseline_msf_band_rms_nm: f64,
    pub induced_msf_band_rms_nm: f64,
    /// σ1 at 1/pitch (Y) of the predicted and of the baseline removal, nm.
    pub removal_ripple_sigma1_nm: Option<f64>,
    pub baseline_removal_ripple_sigma1_nm: Option<f64>,
    /// Why `ripple` and the σ1 fields are null (no pitch in the recipe); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_reason: Option<String>,
}

/// Why a ripple is not evaluated: no pitch in the recipe (None with a pitch).
fn no_pitch_reason(pitch_mm: Option<f64>) -> Option<String> {
    pitch_mm
        .is_none()
        .then(|| "no [path] pitch_mm in the recipe: ripple not evaluated".to_string())
}

const SHARE_BASIS: &str = "fraction of the summed MSF band power (Y, msf_band_per_mm) of all \
     entries of this array: share = msf_band_rms_nm^2 / sum(msf_band_rms_nm^2)";

/// Everything `simulate` computes, before writing.
pub struct Simulation {
    pub report: SimulationReport,
    pub prediction: Prediction,
    pub before: Surface,
    pub psd_y_after: Psd1d,
    pub psd_y_before: Psd1d,
}

fn perr(file: &Path, e: ProcessError) -> Error {
    let msg = e.to_string();
    // Recipe and path-log errors already name their file.
    let named = matches!(
        e,
        ProcessError::Recipe { .. } | ProcessError::PathLog { .. } | ProcessError::Io { .. }
    );
    let code = if e.is_bad_input() { 2 } else { 1 };
    if named {
        Error { code, message: msg }
    } else if code == 2 {
        Error::input(file, msg)
    } else {
        Error::processing(file, msg)
    }
}

/// Runs the simulation of a recipe: reads its maps, spot and path log; writes nothing.
pub fn simulate(
    recipe_file: &Path,
    opts: &Options,
    progress: &dyn Progress,
) -> Result<Simulation, Error> {
    let exact = opts.exact;
    let step = |msg: &str| progress.step(msg);
    step("recipe");
    let recipe = Recipe::load(recipe_file).map_err(|e| perr(recipe_file, e))?;
    let named = |key: &str| {
        let by = bonnetlab_process::recipe::named_by(recipe_file, key);
        move |mut e: Error| {
            e.message.push_str(&by);
            e
        }
    };
    let before = read_map(&recipe.before).map_err(named("[measurement] before"))?;
    let grid = Grid::of(&before).map_err(|e| perr(&recipe.before, e.into()))?;
    step("tif");
    let spot = match &recipe.tif {
        TifSource::Spot { path, .. } => Some(read_map(path).map_err(named("[tif] spot"))?),
        _ => None,
    };
    let spot_file = match &recipe.tif {
        TifSource::Spot { path, .. } => path.clone(),
        _ => recipe_file.to_path_buf(),
    };
    // The recipe's pixels: the spot is read, and the maps predicted, as they sample.
    let tool = ToolModel::from_source_seen(
        &recipe.tif,
        spot.as_ref(),
        grid.dx_mm,
        grid.dy_mm,
        recipe.pixels,
    )
    .map_err(|e| perr(&spot_file, e))?;
    step("path");
    let path = recipe
        .read_path_log()
        .map_err(|e| perr(&recipe.path_log, e))?;
    check_pitch(recipe_file, &recipe, grid.dy_mm)?;
    bonnetlab_process::path::log::check_run_extent(
        &path,
        &recipe.path_log,
        &grid,
        tool.field().half_extent_mm(),
    )
    .map_err(|e| perr(&recipe.path_log, e))?;
    step("removal");
    let bonnet_name = match opts.bonnet {
        Some(Bonnet::Original) => "original".to_string(),
        Some(Bonnet::Suppression) => "suppression".to_string(),
        None => recipe.process.bonnet.clone(),
    };
    let bonnet = if bonnet_name == "suppression" {
        Bonnet::Suppression
    } else {
        Bonnet::Original
    };
    let with_vibration = !opts.no_vibration
        && (opts.bonnet.is_some() || recipe.vibration.is_some() || has_process_table(recipe_file));
    if exact && with_vibration {
        return Err(Error::usage(
            "--exact applies to the nominal removal only (the vibration coupling has the fast \
             method): add --no-vibration",
        ));
    }
    let mut notes = Vec::new();
    let (prediction, vib, sweep) = if with_vibration || opts.sweep_rpm {
        let p = &recipe.process;
        let params = VibrationParams::from_parts(
            recipe.vibration.as_ref(),
            p.spindle_rpm,
            p.offset_mm,
            p.inner_pressure_mpa,
            None,
        )
        .map_err(|e| vibration_error(recipe_file, recipe.vibration.as_ref(), e))?;
        let input = CouplingInput {
            grid,
            valid: Some(before.valid()),
            tool: &tool,
            path: &path,
            params: &params,
            pitch_mm: recipe.pitch_mm,
        };
        let copts = CouplingOptions::default();
        let sweep = if opts.sweep_rpm {
            progress.message("spindle-speed sweep (both bonnets)");
            Some(
                coupling::spindle_sweep(&input, &copts, &default_sweep_rpm())
                    .map_err(|e| vibration_error(recipe_file, recipe.vibration.as_ref(), e))?,
            )
        } else {
            None
        };
        if with_vibration {
            let pred = coupling::predict(&input, bonnet, &copts)
                .map_err(|e| vibration_error(recipe_file, recipe.vibration.as_ref(), e))?;
            let prediction = prediction_from(&before, pred.removal_nm())
                .map_err(|e| Error::processing(&recipe.before, e))?;
            (prediction, Some(pred), sweep)
        } else {
            (nominal(&before, &tool, &path, exact, &recipe)?, None, sweep)
        }
    } else {
        (nominal(&before, &tool, &path, exact, &recipe)?, None, None)
    };
    step("metrics");
    let terms = [Term::Piston, Term::Tilt];
    let figures = |s: &Surface| -> Result<(f64, f64), Error> {
        let (r, _) = remove_terms(s, &terms).map_err(|e| Error::processing(&recipe.before, e))?;
        let h = height_stats(&r).map_err(|e| Error::processing(&recipe.before, e))?;
        Ok((h.rms_nm, h.pv_nm))
    };
    let (rms_b, pv_b) = figures(&before)?;
    let (rms_a, pv_a) = figures(&prediction.after)?;
    let removal_stats =
        height_stats(&prediction.removal).map_err(|e| Error::processing(&recipe.before, e))?;
    let opts = PsdOptions::default();
    let serr = |e: bonnetlab_spectrum::SpectrumError| Error::processing(&recipe.before, e);
    let (px_a, py_a) = psd_xy(&prediction.after, &opts).map_err(serr)?;
    let (_, py_b) = psd_xy(&before, &opts).map_err(serr)?;
    let (_, py_r) = psd_xy(&prediction.removal, &opts).map_err(serr)?;
    let ripple = match recipe.pitch_mm {
        Some(p) => Some(
            ripple_from_psds(&px_a, &py_a, p, &RippleOptions::default())
                .map_err(|e| pitch_error(recipe_file, &recipe, p, e))?,
        ),
        None => None,
    };
    let (f1, f2) = MSF_DEFAULT_PER_MM;
    let f2 = f2.min(py_r.freq_per_mm.last().copied().unwrap_or(f2));
    let (mech, vibration) = match &vib {
        None => {
            notes.push("vibration coupling is not included in this prediction".to_string());
            (
                mechanisms(&[("nominal_raster", band_rms(&py_r, f1, f2))]),
                None,
            )
        }
        Some(pred) => {
            let mut parts = vec![("nominal_raster", pred.baseline_msf_band_rms_nm)];
            parts.extend(
                pred.mechanisms
                    .iter()
                    .map(|m| (m.name.as_str(), m.msf_band_rms_nm)),
            );
            let mut mech = mechanisms(&parts);
            for (m, lib) in mech.iter_mut().skip(1).zip(&pred.mechanisms) {
                m.enabled = lib.enabled;
                m.vibration_share = Some(lib.share);
            }
            let summary = VibrationSummary {
                bonnet: pred.bonnet.name().to_string(),
                spindle_rpm: pred.spindle_rpm,
                msf_band_per_mm: pred.msf_band_per_mm,
                ripple: ripple.clone(),
                removal_msf_band_rms_nm: pred.removal_msf_band_rms_nm,
                baseline_msf_band_rms_nm: pred.baseline_msf_band_rms_nm,
                induced_msf_band_rms_nm: pred.induced_msf_band_rms_nm,
                removal_ripple_sigma1_nm: pred.ripple_sigma1_nm,
                baseline_removal_ripple_sigma1_nm: pred.baseline_ripple_sigma1_nm,
                ripple_reason: no_pitch_reason(recipe.pitch_mm),
            };
            (mech, Some(summary))
        }
    };
    let ripple_reason = no_pitch_reason(recipe.pitch_mm);
    if let Some(why) = &ripple_reason {
        notes.push(why.clone());
    }
    let t = tool.sampled();
    let cr_reason = undefined_convergence_reason(rms_b, pv_b, &terms);
    let report = SimulationReport {
        recipe: recipe_file.display().to_string(),
        mode: if exact && vib.is_none() {
            "exact"
        } else {
            "fast"
        }
        .into(),
        bonnet: bonnet_name,
        removed: terms.to_vec(),
        rms_before_nm: rms_b,
        pv_before_nm: pv_b,
        rms_after_nm: rms_a,
        pv_after_nm: pv_a,
        cr_rms: cr_reason.is_none().then(|| convergence_ratio(rms_b, rms_a)),
        cr_pv: cr_reason.is_none().then(|| convergence_ratio(pv_b, pv_a)),
        cr_reason,
        removal_mean_nm: removal_stats.mean_nm,
        removal_rms_nm: removal_stats.rms_nm,
        path_duration_s: path.duration_s(),
        path_length_mm: path.length_mm(),
        tif_peak_rate_nm_per_s: t.peak_rate_nm_per_s(),
        tif_volume_rate_nm_mm2_per_s: t.volume_rate_nm_mm2_per_s(),
        pitch_mm: recipe.pitch_mm,
        ripple,
        ripple_reason,
        msf_band_per_mm: (f1, f2),
        mechanisms: mech,
        mechanism_share_basis: SHARE_BASIS.to_string(),
        vibration,
        spindle_sweep: sweep,
        notes,
        pixels: recipe.pixels.name().to_string(),
    };
    step("done");
    Ok(Simulation {
        report,
        prediction,
        before,
        psd_y_after: py_a,
        psd_y_before: py_b,
    })
}

/// A raster pitch shorter than two Y pixels of the before map cannot be a raster on this map
/// (its ripple is above the Nyquist frequency): bad input naming the recipe key, exit 2.
fn check_pitch(recipe_file: &Path, recipe: &Recipe, dy_mm: f64) -> Result<(), Error> {
    match recipe.pitch_mm {
        // The pixel size is single precision in most formats: 2 pixels within 1e-6 pass.
        Some(p) if p.is_nan() || p < 2.0 * dy_mm * (1.0 - 1e-6) => Err(Error::input(
            recipe_file,
            format!(
                "[path] pitch_mm: {} mm is shorter than two Y pixels of {} ({} mm): no raster \
                 ripple at that pitch is resolvable on this map",
                bonnetlab_surface::format::sig(p, 4),
                recipe.before.display(),
                bonnetlab_surface::format::sig(2.0 * dy_mm, 4)
            ),
        )),
        _ => Ok(()),
    }
}

/// A pitch the map cannot resolve (longer than the Y field, or so few periods on it that the
/// band reaches the biased lowest PSD bins: the ripple's own test) is the recipe's error,
/// named by its key (exit 2); any other failure of the ripple is the map's (exit 1).
fn pitch_error(recipe_file: &Path, recipe: &Recipe, pitch_mm: f64, e: SpectrumError) -> Error {
    match e {
        SpectrumError::NotResolvable(_) => Error::input(
            recipe_file,
            format!(
                "[path] pitch_mm: {} mm on {}: {e}",
                bonnetlab_surface::format::sig(pitch_mm, 4),
                recipe.before.display()
            ),
        ),
        e => Error::processing(&recipe.before, e),
    }
}

/// The nominal prediction (no vibration). An exact walk refused for its size is the path log's
/// doing and names it; other errors name the before map.
fn nominal(
    before: &Surface,
    tool: &ToolModel,
    path: &bonnetlab_process::PathLog,
    exact: bool,
    recipe: &Recipe,
) -> Result<Prediction, Error> {
    let mode = if exact { Mode::Exact } else { Mode::Fast };
    predict(before, tool, path, None, mode).map_err(|e| match e {
        ProcessError::InvalidArgument(what) if exact => Error::input(&recipe.path_log, what),
        e => perr(&recipe.before, e),
    })
}

/// Whether the recipe file has a `[process]` table (the parsed recipe fills defaults).
fn has_process_table(recipe_file: &Path) -> bool {
    bonnetlab_process::recipe::RecipeDoc::load(recipe_file).is_ok_and(|d| d.process.is_some())
}

/// A prediction (removal, after = before - removal) from a removal map on the before grid.
fn prediction_from(
    before: &Surface,
    removal_nm: ndarray::Array2<f64>,
) -> Result<Prediction, bonnetlab_surface::SurfaceError> {
    let mut after = before.with_heights(before.heights_nm() - &removal_nm)?;
    let mut removal = before.with_heights(removal_nm)?;
    removal.removed.clear();
    removal.provenance.format = "synthetic".into();
    removal.provenance.comment =
        Some("predicted removal with vibration coupling (nm, positive = removed)".into());
    after.provenance.format = "synthetic".into();
    after.provenance.comment = Some("predicted after map with vibration coupling".into());
    Ok(Prediction { removal, after })
}
