//! Feed realisation: a dwell map executed as a raster whose feed the machine can follow.
//!
//! The dwell grid's rows are the raster lines (pitch = the row pitch), scanned along X in both
//! directions. Along a line the time per mm is the dwell density (s/mm^2) times the pitch, so
//! the commanded feed is v = dx / T (T in s per pixel), clamped to the machine's [v_min, v_max]
//! ([`crate::path::kinematics::dwell_raster`]); the acceleration limit then re-times it
//! ([`crate::path::kinematics::apply_limits`]). The executed path is simulated with the
//! project's one forward model ([`crate::removal::FastRemoval`], the moving tool's line
//! integrals) and its residual reported beside the planned one.
//!
//! Where limits bind: a pixel whose planned dwell is below the least the raster can give at
//! v_max (dx / v_max), or above the most at v_min, is velocity-bound; a pixel whose executed
//! dwell differs from the commanded path's by more than 1 % of max(commanded, mean dwell) is
//! acceleration-bound (the feed could not change fast enough there).

use ndarray::Array2;
use serde::Serialize;

use super::DwellProblem;
use crate::error::ProcessError;
use crate::grid::Grid;
use crate::path::kinematics::{dwell_raster, Limits};
use crate::path::{PathLog, RasterSpec};
use crate::removal::{dwell_map, FastRemoval};
use crate::tif::RateField;

/// Binding codes of [`FeedRealisation::binding`].
pub const FREE: u8 = 0;
pub const VELOCITY_BOUND: u8 = 1;
pub const ACCELERATION_BOUND: u8 = 2;

/// Figures of a realised feed schedule (all residuals in the CA, piston and tilt removed).
#[derive(Debug, Clone, Serialize)]
pub struct FeedSummary {
    pub limits: Limits,
    pub pitch_mm: f64,
    /// Planned dwell map's total (s).
    pub planned_total_dwell_s: f64,
    /// Duration of the commanded path (feeds clamped, no acceleration limit) and of the
    /// executed one (s); both include the step-overs between lines.
    pub commanded_duration_s: f64,
    pub realised_duration_s: f64,
    /// Residual of the commanded path and of the executed path through the forward model.
    pub commanded_residual_rms_nm: f64,
    pub realised_residual_rms_nm: f64,
    pub realised_residual_pv_nm: f64,
    /// Dwell-grid pixels where the velocity / acceleration limit binds, and their share.
    pub velocity_bound_pixels: usize,
    pub acceleration_bound_pixels: usize,
    pub bound_fraction: f64,
    /// Path samples of the executed path.
    pub path_samples: usize,
}

/// A realised feed schedule with its maps.
#[derive(Debug, Clone)]
pub struct FeedRealisation {
    pub summary: FeedSummary,
    /// The executed path (the schedule: times and positions).
    pub path: PathLog,
    /// Removal (nm) of the executed path on the dwell grid, and its CA residual.
    pub removal_nm: Array2<f64>,
    pub residual_nm: Array2<f64>,
    /// Per dwell-grid pixel: [`FREE`], [`VELOCITY_BOUND`] or [`ACCELERATION_BOUND`].
    pub binding: Array2<u8>,
}

