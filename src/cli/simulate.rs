//! `bonnetlab simulate RECIPE.toml [--bonnet original|suppression] [--exact] --out DIR`
//! (contract: shared/spec/interfaces.md).
//!
//! Predicts the after map of a run from its recipe: the before map, the TIF (measured spot or
//! model), the path log. Writes `DIR/predicted_after.dat`, `DIR/predicted_removal.dat`,
//! `DIR/simulation.json` and plots (`predicted_removal.png`, `predicted_after.png`,
//! `predicted_psd_y.png`).
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

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use bonnetlab_io::MapFormat;
use bonnetlab_process::recipe::{Recipe, TifSource};
use bonnetlab_process::simulate::{predict, Mode, Prediction, ToolModel};
use bonnetlab_process::{read_path_csv, Grid, ProcessError};
use bonnetlab_spectrum::{
    band_rms, psd_xy, ripple_from_psds, Psd1d, PsdOptions, Ripple, RippleOptions,
    MSF_DEFAULT_PER_MM,
};
use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};
use bonnetlab_vibration::coupling::predict::default_sweep_rpm;
use bonnetlab_vibration::coupling::{self, CouplingInput, CouplingOptions, SweepRow};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Serialize;

use super::CliError;
use crate::report;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BonnetArg {
    Original,
    Suppression,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Run recipe (TOML: [measurement], [tif], [path], [process], [vibration]).
    pub recipe: PathBuf,
    /// Bonnet type (overrides the recipe's [process] bonnet).
    #[arg(long, value_enum)]
    pub bonnet: Option<BonnetArg>,
    /// Exact time-domain deposition instead of the fast FFT method (the reference; slower).
    #[arg(long)]
    pub exact: bool,
    /// Leave the vibration coupling out (nominal removal only).
    #[arg(long)]
    pub no_vibration: bool,
    /// Also sweep the spindle speed (250 to 2000 rpm) for both bonnets.
    #[arg(long)]
    pub sweep_rpm: bool,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
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
    pub cr_rms: f64,
    pub cr_pv: f64,
    pub removal_mean_nm: f64,
    pub removal_rms_nm: f64,
    pub path_duration_s: f64,
    pub path_length_mm: f64,
    pub tif_peak_rate_nm_per_s: f64,
    pub tif_volume_rate_nm_mm2_per_s: f64,
    pub pitch_mm: Option<f64>,
    /// Ripple of the predicted after map along Y at the pitch (null without a pitch).
    pub ripple: Option<Ripple>,
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

fn perr(file: &Path, e: ProcessError) -> CliError {
    let msg = e.to_string();
    // Recipe and path-log errors already name their file.
    let named = matches!(
        e,
        ProcessError::Recipe { .. } | ProcessError::PathLog { .. } | ProcessError::Io { .. }
    );
    let code = if e.is_bad_input() { 2 } else { 1 };
    if named {
        CliError { code, message: msg }
    } else if code == 2 {
        CliError::input(file, msg)
    } else {
        CliError::processing(file, msg)
    }
}

fn progress(n: u64) -> ProgressBar {
    let target = if std::io::stderr().is_terminal() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(Some(n), target);
    bar.set_style(
        ProgressStyle::with_template("{spinner} simulate [{bar:30}] {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Runs the simulation of a recipe (no files written; `args.out` is not used).
pub fn simulate_recipe(recipe_file: &Path, args: &Args) -> Result<Simulation, CliError> {
    let exact = args.exact;
    let bar = progress(6);
    let step = |msg: &str| {
        bar.set_message(msg.to_string());
        bar.inc(1);
    };
    step("recipe");
    let recipe = Recipe::load(recipe_file).map_err(|e| perr(recipe_file, e))?;
    let before = super::stats::read_map(&recipe.before)?;
    let grid = Grid::of(&before).map_err(|e| perr(&recipe.before, e))?;
    step("tif");
    let spot = match &recipe.tif {
        TifSource::Spot { path, .. } => Some(super::stats::read_map(path)?),
        _ => None,
    };
    let spot_file = match &recipe.tif {
        TifSource::Spot { path, .. } => path.clone(),
        _ => recipe_file.to_path_buf(),
    };
    let tool = ToolModel::from_source(&recipe.tif, spot.as_ref(), grid.dx_mm, grid.dy_mm)
        .map_err(|e| perr(&spot_file, e))?;
    step("path");
    let path = read_path_csv(&recipe.path_log).map_err(|e| perr(&recipe.path_log, e))?;
    check_pitch(recipe_file, &recipe, grid.dy_mm)?;
    let (ex, ey) = tool.field().half_extent_mm();
    bonnetlab_process::path::log::check_extent(
        &path,
        &recipe.path_log,
        (grid.x0_mm, grid.x_mm(grid.cols - 1)),
        (grid.y0_mm, grid.y_mm(grid.rows - 1)),
        // Overtravel beyond the spot (turnarounds off the part) is allowed up to one part
        // length; anything further is a corrupt log.
        ex.max(ey)
            + (grid.x_mm(grid.cols - 1) - grid.x0_mm).max(grid.y_mm(grid.rows - 1) - grid.y0_mm),
    )
    .map_err(|e| perr(&recipe.path_log, e))?;
    step("removal");
    let bonnet_name = match args.bonnet {
        Some(BonnetArg::Original) => "original".to_string(),
        Some(BonnetArg::Suppression) => "suppression".to_string(),
        None => recipe.process.bonnet.clone(),
    };
    let bonnet = if bonnet_name == "suppression" {
        Bonnet::Suppression
    } else {
        Bonnet::Original
    };
    let with_vibration = !args.no_vibration
        && (args.bonnet.is_some() || recipe.vibration.is_some() || has_process_table(recipe_file));
    let mut notes = Vec::new();
    let (prediction, vib, sweep) = if with_vibration || args.sweep_rpm {
        let p = &recipe.process;
        let params = VibrationParams::from_parts(
            recipe.vibration.as_ref(),
            p.spindle_rpm,
            p.offset_mm,
            p.inner_pressure_mpa,
            None,
        )
        .map_err(|e| super::vibration_error(recipe_file, recipe.vibration.as_ref(), e))?;
        let input = CouplingInput {
            grid,
            valid: Some(before.valid()),
            tool: &tool,
            path: &path,
            params: &params,
            pitch_mm: recipe.pitch_mm,
        };
        let copts = CouplingOptions::default();
        let sweep = if args.sweep_rpm {
            bar.set_message("spindle-speed sweep (both bonnets)");
            Some(
                coupling::spindle_sweep(&input, &copts, &default_sweep_rpm()).map_err(|e| {
                    super::vibration_error(recipe_file, recipe.vibration.as_ref(), e)
                })?,
            )
        } else {
            None
        };
        if with_vibration {
            let pred = coupling::predict(&input, bonnet, &copts)
                .map_err(|e| super::vibration_error(recipe_file, recipe.vibration.as_ref(), e))?;
            let prediction = prediction_from(&before, pred.removal_nm())
                .map_err(|e| CliError::processing(&recipe.before, e))?;
            if exact {
                notes.push(
                    "vibration coupling uses the fast method; --exact applies only without it"
                        .to_string(),
                );
            }
            (prediction, Some(pred), sweep)
        } else {
            (nominal(&before, &tool, &path, exact, &recipe)?, None, sweep)
        }
    } else {
        (nominal(&before, &tool, &path, exact, &recipe)?, None, None)
    };
    step("metrics");
    let terms = [Term::Piston, Term::Tilt];
    let figures = |s: &Surface| -> Result<(f64, f64), CliError> {
        let (r, _) =
            remove_terms(s, &terms).map_err(|e| CliError::processing(&recipe.before, e))?;
        let h = height_stats(&r).map_err(|e| CliError::processing(&recipe.before, e))?;
        Ok((h.rms_nm, h.pv_nm))
    };
    let (rms_b, pv_b) = figures(&before)?;
    let (rms_a, pv_a) = figures(&prediction.after)?;
    let removal_stats =
        height_stats(&prediction.removal).map_err(|e| CliError::processing(&recipe.before, e))?;
    let opts = PsdOptions::default();
    let serr = |e: bonnetlab_spectrum::SpectrumError| CliError::processing(&recipe.before, e);
    let (px_a, py_a) = psd_xy(&prediction.after, &opts).map_err(serr)?;
    let (_, py_b) = psd_xy(&before, &opts).map_err(serr)?;
    let (_, py_r) = psd_xy(&prediction.removal, &opts).map_err(serr)?;
    let ripple = match recipe.pitch_mm {
        Some(p) => {
            Some(ripple_from_psds(&px_a, &py_a, p, &RippleOptions::default()).map_err(serr)?)
        }
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
            };
            (mech, Some(summary))
        }
    };
    if recipe.pitch_mm.is_none() {
        notes.push("no [path] pitch_mm: ripple not evaluated".into());
    }
    let t = tool.sampled();
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
        cr_rms: if rms_b > 0.0 {
            (rms_b - rms_a) / rms_b
        } else {
            0.0
        },
        cr_pv: if pv_b > 0.0 {
            (pv_b - pv_a) / pv_b
        } else {
            0.0
        },
        removal_mean_nm: removal_stats.mean_nm,
        removal_rms_nm: removal_stats.rms_nm,
        path_duration_s: path.duration_s(),
        path_length_mm: path.length_mm(),
        tif_peak_rate_nm_per_s: t.peak_rate_nm_per_s(),
        tif_volume_rate_nm_mm2_per_s: t.volume_rate_nm_mm2_per_s(),
        pitch_mm: recipe.pitch_mm,
        ripple,
        msf_band_per_mm: (f1, f2),
        mechanisms: mech,
        mechanism_share_basis: SHARE_BASIS.to_string(),
        vibration,
        spindle_sweep: sweep,
        notes,
    };
    step("done");
    bar.finish_and_clear();
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
fn check_pitch(recipe_file: &Path, recipe: &Recipe, dy_mm: f64) -> Result<(), CliError> {
    match recipe.pitch_mm {
        // The pixel size is single precision in most formats: 2 pixels within 1e-6 pass.
        Some(p) if p.is_nan() || p < 2.0 * dy_mm * (1.0 - 1e-6) => Err(CliError::input(
            recipe_file,
            format!(
                "[path] pitch_mm: {} mm is shorter than two Y pixels of {} ({} mm): no raster \
                 ripple at that pitch is resolvable on this map",
                report::format::sig(p, 4),
                recipe.before.display(),
                report::format::sig(2.0 * dy_mm, 4)
            ),
        )),
        _ => Ok(()),
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
) -> Result<Prediction, CliError> {
    let mode = if exact { Mode::Exact } else { Mode::Fast };
    predict(before, tool, path, None, mode).map_err(|e| match e {
        ProcessError::InvalidArgument(what) if exact => {
            CliError::input(&recipe.path_log, what.replace("invalid argument: ", ""))
        }
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

/// The sweep as CSV text: one row per (rpm, bonnet), mechanisms' band RMS as columns.
fn sweep_csv(rows: &[SweepRow]) -> String {
    let mut out = String::from(
        "spindle_rpm,bonnet,x1_amplitude_mm,x2_amplitude_mm,offset_amplitude_mm,\
         induced_msf_band_rms_nm,ripple_sigma1_nm",
    );
    if let Some(r) = rows.first() {
        for m in &r.mechanisms {
            out.push_str(&format!(",{}_msf_band_rms_nm", m.name));
        }
    }
    out.push('\n');
    for r in rows {
        out.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e},{}",
            r.spindle_rpm,
            r.bonnet.name(),
            r.x1_amplitude_mm,
            r.x2_amplitude_mm,
            r.offset_amplitude_mm,
            r.induced_msf_band_rms_nm,
            r.ripple_sigma1_nm
                .map(|v| format!("{v:e}"))
                .unwrap_or_default()
        ));
        for m in &r.mechanisms {
            out.push_str(&format!(",{:e}", m.msf_band_rms_nm));
        }
        out.push('\n');
    }
    out
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let sim = simulate_recipe(&args.recipe, args)?;
    write_outputs(&args.out, &sim)?;
    super::println_stdout(&summary(&args.out, &sim.report))
}

/// The one line `simulate` prints on success.
pub fn summary(out: &Path, r: &SimulationReport) -> String {
    let fixed = report::format::fixed;
    let ripple = match &r.ripple {
        Some(p) => format!(
            ", ripple sigma1 {} nm at the {} mm pitch",
            fixed(p.sigma1_nm, 4),
            report::format::sig(p.pitch_mm, 4)
        ),
        None => String::new(),
    };
    format!(
        "simulate: wrote {} ({}, {} bonnet): RMS {} -> {} nm predicted (CR {} %, piston and tilt removed){ripple}",
        out.join("simulation.json").display(),
        r.mode,
        r.bonnet,
        fixed(r.rms_before_nm, 3),
        fixed(r.rms_after_nm, 3),
        fixed(100.0 * r.cr_rms, 1),
    )
}

/// Writes the maps, JSON and plots of a simulation into `dir`, published as one set (nothing
/// in `dir` changes unless every file is written; a second run into `dir` is refused).
pub fn write_outputs(dir: &Path, sim: &Simulation) -> Result<(), CliError> {
    let werr = |e: report::write::WriteError| CliError::input(&e.file, e.what);
    let mut set = report::write::Set::begin(dir).map_err(werr)?;
    set.surface(
        "predicted_after.dat",
        &sim.prediction.after,
        MapFormat::MetroProDat,
    )
    .map_err(werr)?;
    set.surface(
        "predicted_removal.dat",
        &sim.prediction.removal,
        MapFormat::MetroProDat,
    )
    .map_err(werr)?;
    set.json("simulation.json", &sim.report).map_err(werr)?;
    let mut stage =
        |name: &str, bytes: Result<Vec<u8>, report::plot::PlotError>| -> Result<(), CliError> {
            let bytes = bytes.map_err(|e| CliError::processing(dir.join(name), e.what))?;
            set.bytes(name, &bytes).map_err(werr)
        };
    stage(
        "predicted_removal.png",
        report::maps::false_colour_png(&sim.prediction.removal, "predicted removal", "nm"),
    )?;
    stage(
        "predicted_after.png",
        report::maps::false_colour_png(&sim.prediction.after, "predicted after map", "nm"),
    )?;
    let positive = |p: &Psd1d| -> (Vec<f64>, Vec<f64>) {
        p.freq_per_mm
            .iter()
            .zip(&p.psd_nm2_mm)
            .filter(|(f, v)| **f > 0.0 && **v > 0.0)
            .map(|(f, v)| (*f, *v))
            .unzip()
    };
    let (fb, vb) = positive(&sim.psd_y_before);
    let (fa, va) = positive(&sim.psd_y_after);
    let mut plot = report::plot::LinePlot::new(
        "PSD along Y (one-sided, Hann, piston+tilt removed)",
        "frequency (1/mm)",
        "PSD (nm^2 mm)",
    )
    .log_log()
    .series(report::plot::Series::new("before", fb, vb))
    .series(report::plot::Series::new("predicted after", fa, va));
    if let Some(p) = sim.report.pitch_mm {
        plot = plot.grating_markers(p, 3);
    }
    stage("predicted_psd_y.png", plot.to_png())?;
    if let Some(rows) = &sim.report.spindle_sweep {
        stage("spindle_sweep.csv", Ok(sweep_csv(rows).into_bytes()))?;
        let mut plot = report::plot::LinePlot::new(
            "predicted removal ripple sigma1 (Y, 1/pitch) vs spindle speed",
            "spindle speed (rpm)",
            "sigma1 (nm)",
        );
        for b in Bonnet::ALL {
            let (x, y): (Vec<f64>, Vec<f64>) = rows
                .iter()
                .filter(|r| r.bonnet == b)
                .filter_map(|r| r.ripple_sigma1_nm.map(|s| (r.spindle_rpm, s)))
                .unzip();
            if !x.is_empty() {
                plot = plot.series(report::plot::Series::new(b.name(), x, y));
            }
        }
        stage("spindle_sweep.png", plot.to_png())?;
    }
    set.commit().map_err(werr)
}
