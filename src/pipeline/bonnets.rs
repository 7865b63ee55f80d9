//! Why one bonnet polishes better (issue 16): each run given by its recipe is measured,
//! predicted with the forward model and the vibration coupling of its bonnet, calibrated, and
//! its vibration forcing inferred from the measured removal; two or more runs are compared by
//! counterfactual attribution of the difference in σ1 and CR(RMS) (first run against each
//! other run).
//!
//! Per run (see [`analyse_run`] for the order):
//! - `predicted`: the forcing polynomial of the recipe's TIF and bonnet at the recipe's forcing
//!   (`[vibration] fn_n`, `noise_force_rms_n`; the documented defaults otherwise) and rate
//!   scale 1, σ1 and MSF band RMS of the predicted after map (before − removal);
//! - `calibration` (`bonnetlab_calibrate::run::calibrate` on the recipe's maps, TIF and path,
//!   with the vibration's removal at the fitted forcing taken back from the after map), and
//!   each accepted effect's added removal;
//! - the after map registered with the accepted `registration` (if any); the measured removal
//!   is before − registered after on the common valid pixels;
//! - `vibration_forcing`: the forcing fitted to the measured removal's X and Y PSDs, on the
//!   calibrated TIF (the recipe's widened by an accepted `tif_scale`);
//! - the run's causes: the coupling mechanisms at the fitted forcing; each accepted calibrated
//!   effect (the counterfactual without its added removal; SD from the effect's largest
//!   relative parameter uncertainty); and, without an accepted `tif_scale`, `removal_rate`: the
//!   calibration's baseline rate scale against the recipe's rate (a wider spot and a lower rate
//!   leave the same ripple when the removal depth is lost to piston removal; SD from the noise
//!   floor and the forward model's accuracy).
//!
//! Measured σ1 is the ripple at 1/pitch along Y of the registered after map (nm); CR(RMS) is
//! (RMS before − RMS after) / RMS before with the form terms removed; MSF band RMS is along Y
//! in the coupling's MSF band (one-sided PSD, Hann), nm.

use std::path::{Path, PathBuf};

use bonnetlab_calibrate::run::{calibrate, Calibration, EffectReport};
use bonnetlab_process::pixel::PixelSampling;
use bonnetlab_process::recipe::{Recipe, TifSource};
use bonnetlab_process::simulate::{ToolModel, ToolShape};
use bonnetlab_process::tif::RateField;
use bonnetlab_process::{Grid, PathLog};
use bonnetlab_spectrum::{ripple, PsdOptions};
use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};
use bonnetlab_vibration::coupling::predict::msf_band_rms_y;
use bonnetlab_vibration::coupling::{CouplingInput, CouplingOptions};
use bonnetlab_vibration::infer::{
    attribute_difference, infer_forcing, shared_forcing, vibration_effects_with_noise, Difference,
    ForcingFit, ForcingModel, InferOptions, NoiseDraws, Predicted, RunEffects, SharedForcing,
    VibrationForcing,
};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use ndarray::Array2;
use serde::Serialize;

/// A failure: the file it concerns, a one-line message (naming the file), and the exit code
/// (2 bad input, 1 valid but unusable).
#[derive(Debug, Clone)]
pub struct BonnetsError {
    pub file: PathBuf,
    pub message: String,
    pub exit_code: i32,
}

impl std::fmt::Display for BonnetsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.message)
    }
}

impl std::error::Error for BonnetsError {}

impl BonnetsError {
    fn new(file: &Path, what: impl std::fmt::Display, exit_code: i32) -> BonnetsError {
        let what = what.to_string();
        let name = file.display().to_string();
        let message = if what.contains(&name) {
            what
        } else {
            format!("{name}: {what}")
        };
        BonnetsError {
            file: file.to_path_buf(),
            message: message.lines().next().unwrap_or("").to_string(),
            exit_code,
        }
    }
    fn input(file: &Path, what: impl std::fmt::Display) -> BonnetsError {
        BonnetsError::new(file, what, 2)
    }
    fn processing(file: &Path, what: impl std::fmt::Display) -> BonnetsError {
        BonnetsError::new(file, what, 1)
    }
}

