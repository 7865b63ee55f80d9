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

use std::path::{Path, PathBuf};
use std::time::Instant;

use bonnetlab_io::MapFormat;
use bonnetlab_process::dwell::auto_coarsening;
use bonnetlab_process::dwell::feed::{realise, FeedRealisation, FeedSummary};
use bonnetlab_process::dwell::{
    solve_iterative, solve_rifta, DwellCase, DwellSolution, DwellTarget, IterativeOptions,
    MinDwell, MinDwellOptions, RiftaOptions, TradeOffPoint,
};
use bonnetlab_surface::Surface;
use serde::Serialize;

use super::CliError;
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

/// The coarse dwell grid of `min-dwell`: chosen from the TIF, or a factor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coarsen {
    Auto,
    Factor(usize),
}

impl std::str::FromStr for Coarsen {
    type Err = String;
    fn from_str(v: &str) -> Result<Coarsen, String> {
        if v.eq_ignore_ascii_case("auto") {
            return Ok(Coarsen::Auto);
        }
        match v.parse::<usize>() {
            Ok(n) if (1..=16).contains(&n) => Ok(Coarsen::Factor(n)),
            _ => Err(format!("expected `auto` or a factor 1..=16, got `{v}`")),
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
    #[arg(long, conflicts_with = "max_dwell_min")]
    pub target_rms_nm: Option<f64>,
    /// min-dwell: least residual with total dwell <= this (min).
    #[arg(long)]
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
    /// Coarse dwell-grid factors (rows, cols) of min-dwell ([1, 1]: the full grid).
    pub coarsening: [usize; 2],
    pub dwell_grid_rows: usize,
    pub dwell_grid_cols: usize,
    /// Residual vs total dwell (min-dwell: one point per extra uniform removal, `parameter`
    /// in nm; other methods: their knob).
    pub trade_off: Vec<TradeOffPoint>,
    /// What was asked of the trade-off, and whether the chosen point meets it.
    pub target: DwellTarget,
    pub target_met: bool,
    /// Extra uniform removal of the chosen point (nm; min-dwell only).
    pub offset_nm: Option<f64>,
    /// Time of one point's solve (s): the shared start plus the sweep's mean healing and
    /// evaluation per point; `wall_s` covers the whole sweep.
    pub point_solve_s: f64,
    /// Real 2-D FFTs of the chosen point's solve.
    pub fft_count: usize,
    /// The dwell map executed as a raster feed under the machine limits.
    pub feed: FeedSummary,
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

/// A solved case: the report, the chosen solution, its feed realisation, the clear-aperture
/// mask on the dwell grid, the dwell grid's offset in the map (rows, cols) and the pixel size.
pub struct SolvedCase {
    pub report: DwellReport,
    pub solution: DwellSolution,
    pub feed: FeedRealisation,
    pub aperture: ndarray::Array2<bool>,
    pub offset: (usize, usize),
    pub pixel_mm: f64,
}

/// What the user asked of the trade-off.
pub fn target_of(args: &Args) -> Result<DwellTarget, CliError> {
    let pos = |v: f64, name: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(CliError::input(
                &args.case,
                format!("{name} must be a positive number, got {v}"),
            ))
        }
    };
    Ok(match (args.target_rms_nm, args.max_dwell_min) {
        (Some(nm), _) => DwellTarget::ResidualRms {
            nm: pos(nm, "--target-rms-nm")?,
        },
        (None, Some(min)) => DwellTarget::MaxDwell {
            s: 60.0 * pos(min, "--max-dwell-min")?,
        },
        (None, None) => DwellTarget::NoOffset,
    })
}

/// Loads, solves, realises and reports a case (no output files).
pub fn solve_case(
    case_file: &Path,
    method: Method,
    target: DwellTarget,
    iterations: Option<usize>,
    coarsen: Coarsen,
) -> Result<SolvedCase, CliError> {
    let case =
        DwellCase::load(case_file).map_err(|e| CliError::input(case_file, strip(case_file, e)))?;
    let map = super::stats::read_map(&case.surface)?;
    let cp = case.problem(&map).map_err(|e| proc_err(case_file, e))?;
    let pe = |e| proc_err(case_file, e);
    let t0 = Instant::now();
    let mut coarsening = [1, 1];
    let (sol, curve, point_solve_s, offset_nm) = match method {
        Method::MinDwell => {
            let s = match coarsen {
                Coarsen::Auto => auto_coarsening(&cp.problem),
                Coarsen::Factor(n) => n,
            };
            let mut o = MinDwellOptions::with_coarsening(s);
            if let Some(n) = iterations {
                o.iterations = n;
            }
            let mut md =
                MinDwell::new(&cp.problem, &o).map_err(|e| CliError::input(case_file, e))?;
            let (c0, c1) = md.coarsening();
            coarsening = [c0, c1];
            let start_s = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            let (sol, curve) = md.pick(target).map_err(pe)?;
            // One point's solve: the shared start plus the mean healing of the sweep's points.
            let point = start_s + t1.elapsed().as_secs_f64() / curve.len().max(1) as f64;
            let off = sol.trade_off[0].parameter;
            (sol, curve, point, Some(off))
        }
        Method::Rifta => {
            let s = solve_rifta(&cp.problem, &RiftaOptions::default()).map_err(pe)?;
            let c = s.trade_off.clone();
            (s, c, t0.elapsed().as_secs_f64(), None)
        }
        Method::Iterative => {
            let s = solve_iterative(&cp.problem, &IterativeOptions::default()).map_err(pe)?;
            let c = s.trade_off.clone();
            (s, c, t0.elapsed().as_secs_f64(), None)
        }
    };
    let wall_s = t0.elapsed().as_secs_f64();
    let target_met = match target {
        DwellTarget::ResidualRms { nm } => sol.residual_rms_nm <= nm,
        DwellTarget::MaxDwell { s } => sol.total_dwell_s <= s,
        DwellTarget::NoOffset => true,
    };
    let grid = case.dwell_grid(&cp).map_err(pe)?;
    let feed = realise(&cp.problem, &sol.dwell_s, &case.tif, &grid, &case.limits).map_err(pe)?;
    let (r, c) = cp.problem.dim();
    let report = DwellReport {
        residual_rms_nm: sol.residual_rms_nm,
        residual_pv_nm: sol.residual_pv_nm,
        total_dwell_s: sol.total_dwell_s,
        wall_s,
        method: sol.method.clone(),
        case: case_file.display().to_string(),
        iterations: sol.iterations,
        coarsening,
        dwell_grid_rows: r,
        dwell_grid_cols: c,
        trade_off: curve,
        target,
        target_met,
        offset_nm,
        point_solve_s,
        fft_count: sol.fft_count,
        feed: feed.summary.clone(),
        reference: case
            .reference
            .as_ref()
            .and_then(|t| serde_json::to_value(t).ok()),
    };
    Ok(SolvedCase {
        report,
        solution: sol,
        feed,
        aperture: cp.problem.aperture,
        offset: cp.offset,
        pixel_mm: case.pixel_mm,
    })
}

/// Errors from the case loader already name the file; keep the message as is.
fn strip(file: &Path, e: bonnetlab_process::ProcessError) -> String {
    let msg = e.to_string();
    let prefix = format!("{}: ", file.display());
    msg.strip_prefix(&prefix).map(str::to_string).unwrap_or(msg)
}

/// Solves the case; the JSON goes to `--json` (stdout for `-`), or to stdout when neither
/// `--json` nor `--out` is given; otherwise stdout gets a one-line summary of what was written.
pub fn run(args: &Args) -> Result<(), CliError> {
    let target = target_of(args)?;
    let bar = super::progress::spinner("dwell");
    bar.set_message(format!("solving {}", args.case.display()));
    let solved = solve_case(
        &args.case,
        args.method,
        target,
        args.iterations,
        args.coarsen,
    );
    bar.finish_and_clear();
    let solved = solved?;
    if let Some(dir) = &args.out {
        write_outputs(dir, &solved)?;
    }
    let report = &solved.report;
    match &args.json {
        Some(p) => super::emit_json(p, report)?,
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
        super::println_stdout(&summary(report, &written(args)))?;
    }
    Ok(())
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

/// `dwell: wrote A and B: method M, total dwell T min, residual RMS R nm (PV P nm) in the clear
/// aperture`: one line, numbers to their precision.
fn summary(r: &DwellReport, wrote: &[String]) -> String {
    use crate::report::format::sig;
    format!(
        "dwell: wrote {}: {}, total dwell {} min, residual RMS {} nm (PV {} nm) in the clear aperture{}",
        wrote.join(" and "),
        r.method,
        sig(r.total_dwell_s / 60.0, 4),
        sig(r.residual_rms_nm, 4),
        sig(r.residual_pv_nm, 4),
        if r.target_met { "" } else { "; target not met" },
    )
}

/// The reference methods' (total dwell min, residual nm) points of a case's `[reference]`.
fn reference_points(reference: Option<&serde_json::Value>) -> Vec<report::dwell_report::RefPoint> {
    let Some(obj) = reference.and_then(|v| v.as_object()) else {
        return Vec::new();
    };
    obj.iter()
        .filter_map(|(name, v)| {
            let min = v.get("total_dwell_min")?.as_f64()?;
            let rms = v.get("residual_rms_nm")?.as_f64()?;
            Some((name.clone(), min, rms))
        })
        .collect()
}

/// Writes the `--out` files as one set (`report::write::Set`): all are staged under the
/// directory's lock and published together, so a failure part-way leaves the directory as it
/// was and two runs never mix their files.
fn write_outputs(dir: &Path, solved: &SolvedCase) -> Result<(), CliError> {
    let (sol, aperture, offset, pixel_mm) = (
        &solved.solution,
        &solved.aperture,
        solved.offset,
        solved.pixel_mm,
    );
    let werr = super::write_error;
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
    let realised = on_grid(&solved.feed.residual_nm, Some(aperture))?;
    let binding = on_grid(&solved.feed.binding.mapv(f64::from), None)?;
    let mut set = report::write::Set::begin(dir).map_err(werr)?;
    let map = |set: &mut report::write::Set, name: &str, s: &Surface, f: MapFormat| {
        let bytes = bonnetlab_io::encode_surface(s, f)
            .map_err(|e| CliError::processing(dir.join(name), e))?;
        set.bytes(name, &bytes).map_err(werr)
    };
    map(&mut set, "dwell_s.csv", &dwell, MapFormat::Csv)?;
    map(&mut set, "residual.dat", &residual, MapFormat::MetroProDat)?;
    map(
        &mut set,
        "realised_residual.dat",
        &realised,
        MapFormat::MetroProDat,
    )?;
    map(&mut set, "feed_binding.csv", &binding, MapFormat::Csv)?;
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
        &dwell,
        "dwell map (s per pixel)",
        "s",
    )?;
    let (header, cols) = report::dwell_report::trade_off_columns(&solved.report.trade_off);
    let cols: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    set.csv_columns("trade_off.csv", &header, &cols)
        .map_err(werr)?;
    let chosen = sol.trade_off.first().copied().unwrap_or(TradeOffPoint {
        parameter: 0.0,
        residual_rms_nm: sol.residual_rms_nm,
        total_dwell_s: sol.total_dwell_s,
    });
    let refs = reference_points(solved.report.reference.as_ref());
    let bytes = report::dwell_report::trade_off_png(&solved.report.trade_off, &chosen, &refs)
        .map_err(|e| CliError::processing(dir.join("trade_off.png"), e.what))?;
    set.bytes("trade_off.png", &bytes).map_err(werr)?;
    png(
        &mut set,
        "residual.png",
        &residual,
        "residual in the clear aperture (piston, tilt removed)",
        "nm",
    )?;
    set.commit().map_err(werr)
}
