//! Writes a synthetic run as a complete run directory: `before.dat`, `after.dat`, `spot.dat`
//! (MetroPro, through `bonnetlab_io`), `path.csv` (`t_s,x_mm,y_mm`) and `recipe.toml` in the
//! format of spec/interfaces.md. Every file is written atomically.

use std::path::{Path, PathBuf};

use bonnetlab_io::{write_surface, MapFormat};

use super::SynthRun;
use crate::error::CalibrateError;

fn io_err(e: impl std::fmt::Display) -> CalibrateError {
    CalibrateError::InvalidInput(e.to_string())
}

/// Writes the run into `dir` (created if needed); returns the recipe path.
pub fn write_run(dir: &Path, run: &SynthRun) -> Result<PathBuf, CalibrateError> {
    let recipe = format!(
        "# synthetic run written by bonnetlab_calibrate::synth\n\
         [measurement]\nbefore = \"before.dat\"\nafter = \"after.dat\"\n\n\
         [tif]\nspot = \"spot.dat\"\ndwell_s = {}\n\n\
         [path]\nlog = \"path.csv\"\npitch_mm = {}\n\n\
         [process]\nbonnet = \"original\"\nspindle_rpm = 1000.0\noffset_mm = 0.6\nprecession_deg = 20.0\ninner_pressure_mpa = 0.25\n",
        run.spot_dwell_s, run.pitch_mm
    );
    write_run_with_recipe(dir, run, &recipe)
}

/// [`write_run`] with the given recipe text (which should name `before.dat`, `after.dat`,
/// `spot.dat` and `path.csv`).
pub fn write_run_with_recipe(
    dir: &Path,
    run: &SynthRun,
    recipe: &str,
) -> Result<PathBuf, CalibrateError> {
    std::fs::create_dir_all(dir).map_err(|e| io_err(format!("{}: {e}", dir.display())))?;
    write_surface(&dir.join("before.dat"), &run.before, MapFormat::MetroProDat).map_err(io_err)?;
    write_surface(&dir.join("after.dat"), &run.after, MapFormat::MetroProDat).map_err(io_err)?;
    let mut spot = run.spot.clone();
    spot.origin_mm = (0.0, 0.0);
    write_surface(&dir.join("spot.dat"), &spot, MapFormat::MetroProDat).map_err(io_err)?;
    let mut csv = String::with_capacity(run.path.len() * 40 + 16);
    csv.push_str("t_s,x_mm,y_mm\n");
    for k in 0..run.path.len() {
        csv.push_str(&format!(
            "{},{},{}\n",
            run.path.t_s[k], run.path.x_mm[k], run.path.y_mm[k]
        ));
    }
    bonnetlab_io::atomic::write_atomic(&dir.join("path.csv"), csv.as_bytes()).map_err(io_err)?;
    let rp = dir.join("recipe.toml");
    bonnetlab_io::atomic::write_atomic(&rp, recipe.as_bytes()).map_err(io_err)?;
    Ok(rp)
}
