//! `bonnetlab stats FILE [--remove TERMS] [--json] [--pvr] [--bands [F1,F2]] [--minus FILE2]`
//! (contract: shared/spec/interfaces.md).
//!
//! Reads one map (format detected by content), removes the requested terms jointly, and prints
//! the height parameters of the residual over the valid pixels: a JSON object with `--json`
//! (stable field order, no time stamps), a small table otherwise. With `--bands`, also the
//! figure / MSF / fine band RMS of the same residual (`bonnetlab_spectrum::band_split`: areal
//! brick-wall bands projected over the valid pixels, adding up to Sq exactly; a band the map cannot resolve is null
//! with a reason). With `--minus`, the statistics of `FILE - FILE2` on the pixels valid in both
//! (two maps of one grid): of two measurements of an unchanged part with piston and tilt
//! removed, the RMS is the instrument's repeatability that a recipe may declare.

use std::path::PathBuf;

use bonnetlab_spectrum::BAND_EDGES_DEFAULT_PER_MM;
use bonnetlab_surface::Term;

use super::CliError;
pub use crate::pipeline::read_map;
pub use crate::pipeline::stats::{stats_report, stats_report_with_bands, StatsReport};
pub use crate::report::stats::bands_table;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Map file (.dat, .asc, .xyz, .datx, .csv, .exr); the format is detected from the content.
    pub file: PathBuf,
    /// Comma list of form terms removed jointly before the statistics: piston, tilt, power,
    /// zernikeN (Fringe Z1..ZN, N <= 37, circular apertures), legendreD (total degree <= D,
    /// rectangles), or none.
    #[arg(long, default_value = "piston")]
    pub remove: String,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also compute PVr (Evans 2008: PV of a 37-term Fringe Zernike fit + 3 x residual RMS).
    #[arg(long)]
    pub pvr: bool,
    /// Band RMS: figure below F1, MSF from F1 to F2, fine above F2 (cycles/mm; `1/33` style
    /// allowed). Without a value: 1/33,1/0.12 (periods 33 mm and 0.12 mm, the large-optics
    /// MSF convention of shared/spec/metrology.md).
    #[arg(long, value_name = "F1,F2", num_args = 0..=1, default_missing_value = "default")]
    pub bands: Option<String>,
    /// A second map of the same grid subtracted from FILE pixel by pixel (on the pixels valid in
    /// both) before the terms are removed. With two measurements of an unchanged part and
    /// `--remove piston,tilt`, the RMS is the instrument's repeatability (a recipe's
    /// `[measurement] repeatability_nm`).
    #[arg(long, value_name = "FILE2")]
    pub minus: Option<PathBuf>,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let terms =
        Term::parse_list(&args.remove).map_err(|e| CliError::usage(format!("--remove: {e}")))?;
    let bands = match args.bands.as_deref() {
        None => None,
        Some("default") => Some(BAND_EDGES_DEFAULT_PER_MM),
        Some(v) => super::psd::parse_pair(Some(v), "--bands")?,
    };
    let mut s = read_map(&args.file)?;
    if let Some(mf) = &args.minus {
        let m = read_map(mf)?;
        s = crate::pipeline::stats::difference_of(&args.file, &s, mf, &m)?;
    }
    let mut report = stats_report_with_bands(&args.file, &s, &terms, args.pvr, bands)?;
    report.minus = args.minus.as_ref().map(|m| m.display().to_string());
    let text = if args.json {
        let mut j = serde_json::to_string(&report)
            .map_err(|e| CliError::processing(&args.file, format!("cannot encode JSON: {e}")))?;
        j.push('\n');
        j
    } else {
        crate::report::stats::table(&report)
    };
    super::write_stdout(text.as_bytes())
}