/// One run as its recipe gives it, read into memory.
#[derive(Debug, Clone)]
pub struct RunInput {
    pub name: String,
    /// The recipe file (named in messages).
    pub recipe_file: PathBuf,
    pub before: Surface,
    pub after: Surface,
    pub tif: TifSource,
    /// The measured spot map when `tif` is a measured spot.
    pub spot: Option<Surface>,
    /// How the maps' and the spot's pixels sample the surface (`[measurement] pixels`).
    pub pixels: PixelSampling,
    /// The instrument's declared repeatability (`[measurement] repeatability_nm`), if any.
    pub repeatability_nm: Option<f64>,
    pub path: PathLog,
    /// Raster pitch, mm.
    pub pitch_mm: f64,
    pub bonnet: Bonnet,
    /// The recipe's vibration parameters (its forcing is the prediction's).
    pub params: VibrationParams,
}

impl RunInput {
    /// Reads a recipe and everything it names; errors name the file at fault.
    pub fn load(name: &str, recipe_file: &Path) -> Result<RunInput, BonnetsError> {
        let recipe = Recipe::load(recipe_file).map_err(|e| BonnetsError::input(recipe_file, e))?;
        let read = |p: &Path, key: &str| {
            bonnetlab_io::read_surface(p).map_err(|e| {
                let code = e.exit_code();
                let mut err = BonnetsError::new(p, e, code);
                err.message
                    .push_str(&bonnetlab_process::recipe::named_by(recipe_file, key));
                err
            })
        };
        let before = read(&recipe.before, "[measurement] before")?;
        let after_path = recipe.after.clone().ok_or_else(|| {
            BonnetsError::input(
                recipe_file,
                "[measurement] after: missing (a compared run needs the after map)",
            )
        })?;
        let after = read(&after_path, "[measurement] after")?;
        bonnetlab_process::recipe::check_measured_removal(&before, &after)
            .map_err(|e| BonnetsError::input(&after_path, e))?;
        let spot = match &recipe.tif {
            TifSource::Spot { path, .. } => Some(read(path, "[tif] spot")?),
            _ => None,
        };
        let path = bonnetlab_process::path::read_path_csv(&recipe.path_log)
            .map_err(|e| BonnetsError::input(&recipe.path_log, e))?;
        let pitch_mm = recipe.pitch_mm.ok_or_else(|| {
            BonnetsError::input(
                recipe_file,
                "[path] pitch_mm: missing (the ripple and the forcing need the raster pitch)",
            )
        })?;
        let p = &recipe.process;
        let params = VibrationParams::from_parts(
            recipe.vibration.as_ref(),
            p.spindle_rpm,
            p.offset_mm,
            p.inner_pressure_mpa,
            None,
        )
        .map_err(|e| BonnetsError::input(recipe_file, e))?;
        Ok(RunInput {
            name: name.to_string(),
            recipe_file: recipe_file.to_path_buf(),
            before,
            after,
            tif: recipe.tif.clone(),
            spot,
            pixels: recipe.pixels,
            repeatability_nm: recipe.repeatability_nm,
            path,
            pitch_mm,
            bonnet: if p.bonnet == "suppression" {
                Bonnet::Suppression
            } else {
                Bonnet::Original
            },
            params,
        })
    }
}

/// Settings of the analysis.
#[derive(Debug, Clone)]
pub struct Options {
    pub coupling: CouplingOptions,
    pub infer: InferOptions,
    pub calibrate: bonnetlab_calibrate::run::Options,
    /// Form terms removed before RMS (compare's `--remove`).
    pub remove: Vec<Term>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            coupling: CouplingOptions::default(),
            infer: InferOptions::default(),
            calibrate: bonnetlab_calibrate::run::Options::default(),
            remove: vec![Term::Piston, Term::Tilt],
        }
    }
}

