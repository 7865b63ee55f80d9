//! `bonnetlab dwell CASE.toml [--json OUT] [--out DIR] [--method min-dwell|rifta|iterative]
//! [--target-rms-nm X | --max-dwell-min M]`
//! (contract: shared/spec/interfaces.md).
//!
//! Solves the dwell time of a case file (surface, Gaussian TIF, clear aperture; the format of
//! `shared/data/dwell/*.toml`). The JSON holds `residual_rms_nm`, `residual_pv_nm` (in the clear
//! aperture, piston and tilt removed), `total_dwell_s`, `wall_s` (solver only, no file reading)
//! and `method`, plus the trade-off points and the case's reference figures. `--out DIR` writes
//! the dwell map (`dwell_s.csv`, seconds per pixel), the residual map (`residual.dat`, nm) and
//! plots (`dwell_map.png`, `residual.png`), the trade-off curve (`trade_off.csv`,
//! `trade_off.png`), the executed residual (`realised_residual.dat`) and where the machine's
//! limits bind (`feed_binding.csv`: 0 free, 1 velocity, 2 acceleration).
//!
//! `min-dwell` (default) sweeps the extra uniform removal and picks the point asked for:
//! `--target-rms-nm` (least total dwell at that residual), `--max-dwell-min` (least residual
//! within that budget), or neither (no extra removal); `--iterations` sets the healing
//! iterations per point. The dwell map is solved on a coarse grid (nodes every `s` pixels,
//! cubic B-spline onto the full grid, then 20 healing passes on the full grid) when the TIF is
//! wide enough: `--coarsen auto` (default) takes the largest `s <= 8` with the TIF's RMS
//! width at least 2 node spacings and the clear aperture at least 8 nodes across
//! (`auto_coarsening`); case A
//! (TIF 2.8 px) stays on the full grid, case B (11.8 px) uses s = 5. `--coarsen N` overrides
//! (1: the full grid). Every method's map is then realised as a
//! raster feed under the case's `[machine]` limits and the executed residual reported (`feed`).
//! A min-dwell sweep that did not converge (`convergence`) still writes its outputs, with a
//! `note`, and the command ends with exit code 1.

use std::path::{Path, PathBuf};

use bonnetlab_io::MapFormat;
use bonnetlab_surface::Surface;

use super::CliError;
use crate::pipeline::dwell::{self as pipeline, Coarsen, SolvedCase};
use crate::report;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Least total dwell at the residual target: RIFTA start, chosen uniform offset, projected
    /// gradient (non-negative).
    MinDwell,
    /// Inverse filter with preconditioned conjugate-gradient refinement (fast).
    Rifta,
    /// Accelerated projected gradient, non-negative throughout (slower).
    Iterative,
}

impl From<Method> for pipeline::Method {
    fn from(m: Method) -> Self {
        match m {
            Method::MinDwell => pipeline::Method::MinDwell,
            Method::Rifta => pipeline::Method::Rifta,
            Method::Iterative => pipeline::Method::Iterative,
        }
    }
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
    #[arg(long, value_enum, default_value = "min-dwell")]
    pub method: Method,
    /// min-dwell: least total dwell with residual RMS <= this (nm).
    #[arg(long, allow_negative_numbers = true, conflicts_with = "max_dwell_min")]
    pub target_rms_nm: Option<f64>,
    /// min-dwell: least residual with total dwell <= this (min).
    #[arg(long, allow_negative_numbers = true)]
    pub max_dwell_min: Option<f64>,
    /// min-dwell: healing (ADMM) iterations per trade-off point, on the coarse grid when one
    /// is used (more: lower residual at the same total dwell, slower). Default: 80 on the full
    /// grid, 300 on a coarse grid (then 20 on the full grid).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// min-dwell: coarse dwell grid, `auto` or a factor N (nodes every N pixels, at most; 1: the
    /// full grid). `auto` takes the largest N <= 8 with the TIF's RMS width >= 2 node spacings
    /// and the clear aperture >= 8 nodes across (a TIF only a few pixels wide stays on the
    /// full grid).
    #[arg(long, default_value = "auto")]
    pub coarsen: Coarsen,
}

