//! Command-line interface: one file per subcommand. The contract (names, flags, JSON fields)
//! is `shared/spec/interfaces.md`; each file owns its `Args` and `run`.

use clap::{Parser, Subcommand};

pub mod batch;
pub mod calibrate;
pub mod compare;
pub mod demo;
pub mod dwell;
pub mod error;
pub mod psd;
pub mod simulate;
pub mod spots;
pub mod stats;
pub mod vibration;

pub use error::CliError;

/// bonnetlab: surface metrology, polishing simulation and vibration analysis for robot
/// bonnet polishing.
#[derive(Debug, Parser)]
#[command(name = "bonnetlab", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Height parameters of one map (PV, RMS, Sa, Ssk, Sku, ...) after form removal.
    Stats(stats::Args),
    /// 1-D PSD along X and Y, and the ripple check at the grating spacing.
    Psd(psd::Args),
    /// Compare bonnet runs (before/after maps): convergence, ripple, HTML + JSON report.
    Compare(compare::Args),
    /// Stats and ripple of many maps as JSON lines, in parallel.
    Batch(batch::Args),
    /// Generate the bundled two-bonnet sample and write the demo report.
    Demo(demo::Args),
    /// Solve dwell time for a case file (surface, TIF, clear aperture).
    Dwell(dwell::Args),
    /// Predict the after-surface of a polishing run from its recipe.
    Simulate(simulate::Args),
    /// Two-degree-of-freedom forced vibration response for a bonnet.
    Vibration(vibration::Args),
    /// Close the loop: predicted vs measured removal, diagnose and add missing effects.
    Calibrate(calibrate::Args),
    /// Fixed-point spot sweeps: TIF metrics per spot and trends per bonnet.
    Spots(spots::Args),
}

/// Runs a parsed command line; returns the process exit code and prints any error as one line.
pub fn run(cli: Cli) -> i32 {
    let result = match &cli.command {
        Command::Stats(a) => stats::run(a),
        Command::Psd(a) => psd::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Batch(a) => batch::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Dwell(a) => dwell::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Vibration(a) => vibration::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Spots(a) => spots::run(a),
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("bonnetlab: {}", e.message.replace('\n', " "));
            e.code
        }
    }
}