/// What was measured on a run (registered after map).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Measured {
    /// σ1 at 1/pitch along Y of the after map, nm.
    pub sigma1_nm: f64,
    /// MSF band RMS along Y of the after map (the coupling's band), nm.
    pub msf_rms_nm: f64,
    pub rms_before_nm: f64,
    pub rms_after_nm: f64,
    pub cr_rms: f64,
}

/// One analysed run.
#[derive(Debug, Clone, Serialize)]
pub struct RunAnalysis {
    pub name: String,
    pub bonnet: Bonnet,
    pub pitch_mm: f64,
    pub measured: Measured,
    pub predicted: Predicted,
    pub calibration: Calibration,
    pub vibration_forcing: VibrationForcing,
    /// The forcing fit in full (best values, broadband level, rate scale, evidence).
    pub forcing_fit: ForcingFit,
    /// TIF scale the forcing was fitted with (1 = the recipe's TIF).
    pub fit_tif_scale: f64,
    /// The causes' effects on this run (attribution input).
    pub effects: RunEffects,
}

/// The comparison of two or more runs.
#[derive(Debug, Clone, Serialize)]
pub struct BonnetsComparison {
    pub runs: Vec<RunAnalysis>,
    /// First run against each other run.
    pub difference: Vec<Difference>,
    /// Whether one forcing explains all runs (two or more runs).
    pub shared_forcing: Option<SharedForcing>,
}

/// A rate field widened by `scale` (`T_s(r) = T(r / s)`, calibrate's `tif_scale` convention).
struct Scaled<'a> {
    base: &'a dyn RateField,
    scale: f64,
}

impl RateField for Scaled<'_> {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.base.rate_at_mm(dx_mm / self.scale, dy_mm / self.scale)
    }
    fn half_extent_mm(&self) -> (f64, f64) {
        let (x, y) = self.base.half_extent_mm();
        (x * self.scale, y * self.scale)
    }
    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        self.base
            .volume_rate_nm_mm2_per_s()
            .map(|v| v * self.scale * self.scale)
    }
}

/// The tool widened by `scale`: a Gaussian model as the same model with its width scaled (the
/// project's front end), any other TIF as the scaled field sampled at the map pitch.
fn scaled_tool_model(
    src: &TifSource,
    tool: &ToolModel,
    scale: f64,
    dx: f64,
    dy: f64,
) -> Result<ToolModel, bonnetlab_process::ProcessError> {
    match src {
        TifSource::Gaussian(g) => {
            let w = bonnetlab_process::tif::GaussianTif::new(
                g.sigma_mm * scale,
                g.diameter_mm * scale,
                g.peak_rate_nm_per_s,
            )?;
            Ok(
                ToolModel::from_source(&TifSource::Gaussian(w), None, dx, dy)?
                    .seen_by(tool.response()),
            )
        }
        _ => {
            let f = Scaled {
                base: tool.field(),
                scale,
            };
            Ok(
                ToolModel::from(ToolShape::Sampled(bonnetlab_process::tif::Tif::sample(
                    &f, dx, dy,
                )?))
                .seen_by(tool.response()),
            )
        }
    }
}

fn num(e: &EffectReport, key: &str) -> Option<f64> {
    e.params.get(key).and_then(|v| v.as_f64())
}

/// Relative one-sigma uncertainty of an effect's size: the largest over its numeric parameters
/// of SD / |deviation from no effect| (a scale's deviation is from 1), at most 1.
fn relative_uncertainty(e: &EffectReport) -> f64 {
    let mut rel: f64 = 0.0;
    for (k, v) in &e.params {
        let (Some(v), Some(sd)) = (v.as_f64(), e.uncertainties.get(k).and_then(|s| s.as_f64()))
        else {
            continue;
        };
        let dev = if k == "scale" { v - 1.0 } else { v };
        if dev.abs() > 0.0 {
            rel = rel.max(sd.abs() / dev.abs());
        }
    }
    rel.min(1.0)
}

fn rms_of(s: &Surface, remove: &[Term], file: &Path) -> Result<f64, BonnetsError> {
    let (r, _) = remove_terms(s, remove).map_err(|e| BonnetsError::processing(file, e))?;
    Ok(height_stats(&r)
        .map_err(|e| BonnetsError::processing(file, e))?
        .rms_nm)
}