/// Solves the case; the JSON goes to `--json` (stdout for `-`), or to stdout when neither
/// `--json` nor `--out` is given; otherwise stdout gets a one-line summary of what was written.
pub fn run(args: &Args) -> Result<(), CliError> {
    let target = pipeline::target(&args.case, args.target_rms_nm, args.max_dwell_min)?;
    let bar = super::progress::spinner("dwell");
    bar.set_message(format!("solving {}", args.case.display()));
    let solved = pipeline::solve_case(
        &args.case,
        args.method.into(),
        target,
        args.iterations,
        args.coarsen,
    );
    bar.finish_and_clear();
    let solved = solved?;
    // The --out files and the --json file are published together or not at all.
    // The set first: it creates the --out directory, where the --json file may be.
    let mut outputs = super::Outputs::default();
    let report = &solved.report;
    if let Some(dir) = &args.out {
        outputs.set(stage_outputs(dir, &solved)?);
    }
    if let Some(p) = &args.json {
        let text = serde_json::to_string_pretty(report)
            .map_err(|e| CliError::processing(p, format!("JSON: {e}")))?;
        outputs.file(p, format!("{text}\n").as_bytes())?;
    }
    outputs.publish()?;
    match &args.json {
        Some(_) => {}
        None if args.out.is_none() => {
            let text = serde_json::to_string_pretty(report)
                .map_err(|e| CliError::processing(&args.case, e))?;
            super::println_stdout(&text)?
        }
        None => {}
    }
    let json_on_stdout = match &args.json {
        Some(p) => super::is_stdout(p),
        None => args.out.is_none(),
    };
    if !json_on_stdout {
        super::println_stdout(&report::dwell_report::summary(report, &written(args)))?;
    }
    // An answer that did not converge is written (to be looked at) but never passes as one.
    match &report.note {
        Some(note) => Err(CliError::processing(&args.case, note)),
        None => Ok(()),
    }
}

/// The files `dwell` wrote, as its summary names them.
fn written(args: &Args) -> Vec<String> {
    let mut wrote = Vec::new();
    if let Some(dir) = &args.out {
        wrote.push(format!("{}/", dir.display()));
    }
    if let Some(j) = args.json.as_deref().filter(|j| !super::is_stdout(j)) {
        wrote.push(j.display().to_string());
    }
    wrote
}

/// Stages the `--out` files as one set (`report::write::Set`): all are staged under the
/// directory's lock and published together by the caller, so a failure part-way leaves the
/// directory as it was and two runs never mix their files.
fn stage_outputs(dir: &Path, solved: &SolvedCase) -> Result<report::write::Set, CliError> {
    let werr = super::write_error;
    let maps = solved.maps(dir)?;
    let mut set = report::write::Set::begin(dir, "dwell").map_err(werr)?;
    let map = |set: &mut report::write::Set, name: &str, s: &Surface, f: MapFormat| {
        let bytes = bonnetlab_io::encode_surface(s, f)
            .map_err(|e| CliError::processing(dir.join(name), e))?;
        set.bytes(name, &bytes).map_err(werr)
    };
    // The CSV grids say what they hold (the generic writer's header says heights in nm).
    let grid = |set: &mut report::write::Set, name: &str, s: &Surface, what: &str| {
        let mut bytes = Vec::new();
        bonnetlab_io::csv_grid::write_labelled(s, &mut bytes, what)
            .map_err(|e| CliError::processing(dir.join(name), e))?;
        set.bytes(name, &bytes).map_err(werr)
    };
    grid(
        &mut set,
        "dwell_s.csv",
        &maps.dwell_s,
        "dwell map: seconds per pixel",
    )?;
    map(
        &mut set,
        "residual.dat",
        &maps.residual_nm,
        MapFormat::MetroProDat,
    )?;
    map(
        &mut set,
        "realised_residual.dat",
        &maps.realised_residual_nm,
        MapFormat::MetroProDat,
    )?;
    grid(
        &mut set,
        "feed_binding.csv",
        &maps.feed_binding,
        "feed limit that binds per pixel: 0 none, 1 velocity, 2 acceleration",
    )?;
    let png = |set: &mut report::write::Set,
               name: &str,
               s: &Surface,
               title: &str,
               unit: &str|
     -> Result<(), CliError> {
        let bytes = report::maps::false_colour_png(s, title, unit)
            .map_err(|e| CliError::processing(dir.join(name), e.what))?;
        set.bytes(name, &bytes).map_err(werr)
    };
    png(
        &mut set,
        "dwell_map.png",
        &maps.dwell_s,
        "dwell map (s per pixel)",
        "s",
    )?;
    let (header, cols) = report::dwell_report::trade_off_columns(&solved.report.trade_off);
    let cols: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    set.csv_columns("trade_off.csv", &header, &cols)
        .map_err(werr)?;
    let refs = report::dwell_report::reference_points(solved.report.reference.as_ref());
    let bytes =
        report::dwell_report::trade_off_png(&solved.report.trade_off, &solved.chosen(), &refs)
            .map_err(|e| CliError::processing(dir.join("trade_off.png"), e.what))?;
    set.bytes("trade_off.png", &bytes).map_err(werr)?;
    png(
        &mut set,
        "residual.png",
        &maps.residual_nm,
        "residual in the clear aperture (piston, tilt removed)",
        "nm",
    )?;
    Ok(set)
}
