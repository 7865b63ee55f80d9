//! The checks `simulate` and `calibrate` make on an accepted recipe before they allocate
//! (`recipe-x` runs them after `Recipe::parse`), on a reference before-map grid instead of the
//! recipe's maps (maps are fuzzed by the byte readers):
//!
//! - the TIF sampled at the map pitch (`ToolModel::from_source`, which refuses a footprint of
//!   more than `simulate::MAX_TIF_PIXELS` before sampling it);
//! - the path log (a generated one with extreme rows, chosen by the input's hash) read and
//!   checked against the part plus the spot (`path::log::check_extent`, with the margin both
//!   pipelines use);
//! - the exact deposition's sub-step budget (`removal::check_exact_budget`, for `--exact`);
//! - the `[vibration]` parameters as `simulate` builds them (`VibrationParams::from_parts`).
//!
//! An input that passes all of them is one the CLI would run. Its cost is then predicted from
//! the sizes the pipeline builds: the fast removal's transform of the map grid grown by the
//! footprint (about 64 bytes per transform pixel: the real buffer, three kernel spectra and
//! two work spectra) plus the sampled TIF and its kernels (40 bytes per footprint pixel). An
//! accepted input predicted over [`BUDGET_BYTES`] is a finding (`BUDGET:` error).
//!
//! The TIF sampling runs for real, so its time and heap are measured like every input's,
//! except that a footprint of more than [`LARGE_PIXELS`] (up to the 1001 x 1001 pixels
//! `from_source` allows, about 0.3 s to sample) is sampled for real only the first
//! [`LARGE_SAMPLED`] times in a run; later ones pass the same size check
//! (`simulate::check_footprint`, which `from_source` applies first) and are counted in
//! [`LARGE_TIFS`], so a million inputs stay within minutes.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use bonnetlab_process::path::log::{check_extent, read_path_from};
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::removal::{check_exact_budget, exact_step, ExactOptions};
use bonnetlab_process::simulate::{check_footprint, ToolModel};
use bonnetlab_process::tif::bonnet::BonnetTif;
use bonnetlab_process::{Grid, RateField, Recipe};
use bonnetlab_surface::rng::Rng;

/// The memory an accepted input may need (the bound).
pub const BUDGET_BYTES: f64 = 1024.0 * 1024.0 * 1024.0;
/// A footprint above this many pixels is "large".
const LARGE_PIXELS: f64 = 250_000.0;
/// Large footprints sampled for real per run.
const LARGE_SAMPLED: u64 = 10;
/// Large footprints checked for size but not sampled.
pub static LARGE_TIFS: AtomicU64 = AtomicU64::new(0);
static LARGE_SEEN: AtomicU64 = AtomicU64::new(0);
/// Recipes that passed every check of the default (fast) mode: the CLI would run them.
pub static ACCEPTED: AtomicU64 = AtomicU64::new(0);

/// Reference before-map grids: (rows, cols, pixel mm).
const GRIDS: [(usize, usize, f64); 3] = [(100, 150, 0.5), (1000, 1000, 0.1), (40, 60, 2.0)];

fn hash(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Smallest 2^a 3^b 5^c >= n (an upper bound of the transform length the convolver picks).
fn fast_len(n: f64) -> f64 {
    let mut best = f64::INFINITY;
    let mut p2 = 1.0;
    while p2 < 2.0 * n {
        let mut p3 = p2;
        while p3 < 2.0 * n {
            let mut p5 = p3;
            while p5 < 2.0 * n {
                if p5 >= n {
                    best = best.min(p5);
                }
                p5 *= 5.0;
            }
            p3 *= 3.0;
        }
        p2 *= 2.0;
    }
    best.max(n)
}

/// Runs the pre-allocation checks on an accepted recipe; Err is the rejection (or a `BUDGET:`
/// finding).
pub fn recipe(recipe: &Recipe, bytes: &[u8]) -> Result<(), String> {
    let h = hash(bytes);
    let (rows, cols, px) = GRIDS[(h % GRIDS.len() as u64) as usize];
    let grid = Grid::new(rows, cols, px, px, 0.0, 0.0).map_err(|e| e.to_string())?;
    let p = &recipe.process;
    let _ = bonnetlab_vibration::params::VibrationParams::from_parts(
        recipe.vibration.as_ref(),
        p.spindle_rpm,
        p.offset_mm,
        p.inner_pressure_mpa,
        None,
    );
    // A measured spot needs its map (read by the map readers, fuzzed there).
    if matches!(recipe.tif, TifSource::Spot { .. }) {
        return Ok(());
    }
    let model: Box<dyn RateField>;
    let field: &dyn RateField = match &recipe.tif {
        TifSource::Gaussian(g) => {
            model = Box::new(*g);
            model.as_ref()
        }
        TifSource::Bonnet(b) => {
            model = Box::new(BonnetTif::new(b).map_err(|e| e.to_string())?);
            model.as_ref()
        }
        TifSource::Spot { .. } => unreachable!("returned above"),
    };
    let (ex, ey) = field.half_extent_mm();
    let (h1, h0) = ((ex / px + 1e-9).floor(), (ey / px + 1e-9).floor());
    let tif_pixels = (2.0 * h0 + 1.0) * (2.0 * h1 + 1.0);
    if tif_pixels > LARGE_PIXELS && LARGE_SEEN.fetch_add(1, Ordering::Relaxed) >= LARGE_SAMPLED {
        check_footprint(field, px, px).map_err(|e| e.to_string())?;
        LARGE_TIFS.fetch_add(1, Ordering::Relaxed);
    } else {
        let tool = ToolModel::from_source(&recipe.tif, None, px, px).map_err(|e| e.to_string())?;
        // The sampled tool's field is the model's (same half-extents).
        debug_assert_eq!(tool.field().half_extent_mm(), (ex, ey));
    }
    // The path log: a generated one with extreme rows.
    let log = super::mutate::extreme_path_log(&mut Rng::new(h));
    let name = Path::new("/nonexistent/path.csv");
    let path = read_path_from(&log[..], name).map_err(|e| e.to_string())?;
    let (x1, y1) = (grid.x_mm(cols - 1), grid.y_mm(rows - 1));
    check_extent(&path, name, (0.0, x1), (0.0, y1), ex.max(ey) + x1.max(y1))
        .map_err(|e| e.to_string())?;
    let opts = ExactOptions::default();
    let exact = exact_step(field, &grid, &opts)
        .and_then(|step| check_exact_budget(&path, &grid, step, &opts, (ex, ey)));
    // Predicted memory of the fast removal (the default mode, which an input refused for
    // --exact still runs).
    let ext = (
        fast_len(rows as f64 + 2.0 * (h0 + 2.0)),
        fast_len(cols as f64 + 2.0 * (h1 + 2.0)),
    );
    let bytes_fast = 64.0 * ext.0 * ext.1 + 40.0 * tif_pixels;
    ACCEPTED.fetch_add(1, Ordering::Relaxed);
    if bytes_fast > BUDGET_BYTES {
        return Err(format!(
            "BUDGET: accepted recipe, footprint {} x {} px at {px} mm (half-extent {ex:.4e} x \
             {ey:.4e} mm) on a {rows} x {cols} map: fast removal needs about {:.3e} bytes",
            2.0 * h1 + 1.0,
            2.0 * h0 + 1.0,
            bytes_fast
        ));
    }
    exact.map_err(|e| e.to_string())
}