/// The removal the vibration added at a fitted forcing (nm, rate scale applied): every coupling
/// mechanism's map, the commanded-path baseline excluded.
fn induced_removal(model: &ForcingModel, fit: &ForcingFit) -> Array2<f64> {
    let m = model.maps(fit.best_fn_n, fit.noise_force_rms_n);
    (m.total() - &m.baseline) * fit.rate_scale
}

fn effect_num(cal: &Calibration, kind: &str, key: &str) -> Option<f64> {
    cal.effects
        .iter()
        .find(|e| e.kind == kind)
        .and_then(|e| num(e, key))
}

/// When the measured spectrum does not constrain a run's forcing, the mechanisms are
/// attributed at the recipe's stated forcing (`[vibration] fn_n`) if the data allow it (at or
/// below the fit's one-sided upper bound, or no bound found), rather than at the fit's
/// meaningless optimum; the reason says so. The verdict stays "not constrained" (no `fn_n`).
fn at_recipe_when_unconstrained(mut fit: ForcingFit, recipe: &VibrationParams) -> ForcingFit {
    if fit.forcing.constrained {
        return fit;
    }
    let allowed = fit.forcing.upper_bound_n.is_none_or(|u| recipe.fn_n <= u);
    if allowed {
        fit.best_fn_n = recipe.fn_n;
        fit.forcing.reason = format!(
            "{}; the mechanisms are attributed at the recipe's fn_n = {} N, which the data allow",
            fit.forcing.reason, recipe.fn_n
        );
    }
    fit
}

/// Effects of a calibration that the forcing model already accounts for: the TIF scale (the
/// model is rebuilt with it, and the fit's free rate scale takes what is left) and the
/// registration (the after map is resampled through it).
const MODELLED_EFFECTS: [&str; 2] = ["tif_scale", "registration"];

/// The measured removal without the removal the calibration's other accepted effects add
/// (their [`bonnetlab_calibrate::run::Maps::effect_removal_nm`]), on the pixels the calibration
/// fitted (the effect maps are zero elsewhere); `removal` unchanged when no such effect was
/// accepted.
fn without_unmodelled_effects(
    removal: &Surface,
    cal: &Calibration,
    also_modelled: &[&str],
) -> Result<Surface, bonnetlab_surface::SurfaceError> {
    let added: Vec<&Array2<f64>> = cal
        .maps
        .effect_removal_nm
        .iter()
        .filter(|(kind, _)| {
            !MODELLED_EFFECTS.contains(&kind.as_str()) && !also_modelled.contains(&kind.as_str())
        })
        .map(|(_, m)| m)
        .collect();
    let fitted = cal.maps.final_residual_nm.as_ref().map(|(_, m)| m);
    let (Some(fitted), false) = (fitted, added.is_empty()) else {
        return Ok(removal.clone());
    };
    let mut z = removal.heights_nm().clone();
    for m in added {
        z -= m;
    }
    let valid = ndarray::Zip::from(removal.valid())
        .and(fitted)
        .map_collect(|&a, &b| a && b);
    Surface::with_mask(z, valid, removal.dx_mm, removal.dy_mm)
}

/// Draws of the maps' white noise behind the attribution's SDs ([`NoiseDraws`]): 16 give an
/// SD within about 18 % (1 sigma).
pub const NOISE_DRAWS: usize = 16;
/// Fixed seed of those draws (the same input gives the same bytes out).
const NOISE_SEED: u64 = 0x005e_ed0f_a77b;

