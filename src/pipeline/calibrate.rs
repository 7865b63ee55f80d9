//! `calibrate`: a run's recipe (before/after maps, measured spot or TIF model, commanded path
//! log) read into the calibration problem, and the closed-loop calibration of it
//! (`bonnetlab_calibrate::run::calibrate`).

use std::path::Path;

use bonnetlab_calibrate::model::Problem;
use bonnetlab_calibrate::run::{calibrate as calibrate_problem, Calibration, Options};

use super::Error;

/// Loads the run and returns the prepared problem (`bonnetlab_calibrate::pipeline::load_recipe`, its
/// errors as the pipelines' [`Error`]).
pub fn load(recipe_path: &Path) -> Result<Problem, Error> {
    bonnetlab_calibrate::pipeline::load_recipe(recipe_path).map_err(|e| match e.exit_code {
        1 => Error::processing(&e.file, e.message),
        _ if e.message.starts_with(&*e.file.to_string_lossy()) => Error {
            code: e.exit_code,
            message: e.message,
        },
        _ => Error::input(&e.file, e.message),
    })
}

/// Calibrates a loaded run (a processing failure names the recipe, exit 1).
pub fn calibrate(
    recipe_path: &Path,
    problem: &Problem,
    opts: &Options,
) -> Result<Calibration, Error> {
    calibrate_problem(problem, opts).map_err(|e| Error::processing(recipe_path, e))
}
