//! Writes a synthetic run as a complete run directory: `before.dat`, `after.dat`, `spot.dat`
//! (MetroPro, through `bonnetlab_io`), `path.csv` (`t_s,x_mm,y_mm`) and `recipe.toml` in the
//! format of spec/interfaces.md. The files are published together as one output set.

use std::path::{Path, PathBuf};

use bonnetlab_io::atomic::OutputSet;
use bonnetlab_io::{encode_surface, MapFormat};

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
/// `spot.dat` and `path.csv`). The files are published together (an output set: all or none,
/// never mixed with a concurrent run's).
pub fn write_run_with_recipe(
    dir: &Path,
    run: &SynthRun,
    recipe: &str,
) -> Result<PathBuf, CalibrateError> {
    let mut set = OutputSet::begin(dir).map_err(|e| io_err(format!("{}: {e}", dir.display())))?;
    set.record_as("synth")
        .map_err(|e| io_err(format!("{}: {e}", dir.display())))?;
    for (name, bytes) in run_files(run, recipe)? {
        set.write(&name, &bytes)
            .map_err(|e| io_err(format!("{}: {e}", dir.join(&name).display())))?;
    }
    set.commit()
        .map_err(|e| io_err(format!("{}: {e}", dir.display())))?;
    Ok(dir.join("recipe.toml"))
}

/// The files of a run directory, by name, encoded: `before.dat`, `after.dat`, `spot.dat`
/// (MetroPro), `path.csv` and `recipe.toml` (the given text).
pub fn run_files(run: &SynthRun, recipe: &str) -> Result<Vec<(String, Vec<u8>)>, CalibrateError> {
    let dat = |name: &str, s: &bonnetlab_surface::Surface| {
        encode_surface(s, MapFormat::MetroProDat)
            .map(|b| (name.to_string(), b))
            .map_err(|e| io_err(format!("{name}: {e}")))
    };
    let mut spot = run.spot.clone();
    spot.origin_mm = (0.0, 0.0);
    let mut csv = String::with_capacity(run.path.len() * 40 + 16);
    csv.push_str("t_s,x_mm,y_mm\n");
    for k in 0..run.path.len() {
        csv.push_str(&format!(
            "{},{},{}\n",
            run.path.t_s[k], run.path.x_mm[k], run.path.y_mm[k]
        ));
    }
    Ok(vec![
        dat("before.dat", &run.before)?,
        dat("after.dat", &run.after)?,
        dat("spot.dat", &spot)?,
        ("path.csv".into(), csv.into_bytes()),
        ("recipe.toml".into(), recipe.as_bytes().to_vec()),
    ])
}
