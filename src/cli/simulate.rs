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
use bonnetlab_vibration::params::Bonnet;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::progress::Bar;
use super::CliError;
use crate::pipeline::simulate::{simulate, Options, Simulation};
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
    /// The nominal removal only: give it with --no-vibration (the vibration coupling has the
    /// fast method only).
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

/// The pipeline's options from the command line.
pub fn options(args: &Args) -> Options {
    Options {
        bonnet: args.bonnet.map(|b| match b {
            BonnetArg::Original => Bonnet::Original,
            BonnetArg::Suppression => Bonnet::Suppression,
        }),
        exact: args.exact,
        no_vibration: args.no_vibration,
        sweep_rpm: args.sweep_rpm,
    }
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let bar = Bar(progress(6));
    let sim = simulate(&args.recipe, &options(args), &bar)?;
    bar.0.finish_and_clear();
    write_outputs(&args.out, &sim)?;
    super::println_stdout(&report::simulate::summary(&args.out, &sim.report))
}

/// Writes the maps, JSON and plots of a simulation into `dir`, published as one set (nothing
/// in `dir` changes unless every file is written; a second run into `dir` is refused).
pub fn write_outputs(dir: &Path, sim: &Simulation) -> Result<(), CliError> {
    let werr = super::write_error;
    let mut set = report::write::Set::begin(dir, "simulate").map_err(werr)?;
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
    stage("predicted_psd_y.png", report::simulate::psd_y_png(sim))?;
    if let Some(rows) = &sim.report.spindle_sweep {
        stage(
            "spindle_sweep.csv",
            Ok(report::simulate::sweep_csv(rows).into_bytes()),
        )?;
        stage(
            "spindle_sweep.png",
            report::simulate::spindle_sweep_png(rows),
        )?;
    }
    set.commit().map_err(werr)
}
