//! The calibration pipeline of a run: the recipe's maps, spot and path log, the TIF from the
//! project's one front end ([`ToolModel::from_source`], the same as `simulate`), and the prepared
//! [`Problem`]. The CLI calls [`load_recipe`]; tests that build runs in memory call
//! [`problem_from_parts`], the step [`load_recipe`] ends with, so both go through the same code.

use std::path::{Path, PathBuf};

use bonnetlab_process::pixel::PixelSampling;
use bonnetlab_process::recipe::{Recipe, TifSource};
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::PathLog;
use bonnetlab_surface::Surface;

use crate::error::CalibrateError;
use crate::model::Problem;
use crate::tif::TifMap;

/// A pipeline failure: the file it concerns, what went wrong, and whether the input was bad
/// (exit code 2) or valid but unusable (exit code 1).
#[derive(Debug)]
pub struct PipelineError {
    pub file: PathBuf,
    pub message: String,
    pub exit_code: i32,
}

impl std::fmt::Display for PipelineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.message)
    }
}

impl PipelineError {
    fn input(file: &Path, what: impl std::fmt::Display) -> PipelineError {
        PipelineError {
            file: file.to_path_buf(),
            message: what.to_string(),
            exit_code: 2,
        }
    }
}

/// The prepared problem of a run from its parts: before and after maps, the recipe's TIF
/// source (with the spot map when it is a measured spot) and the commanded path.
pub fn problem_from_parts(
    before: &Surface,
    after: &Surface,
    tif: &TifSource,
    spot: Option<&Surface>,
    path: &PathLog,
) -> Result<Problem, CalibrateError> {
    problem_from_parts_seen(before, after, tif, spot, path, PixelSampling::Point)
}

/// [`problem_from_parts`] for maps and spot whose pixels sample the removal as `pixels` says
/// (a recipe's `[measurement] pixels`).
pub fn problem_from_parts_seen(
    before: &Surface,
    after: &Surface,
    tif: &TifSource,
    spot: Option<&Surface>,
    path: &PathLog,
    pixels: PixelSampling,
) -> Result<Problem, CalibrateError> {
    let (dx, dy) = before.pixel_mm("calibration")?;
    let tool = ToolModel::from_source_seen(tif, spot, dx, dy, pixels)?;
    Problem::new(before, after, &TifMap::new(tool), path)
}

/// A measured-spot run's problem (the common case of the synthetic runs).
pub fn problem_with_spot(
    before: &Surface,
    after: &Surface,
    spot: &Surface,
    spot_dwell_s: f64,
    path: &PathLog,
) -> Result<Problem, CalibrateError> {
    let src = TifSource::Spot {
        path: PathBuf::from("spot"),
        dwell_s: spot_dwell_s,
    };
    problem_from_parts(before, after, &src, Some(spot), path)
}

/// Reads everything a recipe names and prepares the problem; errors name the file at fault.
pub fn load_recipe(recipe_path: &Path) -> Result<Problem, PipelineError> {
    let recipe = Recipe::load(recipe_path).map_err(|e| PipelineError::input(recipe_path, e))?;
    let read = |p: &Path, key: &str| {
        bonnetlab_io::read_surface(p).map_err(|e| PipelineError {
            file: p.to_path_buf(),
            exit_code: e.exit_code(),
            message: format!(
                "{e}{}",
                bonnetlab_process::recipe::named_by(recipe_path, key)
            ),
        })
    };
    let before = read(&recipe.before, "[measurement] before")?;
    let after_path = recipe.after.clone().ok_or_else(|| {
        PipelineError::input(
            recipe_path,
            "[measurement] after: missing (calibrate needs the after map)",
        )
    })?;
    let after = read(&after_path, "[measurement] after")?;
    // The after map's own pixel size is needed too: an unknown one is the after map's fault,
    // named here (Problem::new would report it against the recipe).
    after
        .pixel_mm("calibration")
        .map_err(|e| PipelineError::input(&after_path, e))?;
    let (spot, spot_file) = match &recipe.tif {
        TifSource::Spot { path, .. } => (Some(read(path, "[tif] spot")?), path.clone()),
        _ => (None, recipe_path.to_path_buf()),
    };
    let path = bonnetlab_process::path::read_path_csv(&recipe.path_log)
        .map_err(|e| PipelineError::input(&recipe.path_log, e))?;
    let (dx, dy) = before
        .pixel_mm("calibration")
        .map_err(|e| PipelineError::input(&recipe.before, e))?;
    let tool = ToolModel::from_source_seen(&recipe.tif, spot.as_ref(), dx, dy, recipe.pixels)
        .map_err(|e| PipelineError::input(&spot_file, e))?;
    // Samples outside the part plus the spot are refused here, before any grid is built from
    // the path (the same check as `simulate`).
    let grid = bonnetlab_process::Grid::of(&before)
        .map_err(|e| PipelineError::input(&recipe.before, e))?;
    bonnetlab_process::path::log::check_run_extent(
        &path,
        &recipe.path_log,
        &grid,
        tool.field().half_extent_mm(),
    )
    .map_err(|e| PipelineError::input(&recipe.path_log, e))?;
    bonnetlab_process::recipe::check_measured_removal(&before, &after)
        .map_err(|e| PipelineError::input(&after_path, e))?;
    let mut p = Problem::new(&before, &after, &TifMap::new(tool), &path).map_err(|e| match e {
        CalibrateError::Processing(m) => PipelineError {
            file: recipe_path.to_path_buf(),
            message: m,
            exit_code: 1,
        },
        other => PipelineError::input(recipe_path, other),
    })?;
    p.repeatability_nm = recipe.repeatability_nm;
    Ok(p)
}