/// Analyses one run.
///
/// Calibration does not model vibration: given the raw maps it explains the spindle imprint
/// with aliases (a rate oscillation at the spindle period, path errors at the pitch). So the
/// forcing is fitted first (recipe TIF, unregistered maps), the run is calibrated with the
/// vibration's removal at that forcing taken back (`after + induced`), and the forcing refitted
/// on the calibrated TIF and registered after map, with the removal of the calibration's other
/// accepted effects (path and rate effects the forcing model does not have) taken out; when the calibrated TIF scale moved by more
/// than 0.5 %, once more (at most two calibrations).
pub fn analyse_run(run: &RunInput, opts: &Options) -> Result<RunAnalysis, BonnetsError> {
    let file = run.recipe_file.as_path();
    let perr = |e: &dyn std::fmt::Display| BonnetsError::processing(file, e);
    let ierr = |e: &dyn std::fmt::Display| BonnetsError::input(file, e);

    let (dx, dy) = run.before.pixel_mm("compare").map_err(|e| ierr(&e))?;
    if run.after.dim() != run.before.dim() {
        return Err(ierr(&format!(
            "after map is {:?}, the before map {:?}",
            run.after.dim(),
            run.before.dim()
        )));
    }
    let common = |after: &Surface| -> Result<(Surface, Surface, Surface), BonnetsError> {
        let valid: Array2<bool> = ndarray::Zip::from(run.before.valid())
            .and(after.valid())
            .map_collect(|&a, &b| a && b);
        let b = Surface::with_mask(
            run.before.heights_nm().clone(),
            valid.clone(),
            Some(dx),
            Some(dy),
        )
        .map_err(|e| perr(&e))?;
        let a = Surface::with_mask(after.heights_nm().clone(), valid, Some(dx), Some(dy))
            .map_err(|e| perr(&e))?;
        let r = b
            .with_heights(b.heights_nm() - a.heights_nm())
            .map_err(|e| perr(&e))?;
        Ok((b, a, r))
    };
    let (before0, after0, removal0) = common(&run.after)?;

    // Prediction with the recipe's TIF and forcing.
    let grid = Grid::of(&run.before).map_err(|e| ierr(&e))?;
    let tool = ToolModel::from_source_seen(&run.tif, run.spot.as_ref(), dx, dy, run.pixels)
        .map_err(|e| ierr(&e))?;
    let input = CouplingInput {
        grid,
        valid: Some(before0.valid()),
        tool: &tool,
        path: &run.path,
        params: &run.params,
        pitch_mm: Some(run.pitch_mm),
    };
    let band = opts.coupling.msf_band_per_mm;
    let nominal = ForcingModel::build(&input, run.bonnet, &opts.coupling).map_err(|e| perr(&e))?;
    let predicted = nominal
        .predicted(
            &input,
            run.params.fn_n,
            run.params.noise_force_rms_n,
            1.0,
            band,
            Some(&before0),
        )
        .map_err(|e| perr(&e))?;

    // Forcing, vibration-corrected calibration, forcing again on the calibrated run.
    let mut fit = infer_forcing(&nominal, &removal0, &opts.infer).map_err(|e| perr(&e))?;
    let mut model = nominal;
    let mut scale = 1.0;
    let mut raw_problem = None;
    let mut state = None;
    let mut scaled_tool;
    for _round in 0..2 {
        let corrected = run
            .after
            .with_heights(run.after.heights_nm() + &induced_removal(&model, &fit))
            .map_err(|e| perr(&e))?;
        let mut problem = bonnetlab_calibrate::pipeline::problem_from_parts_seen(
            &run.before,
            &corrected,
            &run.tif,
            run.spot.as_ref(),
            &run.path,
            run.pixels,
        )
        .map_err(|e| ierr(&e))?;
        problem.repeatability_nm = run.repeatability_nm;
        let cal = calibrate(&problem, &opts.calibrate).map_err(|e| perr(&e))?;
        let new_scale = effect_num(&cal, "tif_scale", "scale").unwrap_or(1.0);
        let after_reg = match cal.effects.iter().find(|e| e.kind == "registration") {
            Some(e) => {
                let r = [
                    num(e, "dx_mm").unwrap_or(0.0),
                    num(e, "dy_mm").unwrap_or(0.0),
                    num(e, "rotation_deg").unwrap_or(0.0).to_radians(),
                ];
                if raw_problem.is_none() {
                    raw_problem = Some(
                        bonnetlab_calibrate::pipeline::problem_from_parts_seen(
                            &run.before,
                            &run.after,
                            &run.tif,
                            run.spot.as_ref(),
                            &run.path,
                            run.pixels,
                        )
                        .map_err(|e| ierr(&e))?,
                    );
                }
                let (z, v) = raw_problem
                    .as_ref()
                    .map(|p| p.resample_after(r))
                    .unwrap_or_else(|| (run.after.heights_nm().clone(), run.after.valid().clone()));
                Some(Surface::with_mask(z, v, Some(dx), Some(dy)).map_err(|e| perr(&e))?)
            }
            None => None,
        };
        let moved = (new_scale - scale).abs() > 0.005;
        if moved {
            scaled_tool =
                scaled_tool_model(&run.tif, &tool, new_scale, dx, dy).map_err(|e| perr(&e))?;
            let inp = CouplingInput {
                tool: &scaled_tool,
                ..input
            };
            model = ForcingModel::build(&inp, run.bonnet, &opts.coupling).map_err(|e| perr(&e))?;
            scale = new_scale;
        }
        let maps = match &after_reg {
            Some(a) => common(a)?,
            None => (before0.clone(), after0.clone(), removal0.clone()),
        };
        // The forcing model is the commanded path's: the run's calibrated path and rate effects
        // (a servo lag, a path offset, rate drifts) are not in it, and left in the removal
        // their spectrum is read as forcing. They are taken out before the refit.
        let target = without_unmodelled_effects(&maps.2, &cal, &[]).map_err(|e| perr(&e))?;
        fit = infer_forcing(&model, &target, &opts.infer).map_err(|e| perr(&e))?;
        state = Some((cal, maps));
        if !moved {
            break;
        }
    }
    let Some((cal, (before, after, removal))) = state else {
        return Err(perr(&"no calibration round ran"));
    };
    // A calibrated servo lag moves neighbouring raster lines in opposite directions along the
    // scan, which changes how their spindle imprints add where the spot covers two lines: the
    // commanded path's model misreads that as forcing. With a lag accepted, the forcing model is
    // built for the lag (the tool moved back along the travel at the run's own clock: the
    // spindle phase along each line is the run's) and the lag's removal is no longer taken out
    // of the target.
    let lagged = effect_num(&cal, "direction_lag", "lag_mm").filter(|l| l.is_finite() && *l != 0.0);
    if let Some(lag_mm) = lagged {
        let rescaled;
        let tool_now = if scale != 1.0 {
            rescaled = scaled_tool_model(&run.tif, &tool, scale, dx, dy).map_err(|e| perr(&e))?;
            &rescaled
        } else {
            &tool
        };
        let inp = CouplingInput {
            tool: tool_now,
            ..input
        };
        model = ForcingModel::build_lagged(&inp, run.bonnet, &opts.coupling, lag_mm)
            .map_err(|e| perr(&e))?;
        let target =
            without_unmodelled_effects(&removal, &cal, &["direction_lag"]).map_err(|e| perr(&e))?;
        fit = infer_forcing(&model, &target, &opts.infer).map_err(|e| perr(&e))?;
    }

    // Measured values and the causes.
    let sigma1 = |s: &Surface| {
        ripple(s, run.pitch_mm, &PsdOptions::default())
            .map(|r| r.sigma1_nm)
            .map_err(|e| perr(&e))
    };
    let rms_b = rms_of(&before, &opts.remove, file)?;
    let rms_a = rms_of(&after, &opts.remove, file)?;
    let minput = CouplingInput {
        valid: Some(after.valid()),
        ..input
    };
    let measured = Measured {
        sigma1_nm: sigma1(&after)?,
        msf_rms_nm: msf_band_rms_y(&minput, after.heights_nm(), band).map_err(|e| perr(&e))?,
        rms_before_nm: rms_b,
        rms_after_nm: rms_a,
        cr_rms: if rms_b > 0.0 {
            (rms_b - rms_a) / rms_b
        } else {
            0.0
        },
    };
    let fit = at_recipe_when_unconstrained(fit, &run.params);
    // The maps' white noise, from the calibration's floor (before - after: both maps' noise in
    // quadrature), re-drawn to give the SDs it puts on σ1, CR and each cause's effect.
    let draws = NoiseDraws::new(
        &before,
        &after,
        cal.noise_floor_rms_nm / std::f64::consts::SQRT_2,
        NOISE_DRAWS,
        NOISE_SEED,
        run.pitch_mm,
        &opts.remove,
    )
    .map_err(|e| perr(&e))?;
    let (sigma1_noise_sd_nm, cr_rms_noise_sd) = draws.value_sd().map_err(|e| perr(&e))?;
    let mut causes =
        vibration_effects_with_noise(&model, &fit, &before, &after, &opts.remove, Some(&draws))
            .map_err(|e| perr(&e))?;
    for (e, (kind, added)) in cal.effects.iter().zip(&cal.maps.effect_removal_nm) {
        let cause = draws.cause_effect(kind, added, relative_uncertainty(e));
        causes.push(cause.map_err(|e| perr(&e))?);
    }
    // The removal rate against the recipe's (calibration's baseline rate scale), when no TIF
    // scale was accepted: with piston removed, a wider spot and a lower rate leave the same
    // ripple at the pitch, so this cause stands for either.
    if scale == 1.0 {
        let c = cal.baseline.rate_scale;
        let base = model.maps(0.0, 0.0).baseline;
        let added = &base * (c - 1.0);
        // Least-squares standard error of a scale on the model removal with white noise at the
        // calibration's noise floor, and the forward model's own accuracy, in quadrature.
        let ss: f64 = ndarray::Zip::from(&base)
            .and(before.valid())
            .fold(0.0, |acc, &v, &ok| if ok { acc + v * v } else { acc });
        let sd_noise = if ss > 0.0 {
            cal.noise_floor_rms_nm / ss.sqrt()
        } else {
            0.0
        };
        let sd_c = sd_noise.hypot(bonnetlab_calibrate::run::MODEL_ACCURACY);
        let rel = if (c - 1.0).abs() > 0.0 {
            (sd_c / (c - 1.0).abs()).min(1.0)
        } else {
            1.0
        };
        let cause = draws.cause_effect("removal_rate", &added, rel);
        causes.push(cause.map_err(|e| perr(&e))?);
    }
    let effects = RunEffects {
        name: run.name.clone(),
        sigma1_nm: measured.sigma1_nm,
        cr_rms: measured.cr_rms,
        sigma1_noise_sd_nm,
        cr_rms_noise_sd,
        causes,
    };
    Ok(RunAnalysis {
        name: run.name.clone(),
        bonnet: run.bonnet,
        pitch_mm: run.pitch_mm,
        measured,
        predicted,
        calibration: cal,
        vibration_forcing: fit.forcing.clone(),
        forcing_fit: fit,
        fit_tif_scale: scale,
        effects,
    })
}

/// Analyses every run and, with two or more, attributes the differences (first run against
/// each other run) and tests whether one forcing explains them all.
pub fn compare_runs(runs: &[RunInput], opts: &Options) -> Result<BonnetsComparison, BonnetsError> {
    let analysed = runs
        .iter()
        .map(|r| analyse_run(r, opts))
        .collect::<Result<Vec<_>, _>>()?;
    let difference = match analysed.split_first() {
        Some((first, rest)) => rest
            .iter()
            .map(|r| attribute_difference(&first.effects, &r.effects))
            .collect(),
        None => Vec::new(),
    };
    let shared = if analysed.len() >= 2 {
        let fits: Vec<&ForcingFit> = analysed.iter().map(|r| &r.forcing_fit).collect();
        Some(shared_forcing(&fits).map_err(|e| {
            BonnetsError::processing(&runs[0].recipe_file, format!("shared forcing: {e}"))
        })?)
    } else {
        None
    };
    Ok(BonnetsComparison {
        runs: analysed,
        difference,
        shared_forcing: shared,
    })
}
