//! `dwell`: the dwell time of a case file (surface, Gaussian TIF, clear aperture; the format of
//! `shared/data/dwell/*.toml`), solved, realised as a raster feed under the case's `[machine]`
//! limits and reported (`DwellReport`, the JSON of `bonnetlab dwell`).
//!
//! `MinDwell` sweeps the extra uniform removal and picks the point asked for ([`target`]); the
//! dwell map is solved on a coarse grid when the TIF is wide enough ([`Coarsen`]). `Rifta` and
//! `Iterative` are the other solvers of `bonnetlab_process::dwell`.

use std::path::Path;
use std::time::Instant;

use bonnetlab_process::dwell::auto_coarsening;
use bonnetlab_process::dwell::feed::{realise, FeedRealisation, FeedSummary};
use bonnetlab_process::dwell::{
    solve_iterative, solve_rifta, Convergence, DwellCase, DwellSolution, DwellTarget,
    IterativeOptions, MinDwell, MinDwellOptions, RiftaOptions, TradeOffPoint,
};
use bonnetlab_surface::Surface;
use ndarray::Array2;
use serde::Serialize;

use super::{read_map, Error};

/// The dwell solver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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
    /// What was asked of the trade-off, and whether the chosen point meets it: the residual
    /// target, or the dwell budget, and (min-dwell) a converged sweep; with neither target, a
    /// converged sweep.
    pub target: DwellTarget,
    pub target_met: bool,
    /// min-dwell: whether the sweep reached what the TIF can do (its best residual against the
    /// unconstrained inverse filter's); null for the other methods.
    pub convergence: Option<Convergence>,
    /// Why the answer should not be trusted (a sweep that did not converge); null otherwise.
    pub note: Option<String>,
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

/// A solved case: the report, the chosen solution, its feed realisation, the clear-aperture
/// mask on the dwell grid, the dwell grid's offset in the map (rows, cols) and the pixel size.
pub struct SolvedCase {
    pub report: DwellReport,
    pub solution: DwellSolution,
    pub feed: FeedRealisation,
    pub aperture: Array2<bool>,
    pub offset: (usize, usize),
    pub pixel_mm: f64,
}

/// The maps of a solved case, placed where the dwell grid sits in the case's map.
pub struct DwellMaps {
    /// Dwell time, s per pixel.
    pub dwell_s: Surface,
    /// Residual of the solution in the clear aperture, nm.
    pub residual_nm: Surface,
    /// Residual of the executed feed in the clear aperture, nm.
    pub realised_residual_nm: Surface,
    /// Where the machine's limits bind: 0 free, 1 velocity, 2 acceleration.
    pub feed_binding: Surface,
}

fn proc_err(file: &Path, e: bonnetlab_process::ProcessError) -> Error {
    if e.is_bad_input() {
        Error::input(file, e)
    } else {
        Error::processing(file, e)
    }
}

/// What is asked of the trade-off: least dwell at a residual RMS (nm), least residual within a
/// dwell budget (min), or neither. `case` names the case in the error of a value that is not a
/// positive number.
pub fn target(
    case: &Path,
    target_rms_nm: Option<f64>,
    max_dwell_min: Option<f64>,
) -> Result<DwellTarget, Error> {
    let pos = |v: f64, name: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(Error::input(
                case,
                format!("{name} must be a positive number, got {v}"),
            ))
        }
    };
    Ok(match (target_rms_nm, max_dwell_min) {
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
) -> Result<SolvedCase, Error> {
    let case =
        DwellCase::load(case_file).map_err(|e| Error::input(case_file, strip(case_file, e)))?;
    let map = read_map(&case.surface)?;
    let cp = case.problem(&map).map_err(|e| proc_err(case_file, e))?;
    let pe = |e| proc_err(case_file, e);
    let t0 = Instant::now();
    let mut coarsening = [1, 1];
    let mut convergence = None;
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
            let mut md = MinDwell::new(&cp.problem, &o).map_err(|e| Error::input(case_file, e))?;
            let (c0, c1) = md.coarsening();
            coarsening = [c0, c1];
            let start_s = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            let (sol, curve) = md.pick(target).map_err(pe)?;
            // One point's solve: the shared start plus the mean healing of the sweep's points.
            let point = start_s + t1.elapsed().as_secs_f64() / curve.len().max(1) as f64;
            convergence = Some(md.convergence(&curve));
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
    // A budget may leave the chosen point's residual high, so it asks a converged sweep;
    // without a target the chosen point itself must be within the convergence limit.
    let converged = convergence.is_none_or(|c| c.converged);
    let target_met = match target {
        DwellTarget::ResidualRms { nm } => sol.residual_rms_nm <= nm,
        DwellTarget::MaxDwell { s } => sol.total_dwell_s <= s && converged,
        DwellTarget::NoOffset => {
            convergence.is_none_or(|c| c.converged && sol.residual_rms_nm <= c.limit_nm)
        }
    };
    let note = convergence.filter(|c| !c.converged).map(|c| {
        format!(
            "min-dwell did not converge: the best residual of its trade-off is {:.4} nm RMS, \
             above {:.4} nm (the unconstrained inverse filter reaches {:.4} nm with this TIF); \
             try --method iterative or more --iterations",
            c.best_residual_rms_nm, c.limit_nm, c.unconstrained_residual_rms_nm
        )
    });
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
        convergence,
        note,
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

impl SolvedCase {
    /// The dwell, residual, executed-residual and feed-binding maps on the dwell grid, at its
    /// place in the case's map (the residuals masked to the clear aperture). `out` names the
    /// output in an error.
    pub fn maps(&self, out: &Path) -> Result<DwellMaps, Error> {
        let (offset, pixel_mm) = (self.offset, self.pixel_mm);
        let on_grid = |a: &Array2<f64>, mask: Option<&Array2<bool>>| -> Result<Surface, Error> {
            let valid = mask.cloned().unwrap_or_else(|| a.mapv(|_| true));
            let mut s = Surface::with_mask(a.clone(), valid, Some(pixel_mm), Some(pixel_mm))
                .map_err(|e| Error::processing(out, e))?;
            s.origin_mm = (offset.1 as f64 * pixel_mm, offset.0 as f64 * pixel_mm);
            s.provenance.format = "synthetic".into();
            Ok(s)
        };
        Ok(DwellMaps {
            dwell_s: on_grid(&self.solution.dwell_s, None)?,
            residual_nm: on_grid(&self.solution.residual_nm, Some(&self.aperture))?,
            realised_residual_nm: on_grid(&self.feed.residual_nm, Some(&self.aperture))?,
            feed_binding: on_grid(&self.feed.binding.mapv(f64::from), None)?,
        })
    }

    /// The chosen point of the trade-off (the solution's own when it has none).
    pub fn chosen(&self) -> TradeOffPoint {
        let sol = &self.solution;
        sol.trade_off.first().copied().unwrap_or(TradeOffPoint {
            parameter: 0.0,
            residual_rms_nm: sol.residual_rms_nm,
            total_dwell_s: sol.total_dwell_s,
        })
    }
}
