//! `bonnetlab spots MANIFEST --out DIR`: fixed-point (spot) polishing sweeps.
//!
//! Reads the manifest (`bonnetlab_spots::manifest`: TOML or CSV), every spot map it lists
//! (any supported format), measures each spot, fits the bonnet model per bonnet, and writes into
//! DIR (created if missing; every file written whole or not at all):
//! - `report.html`: settings and conventions, per-spot table, removal maps, trend plots (metric
//!   against factor, one solid line per bonnet, the fitted model dashed), trend tables,
//!   optimisation degree, fitted models;
//! - `report.json`: the whole `SweepReport` plus the conventions (fractions, not percent);
//! - `spots.csv`: one row per spot, measured and predicted metrics;
//! - `trends.csv`: factor, metric, bonnet, level, n, measured, predicted;
//! - `model_<bonnet>.toml`: the fitted model as a recipe `[tif] model` table.
//!
//! `bonnetlab spots --make-sample DIR` writes the bundled synthetic sweep (two bonnets, offset
//! swept, MetroPro `.dat` maps and `manifest.toml`) from fixed seeds: the committed
//! `samples/spots/` is its output.
//!
//! Exit codes: 2 for a bad manifest or unreadable map (one line naming the file and the line /
//! key), 1 for a spot that cannot be analysed.

use std::path::{Path, PathBuf};

use super::progress::Bar;
use super::CliError;
use crate::pipeline::spots::{manifest_len, sample_sweep, sweep, Sweep};
use crate::report::{spots, write};
use bonnetlab_io::MapFormat;
use bonnetlab_spots::export::model_toml;
use bonnetlab_spots::{FitStart, SpotAnalysis, SweepReport};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sweep manifest (TOML, or CSV by extension `.csv`); map paths are relative to it.
    #[arg(required_unless_present = "make_sample")]
    pub manifest: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long, required_unless_present = "make_sample")]
    pub out: Option<PathBuf>,
    /// Pressure profile of the fitted bonnet model: parabolic (default) or hertz.
    #[arg(long, default_value = "parabolic")]
    pub pressure: String,
    /// Starting bonnet radius of the fit, mm.
    #[arg(long, allow_negative_numbers = true, default_value_t = 20.0)]
    pub start_radius_mm: f64,
    /// Effective contact modulus (MPa) used as start, and held when the sweep cannot separate it
    /// from the Preston coefficient (no offset or pressure variation).
    #[arg(long, allow_negative_numbers = true, default_value_t = 2.0)]
    pub modulus_mpa: f64,
    /// Write the bundled synthetic sample sweep (maps + manifest.toml) into this directory
    /// and exit.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["manifest", "out"])]
    pub make_sample: Option<PathBuf>,
}

fn start_of(args: &Args) -> Result<FitStart, CliError> {
    let gamma = match args.pressure.to_ascii_lowercase().as_str() {
        "parabolic" => 1.0,
        "hertz" => 0.5,
        other => {
            return Err(CliError::usage(format!(
                "--pressure: '{other}' is not parabolic or hertz"
            )))
        }
    };
    for (name, v) in [
        ("--start-radius-mm", args.start_radius_mm),
        ("--modulus-mpa", args.modulus_mpa),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CliError::usage(format!(
                "{name}: {v} must be a positive number"
            )));
        }
    }
    Ok(FitStart {
        radius_mm: args.start_radius_mm,
        modulus_mpa: args.modulus_mpa,
        pressure_exponent: gamma,
        ..FitStart::default()
    })
}

pub fn run(args: &Args) -> Result<(), CliError> {
    if let Some(dir) = &args.make_sample {
        return make_sample(dir);
    }
    let (Some(manifest), Some(out)) = (&args.manifest, &args.out) else {
        return Err(CliError::usage("spots: give MANIFEST and --out DIR"));
    };
    let start = start_of(args)?;
    let text = super::read_text_input(manifest, "a spot manifest (TOML or CSV)")?;
    let n_maps = manifest_len(manifest, &text)?;
    // Progress on stderr, drawn only on a terminal (reading, measuring, then the model fit,
    // which takes most of the time).
    let bar = indicatif::ProgressBar::with_draw_target(
        Some(n_maps as u64),
        indicatif::ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    let bar = Bar(bar);
    let Sweep { report, analyses } = sweep(manifest, &text, &start, &bar)?;
    let n_spots = report.spots.len();
    let bar = bar.0;
    bar.finish_and_clear();
    write_outputs(out, manifest, &report, &analyses).map_err(|e| CliError {
        code: 2,
        message: e,
    })?;
    println!(
        "spots: wrote {}: {n_spots} spots, {} sweeps, {} trend plots",
        out.join("report.html").display(),
        report.sweeps.len(),
        report.trends.len()
    );
    Ok(())
}

fn write_outputs(
    dir: &Path,
    manifest: &Path,
    rep: &SweepReport,
    analyses: &[SpotAnalysis],
) -> Result<(), String> {
    let w = |e: write::WriteError| e.to_string();
    let mut set = write::Set::begin(dir, "spots").map_err(w)?;
    set.json("report.json", &spots::json_out(manifest, rep))
        .map_err(w)?;
    set.bytes("spots.csv", &spots::spots_csv(rep)?).map_err(w)?;
    set.bytes("trends.csv", &spots::trends_csv(rep)?)
        .map_err(w)?;
    let mut models = Vec::new();
    for f in &rep.fits {
        if let Ok(text) = model_toml(f) {
            let name = format!("model_{}.toml", spots::stem(&f.bonnet));
            set.bytes(&name, text.as_bytes()).map_err(w)?;
            models.push((f.bonnet.clone(), name, text));
        }
    }
    let html = spots::render_html(manifest, rep, analyses, &models)?;
    set.bytes("report.html", html.as_bytes()).map_err(w)?;
    set.commit().map_err(w)
}

/// The bundled sample: two bonnets, offset swept 0.2 .. 1.0 mm at the paper's Table 5 settings
/// otherwise, 2-minute spots, 97 x 97 maps at 0.25 mm, 1.5 nm noise, seeded tilt and centre
/// offsets. The suppression bonnet is given a lower Preston coefficient and a softer contact
/// (an assumption for the sample, not a measured fact).
fn make_sample(dir: &Path) -> Result<(), CliError> {
    let (maps, manifest) = sample_sweep(dir)?;
    // The maps and their manifest are published together (never a mix of two runs').
    let w = |e: write::WriteError| CliError {
        code: 2,
        message: e.to_string(),
    };
    let mut set = write::Set::begin(dir, "spots-sample").map_err(w)?;
    for (file, s) in &maps {
        set.surface(file, s, MapFormat::MetroProDat).map_err(w)?;
    }
    set.bytes("manifest.toml", manifest.as_bytes()).map_err(w)?;
    set.commit().map_err(w)?;
    println!(
        "spots: wrote a sample sweep to {} (manifest.toml and its spot maps)",
        dir.display()
    );
    Ok(())
}
