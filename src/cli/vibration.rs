//! `bonnetlab vibration [RECIPE.toml] [--bonnet original|suppression|both] [--json OUT] [--out DIR]`
//! (contract: shared/spec/interfaces.md).
//!
//! The two-degree-of-freedom forced response (DOMAIN.md section 2) for the bonnet named in the
//! recipe's `[process]` (or `--bonnet`), with parameters from the optional `[vibration]` table;
//! every default is documented in `bonnetlab_vibration::params`. Only the `[process]`,
//! `[vibration]`, `[tif]` and `[path]` tables are read, so a recipe holding just those works.
//!
//! `--json OUT` writes one JSON object (`-` for stdout); with `--bonnet both` it writes a JSON
//! array of two such objects, original first. `--out DIR` writes the FRF plots of both bonnets
//! (`frf_x1.svg/.png`, `frf_x2.svg/.png`, the paper's figures 10 and 15 as curves over the spindle
//! band) and `timeseries.csv` (tool-tip displacement for `--duration-s` seconds at 1 kHz,
//! including ring-down after the reversals of the recipe's path log when it has one).

use std::path::PathBuf;

use super::CliError;
use crate::pipeline::vibration::response;
use crate::report;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Run recipe (TOML); its [process] names the bonnet and spindle speed, [vibration] overrides defaults.
    pub recipe: Option<PathBuf>,
    /// Bonnet to model: original, suppression or both (default: the recipe's [process] bonnet, else original).
    #[arg(long)]
    pub bonnet: Option<String>,
    /// Write the JSON result to this file ("-" for stdout).
    #[arg(long, value_name = "OUT")]
    pub json: Option<PathBuf>,
    /// Directory for the FRF plots and the tool-tip time series.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Length of the time series written to DIR, seconds.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10.0)]
    pub duration_s: f64,
    /// Seed of the broadband force noise in the time series.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let text = match &args.recipe {
        Some(p) => Some(super::read_text_input(p, "a recipe (TOML)")?),
        None => None,
    };
    let recipe = args.recipe.as_deref().zip(text.as_deref());
    let v = response(recipe, args.bonnet.as_deref(), args.duration_s)?;

    // Everything is computed first; the --out files (one set, `report::write::Set`, staged
    // first: it creates the directory, where the --json file may be) and the --json file are
    // then published together or not at all, before the summary.
    let mut published = super::Outputs::default();
    if let Some(dir) = &args.out {
        let outputs = v.outputs(args.duration_s, args.seed, &dir.join("timeseries.csv"))?;
        let werr = super::write_error;
        let mut set = report::write::Set::begin(dir, "vibration").map_err(werr)?;
        for dof in 0..2 {
            let plot = report::vibration::frf_plot(&v.params, &outputs.frf, dof);
            let stem = format!("frf_x{}", dof + 1);
            let svg = plot
                .to_svg()
                .map_err(|e| CliError::processing(set.path(&stem), e))?;
            set.bytes(&format!("{stem}.svg"), svg.as_bytes())
                .map_err(werr)?;
            let png = plot
                .to_png()
                .map_err(|e| CliError::processing(set.path(&stem), e))?;
            set.bytes(&format!("{stem}.png"), &png).map_err(werr)?;
        }
        let csv = report::vibration::timeseries_csv(&outputs.timeseries);
        set.bytes("timeseries.csv", &csv).map_err(werr)?;
        published.set(set);
    }
    if let Some(json_path) = &args.json {
        let text = if v.outs.len() == 1 {
            serde_json::to_string_pretty(&v.outs[0])
        } else {
            serde_json::to_string_pretty(&v.outs)
        }
        .map_err(|e| CliError::processing(json_path, e))?;
        published.file(json_path, format!("{text}\n").as_bytes())?;
    }
    published.publish()?;

    if let Some(json_path) = &args.json {
        if !super::is_stdout(json_path) {
            let mut wrote = vec![json_path.display().to_string()];
            wrote.extend(args.out.iter().map(|d| format!("{}/", d.display())));
            super::println_stdout(&report::vibration::written_line(&wrote, &v.outs))?;
        }
    } else {
        let mut text = report::vibration::summary(&v.params, &v.outs);
        if let Some(dir) = &args.out {
            text += &format!(
                "vibration: wrote {}/ (FRF plots and the tool-tip time series)\n",
                dir.display()
            );
        }
        super::write_stdout(text.as_bytes())?;
    }
    Ok(())
}
