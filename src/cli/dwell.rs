//! `bonnetlab dwell CASE.toml [--json OUT] [--out DIR] [--method rifta|iterative]`
//! (contract: shared/spec/interfaces.md).
//!
//! Solves the dwell time of a case file (surface, Gaussian TIF, clear aperture; the format of
//! `shared/data/dwell/*.toml`). The JSON holds `residual_rms_nm`, `residual_pv_nm` (in the clear
//! aperture, piston and tilt removed), `total_dwell_s`, `wall_s` (solver only, no file reading)
//! and `method`, plus the trade-off points and the case's reference figures. `--out DIR` writes
//! the dwell map (`dwell_s.csv`, seconds per pixel), the residual map (`residual.dat`, nm) and
//! plots (`dwell_map.png`, `residual.png`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use bonnetlab_io::MapFormat;
use bonnetlab_process::dwell::{
    solve_iterative, solve_rifta, DwellCase, DwellSolution, IterativeOptions, RiftaOptions,
    TradeOffPoint,
};
use bonnetlab_surface::Surface;
use serde::Serialize;

use super::CliError;
use crate::report;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Inverse filter with preconditioned conjugate-gradient refinement (fast).
    Rifta,
    /// Accelerated projected gradient, non-negative throughout (slower).
    Iterative,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Case file (TOML: surface, [tif], [clear_aperture]).
    pub case: PathBuf,
    /// Write the JSON result here (otherwise it goes to stdout).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the dwell map, residual map and plots into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Solver.
    #[arg(long, value_enum, default_value = "rifta")]
    pub method: Method,
}

/// The JSON written by `dwell` (the first five fields are the CLI contract).
#[derive(Debug, Clone, Serialize)]
pub struct DwellReport {
    pub residual_rms_nm: f64,
    pub residual_pv_nm: f64,
    pub total_dwell_s: f64,
    pub wall_s: f64,
    pub method: String,
    pub case: String,
    pub iterations: usize,
    pub dwell_grid_rows: usize,
    pub dwell_grid_cols: usize,
    pub trade_off: Vec<TradeOffPoint>,
    /// The case's `[reference]` table, unchanged, for side-by-side reading.
    pub reference: Option<serde_json::Value>,
}

fn proc_err(file: &Path, e: bonnetlab_process::ProcessError) -> CliError {
    if e.is_bad_input() {
        CliError::input(file, e)
    } else {
        CliError::processing(file, e)
    }
}

/// Loads, solves and reports a case (no output files).
/// The solved case: report, solution, clear-aperture mask on the dwell grid, the dwell grid's
/// offset in the map (rows, cols) and the pixel size.
pub type SolvedCase = (
    DwellReport,
    DwellSolution,
    ndarray::Array2<bool>,
    (usize, usize),
    f64,
);

pub fn solve_case(case_file: &Path, method: Method) -> Result<SolvedCase, CliError> {
    let case =
        DwellCase::load(case_file).map_err(|e| CliError::input(case_file, strip(case_file, e)))?;
    let map = super::stats::read_map(&case.surface)?;
    let cp = case.problem(&map).map_err(|e| proc_err(case_file, e))?;
    let t0 = Instant::now();
    let sol = match method {
        Method::Rifta => solve_rifta(&cp.problem, &RiftaOptions::default()),
        Method::Iterative => solve_iterative(&cp.problem, &IterativeOptions::default()),
    }
    .map_err(|e| proc_err(case_file, e))?;
    let wall_s = t0.elapsed().as_secs_f64();
    let (r, c) = cp.problem.dim();
    let report = DwellReport {
        residual_rms_nm: sol.residual_rms_nm,
        residual_pv_nm: sol.residual_pv_nm,
        total_dwell_s: sol.total_dwell_s,
        wall_s,
        method: sol.method.clone(),
        case: case_file.display().to_string(),
        iterations: sol.iterations,
        dwell_grid_rows: r,
        dwell_grid_cols: c,
        trade_off: sol.trade_off.clone(),
        reference: case
            .reference
            .as_ref()
            .and_then(|t| serde_json::to_value(t).ok()),
    };
    Ok((report, sol, cp.problem.aperture, cp.offset, case.pixel_mm))
}

/// Errors from the case loader already name the file; keep the message as is.
fn strip(file: &Path, e: bonnetlab_process::ProcessError) -> String {
    let msg = e.to_string();
    let prefix = format!("{}: ", file.display());
    msg.strip_prefix(&prefix).map(str::to_string).unwrap_or(msg)
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let (report, sol, aperture, offset, pixel_mm) = solve_case(&args.case, args.method)?;
    if let Some(dir) = &args.out {
        write_outputs(dir, &sol, &aperture, offset, pixel_mm)?;
    }
    let text =
        serde_json::to_string_pretty(&report).map_err(|e| CliError::processing(&args.case, e))?;
    match &args.json {
        Some(p) => super::emit_json(p, &report)?,
        None => super::println_stdout(&text)?,
    }
    Ok(())
}

fn write_outputs(
    dir: &Path,
    sol: &DwellSolution,
    aperture: &ndarray::Array2<bool>,
    offset: (usize, usize),
    pixel_mm: f64,
) -> Result<(), CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::input(dir, format!("cannot create the output directory: {e}")))?;
    let on_grid = |a: &ndarray::Array2<f64>,
                   mask: Option<&ndarray::Array2<bool>>|
     -> Result<Surface, CliError> {
        let valid = mask.cloned().unwrap_or_else(|| a.mapv(|_| true));
        let mut s = Surface::with_mask(a.clone(), valid, Some(pixel_mm), Some(pixel_mm))
            .map_err(|e| CliError::processing(dir, e))?;
        s.origin_mm = (offset.1 as f64 * pixel_mm, offset.0 as f64 * pixel_mm);
        s.provenance.format = "synthetic".into();
        Ok(s)
    };
    let dwell = on_grid(&sol.dwell_s, None)?;
    let residual = on_grid(&sol.residual_nm, Some(aperture))?;
    let w = |p: PathBuf, s: &Surface, f: MapFormat| {
        bonnetlab_io::write_surface(&p, s, f).map_err(|e| CliError {
            code: e.exit_code(),
            message: e.to_string(),
        })
    };
    w(dir.join("dwell_s.csv"), &dwell, MapFormat::Csv)?;
    w(dir.join("residual.dat"), &residual, MapFormat::MetroProDat)?;
    let png = |name: &str, s: &Surface, title: &str, unit: &str| -> Result<(), CliError> {
        let bytes = report::maps::false_colour_png(s, title, unit)
            .map_err(|e| CliError::processing(dir.join(name), e.what))?;
        report::write::bytes(&dir.join(name), &bytes).map_err(|e| CliError::input(&e.file, e.what))
    };
    png("dwell_map.png", &dwell, "dwell map (s per pixel)", "s")?;
    png(
        "residual.png",
        &residual,
        "residual in the clear aperture (piston, tilt removed)",
        "nm",
    )?;
    Ok(())
}
