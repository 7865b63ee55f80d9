//! `calibrate`: a run's recipe (before/after maps, measured spot or TIF model, commanded path
//! log) read into the calibration problem, and the closed-loop calibration of it
//! (`bonnetlab_calibrate::run::calibrate`).

use std::path::Path;

use bonnetlab_calibrate::model::Problem;
use bonnetlab_calibrate::run::{calibrate as calibrate_problem, Calibration, Options};

use bonnetlab_process::recipe::Recipe;
use bonnetlab_vibration::params::VibrationParams;

use super::error::vibration_error;
use super::Error;

/// Loads the run and returns the prepared problem (`bonnetlab_calibrate::pipeline::load_recipe`, its
/// errors as the pipelines' [`Error`]). The calibration does not model vibration, but the
/// recipe's `[vibration]` table is read strictly all the same (with its `[process]` values), so
/// a typo there is an error here as in every command that reads the recipe, not ignored.
pub fn load(recipe_path: &Path) -> Result<Problem, Error> {
    let problem =
        bonnetlab_calibrate::pipeline::load_recipe(recipe_path).map_err(|e| match e.exit_code {
            1 => Error::processing(&e.file, e.message),
            _ if e.message.starts_with(&*e.file.to_string_lossy()) => Error {
                code: e.exit_code,
                message: e.message,
            },
            _ => Error::input(&e.file, e.message),
        })?;
    let recipe = Recipe::load(recipe_path).map_err(|e| Error {
        code: if e.is_bad_input() { 2 } else { 1 },
        message: e.to_string(),
    })?;
    let p = &recipe.process;
    VibrationParams::from_parts(
        recipe.vibration.as_ref(),
        p.spindle_rpm,
        p.offset_mm,
        p.inner_pressure_mpa,
        None,
    )
    .map_err(|e| vibration_error(recipe_path, recipe.vibration.as_ref(), e))?;
    Ok(problem)
}

/// Calibrates a loaded run (a processing failure names the recipe, exit 1).
pub fn calibrate(
    recipe_path: &Path,
    problem: &Problem,
    opts: &Options,
) -> Result<Calibration, Error> {
    calibrate_problem(problem, opts).map_err(|e| Error::processing(recipe_path, e))
}