/// Realises `dwell_s` (s per pixel on `grid`, the problem's dwell grid) as a raster under
/// `limits`, with the continuous rate field `field` (the model the problem's TIF samples).
pub fn realise<F: RateField + Send + Clone + 'static>(
    p: &DwellProblem,
    dwell_s: &Array2<f64>,
    field: &F,
    grid: &Grid,
    limits: &Limits,
) -> Result<FeedRealisation, ProcessError> {
    if dwell_s.dim() != p.dim() || (grid.rows, grid.cols) != p.dim() {
        return Err(ProcessError::invalid(
            "dwell map, grid and problem differ in shape",
        ));
    }
    if dwell_s.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(ProcessError::invalid(
            "dwell map must be finite and non-negative",
        ));
    }
    let (dx, dy) = (grid.dx_mm, grid.dy_mm);
    let density = dwell_s.mapv(|t| t / (dx * dy));
    let mut spec = RasterSpec::over_rect(
        (grid.x0_mm, grid.x_mm(grid.cols - 1)),
        (grid.y0_mm, grid.y_mm(grid.rows - 1)),
        dy,
        limits.v_max_mm_per_s,
    );
    spec.rapid_mm_per_s = limits.v_max_mm_per_s;
    let ds = 0.5 * dx.min(dy);
    let (commanded, realised) = dwell_raster(&spec, &density, grid, limits, ds)?;
    let mut fast = FastRemoval::from_field(field, grid)?;
    let removal_cmd = fast.removal(&commanded, None)?;
    let removal = fast.removal(&realised, None)?;
    let res_cmd = p.residual_of_removal(&removal_cmd)?;
    let res = p.residual_of_removal(&removal)?;
    // Where the limits bind.
    let d_cmd = dwell_map(&commanded, None, grid);
    let d_real = dwell_map(&realised, None, grid);
    let mean = dwell_s.mean().unwrap_or(0.0);
    let (t_min, t_max) = (dx / limits.v_max_mm_per_s, dx / limits.v_min_mm_per_s);
    let mut binding = Array2::from_elem(p.dim(), FREE);
    let (mut nv, mut na) = (0, 0);
    for ((ij, b), &t) in binding.indexed_iter_mut().zip(dwell_s.iter()) {
        if t < t_min || t > t_max {
            *b = VELOCITY_BOUND;
            nv += 1;
        } else if (d_real[ij] - d_cmd[ij]).abs() > 0.01 * d_cmd[ij].max(mean) {
            *b = ACCELERATION_BOUND;
            na += 1;
        }
    }
    let summary = FeedSummary {
        limits: *limits,
        pitch_mm: dy,
        planned_total_dwell_s: dwell_s.sum(),
        commanded_duration_s: commanded.duration_s(),
        realised_duration_s: realised.duration_s(),
        commanded_residual_rms_nm: res_cmd.rms_nm,
        realised_residual_rms_nm: res.rms_nm,
        realised_residual_pv_nm: res.pv_nm,
        velocity_bound_pixels: nv,
        acceleration_bound_pixels: na,
        bound_fraction: (nv + na) as f64 / binding.len().max(1) as f64,
        path_samples: realised.len(),
    };
    Ok(FeedRealisation {
        summary,
        path: realised,
        removal_nm: removal,
        residual_nm: res.residual_nm,
        binding,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::{GaussianTif, Tif};

    /// A uniform dwell (every CA pixel sees the same removal) realised slowly enough that no
    /// limit binds: the executed path lasts the planned dwell plus the step-overs, and the
    /// residual is small against the removal. With a low acceleration limit the feed changes
    /// at the line ends bind and the residual grows.
    #[test]
    fn uniform_dwell_is_realised_and_limits_bind_when_tight() {
        let g = GaussianTif::new(1.0, 6.0, 2.0).unwrap();
        let px = 0.5;
        let tif = Tif::sample(&g, px, px).unwrap();
        let (h, _) = tif.half_widths();
        let (r, c) = (12 + 2 * h, 30 + 2 * h);
        let z = Array2::from_elem((r, c), 10.0);
        let a = Array2::from_shape_fn((r, c), |(i, j)| {
            (h..r - h).contains(&i) && (h..c - h).contains(&j)
        });
        let p = DwellProblem::new(z, a, tif).unwrap();
        let grid = Grid::new(r, c, px, px, 0.0, 0.0).unwrap();
        // A hump so the feed varies along the lines.
        let t = Array2::from_shape_fn((r, c), |(i, j)| {
            0.5 + 0.3 * ((i as f64) / 4.0).sin() * ((j as f64) / 5.0).cos()
        });
        let free = Limits {
            a_max_mm_per_s2: 1e6,
            ..Limits::default()
        };
        let f = realise(&p, &t, &g, &grid, &free).unwrap();
        assert_eq!(f.summary.velocity_bound_pixels, 0);
        // The scan lines span the grid's outer pixel centres, so the edge columns get half
        // their dwell: the duration is the planned total less half the two edge columns, plus
        // the step-overs at v_max.
        let edge: f64 = t.column(0).sum() + t.column(c - 1).sum();
        let expect = t.sum() - 0.5 * edge + (r - 1) as f64 * px / free.v_max_mm_per_s;
        assert!(
            (f.summary.commanded_duration_s - expect).abs() < 0.02 * expect,
            "{} vs {expect}",
            f.summary.commanded_duration_s
        );
        let tight = Limits {
            a_max_mm_per_s2: 2.0,
            ..Limits::default()
        };
        let g2 = realise(&p, &t, &g, &grid, &tight).unwrap();
        assert!(g2.summary.acceleration_bound_pixels > 0);
        assert!(g2.summary.realised_duration_s > f.summary.realised_duration_s);
        // Free limits: executed = commanded; tight: the executed removal departs from it.
        let (fs, gs) = (&f.summary, &g2.summary);
        assert!((fs.realised_residual_rms_nm - fs.commanded_residual_rms_nm).abs() < 1e-6);
        let dmax = (&g2.removal_nm - &f.removal_nm)
            .iter()
            .zip(p.aperture.iter())
            .filter(|(_, &m)| m)
            .fold(0.0f64, |m, (v, _)| m.max(v.abs()));
        let peak = f.removal_nm.iter().fold(0.0f64, |m, &v| m.max(v));
        assert!(dmax > 0.002 * peak, "{dmax} vs {peak}");
        assert!((gs.commanded_residual_rms_nm - fs.commanded_residual_rms_nm).abs() < 1e-9);
    }
}
