//! The physical model of a run and its evaluation.
//!
//! Measured removal `M = before - after(T_reg(x))` on the analysis pixels (the after map resampled
//! through the registration transform, see `registration`). Predicted removal:
//!
//! `P(x) = sum_j c_j * R_s(path_exec, g_j)(x) + piston + tilt_x x + tilt_y y`
//!
//! where `R_s(path, g)` is the process crate's fast removal (the one forward model `simulate`
//! uses: motion kernels, raster line phases) of the *executed* path (the densified commanded
//! path perturbed by the accepted path effects: lag, offset, periodic errors) with per-sample
//! rate weights `g`, through the run's TIF widened by the accepted `tif_scale` (see
//! [`bonnetlab_process::channels`]); `g_0 = 1` (baseline) while the other `g_j` are the accepted
//! rate effects' weights (time, covariates, ...), centred by their dwell mean for conditioning. The linear coefficients are fitted jointly by least squares; the
//! non-linear parameters (registration, scale, lag, periods, ...) are refined by variable
//! projection (`refine`). Piston and tilt are the measurement's set-up terms: always fitted,
//! never reported as an effect.

use std::sync::{Arc, Mutex};

use bonnetlab_surface::Surface;
use ndarray::Array2;
use rayon::prelude::*;

use bonnetlab_process::channels::{Channels, ScaleScan};
use bonnetlab_process::pixel::PixelResponse;
use bonnetlab_process::removal::Fidelity;
pub use bonnetlab_process::tif::derived::Channel;

use crate::error::CalibrateError;
use crate::grid::{sample, signed_edge_distance, MapGrid};
use crate::lsq;
use crate::path::{PathLog, Samples};
use crate::resample::Resampler;
use crate::tif::TifMap;

/// Largest TIF widening the kernel frame leaves room for.
pub const MAX_SCALE: f64 = 1.5;

/// A physical effect of the library, in the state it has been fitted to.
pub trait Effect: Send + Sync {
    /// Kind as reported (`registration`, `rate_drift`, ...).
    fn kind(&self) -> &'static str;
    /// Uniqueness key (kind plus covariate / axis): a key is accepted at most once.
    fn key(&self) -> String;
    fn boxed_clone(&self) -> Box<dyn Effect>;
    /// Non-linear parameters (refined by variable projection) and their finite-difference steps.
    fn nl(&self) -> Vec<f64> {
        Vec::new()
    }
    fn set_nl(&mut self, _v: &[f64]) {}
    fn nl_steps(&self) -> Vec<f64> {
        Vec::new()
    }
    /// The finite-difference steps of the uncertainties' Jacobian (`uncertainty`): the local
    /// derivative at the fitted state, where [`Self::nl_steps`] may be wider for the
    /// refinement's sake (a secant that smooths the residual's small-scale roughness on the
    /// way to the minimum). The same by default.
    fn nl_sigma_steps(&self) -> Vec<f64> {
        self.nl_steps()
    }
    /// Per non-linear parameter, the width of the interval around its value that the data
    /// cannot resolve at all (a step time that falls while the tool is off the measured
    /// aperture: the residual is flat across that span). The uncertainty adds `width / sqrt(12)`
    /// (a uniform distribution over it) in quadrature; 0 where the data resolve the parameter.
    fn nl_unresolved(&self, _p: &Problem) -> Vec<f64> {
        vec![0.0; self.nl().len()]
    }
    /// Per non-linear parameter, the step of a bracketing scan of the profiled residual after
    /// the Levenberg-Marquardt steps (0: none; see `refine::scan_profile`). For a parameter whose
    /// residual is not quadratic beyond a short span (a step time: the misassigned stretch of
    /// path adds its removal, so the sum of squares grows like |error| once the stretch is longer
    /// than the spot), where forward-difference Gauss-Newton steps crawl.
    fn nl_scan(&self, _p: &Problem) -> Vec<f64> {
        vec![0.0; self.nl().len()]
    }
    /// Whether the non-linear parameters move the executed path or the kernel (else only the
    /// measured map): decides what must be recomputed.
    fn moves_path(&self) -> bool {
        false
    }
    /// Executed-position perturbation of every sub-step.
    fn perturb(&self, _p: &Problem, _xs: &mut [f64], _ys: &mut [f64]) {}
    /// TIF width factor.
    fn scale(&self) -> f64 {
        1.0
    }
    /// (dx_mm, dy_mm, rotation_rad) of the after map against the before map.
    fn registration(&self) -> Option<[f64; 3]> {
        None
    }
    /// Rate weight columns this effect adds: (name, g per sub-step).
    fn rate_terms(&self, _p: &Problem) -> Vec<(String, Vec<f64>)> {
        Vec::new()
    }
    /// Where a rate term rests on values the maps do not measure (a height under the tool
    /// where the before map has no data): `draws` plausible errors of the term per sub-step,
    /// by rate-term name (see [`crate::fill_error`]). The uncertainties add the spread they
    /// cause. None by default.
    fn term_errors(&self, _p: &Problem, _draws: usize) -> Vec<(String, Vec<Vec<f64>>)> {
        Vec::new()
    }
    /// Reported parameters, from the fitted linear coefficients.
    fn params(&self, lin: &Linear) -> Vec<(String, Param)>;
    /// Why this fitted state cannot be physical (a wiggle larger than the spot, a period the
    /// path cannot sample, a scale at the kernel's bound), or `None`. Checked on every refined
    /// contender; an implausible one is rejected with this reason (`run`).
    fn implausible(&self, _p: &Problem, _lin: &Linear) -> Option<String> {
        None
    }
}

impl Clone for Box<dyn Effect> {
    fn clone(&self) -> Self {
        self.boxed_clone()
    }
}

/// A reported parameter value.
#[derive(Debug, Clone, PartialEq)]
pub enum Param {
    Num(f64),
    Text(String),
    List(Vec<f64>),
}

/// The fitted linear coefficients, by column name, with the uncentred baseline rate.
#[derive(Debug, Clone, Default)]
pub struct Linear {
    pub names: Vec<String>,
    pub coef: Vec<f64>,
    pub means: Vec<f64>,
}

impl Linear {
    pub fn get(&self, name: &str) -> f64 {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| self.coef[i])
            .unwrap_or(0.0)
    }

    /// Baseline coefficient with the rate columns un-centred: the rate scale at g = 0.
    pub fn s0(&self) -> f64 {
        let mut s = self.get("baseline");
        for (i, n) in self.names.iter().enumerate() {
            if n != "baseline" && !n.starts_with("nuisance") && !n.starts_with("lin:") {
                s -= self.coef[i] * self.means[i];
            }
        }
        s
    }
}

/// Least-squares plane of `heights` over the valid pixels: piston and the x and y slopes
/// (nm, nm/mm) about the map centre, `z = p0 + p1 (x - cx) + p2 (y - cy)`.
pub fn plane_fit(g: &MapGrid, heights: &Array2<f64>, valid: &Array2<bool>) -> [f64; 3] {
    let (cx, cy) = g.centre_mm();
    let mut acc = [0.0f64; 6];
    for ((i, j), &v) in valid.indexed_iter() {
        if v {
            let (x, y, z) = (g.x_mm(j) - cx, g.y_mm(i) - cy, heights[(i, j)]);
            acc[0] += z;
            acc[1] += x * z;
            acc[2] += y * z;
            acc[3] += x * x;
            acc[4] += y * y;
            acc[5] += 1.0;
        }
    }
    [
        acc[0] / acc[5].max(1.0),
        acc[1] / acc[3].max(1e-12),
        acc[2] / acc[4].max(1e-12),
    ]
}

/// The before map's heights (nm) with piston and tilt removed (least squares over the valid
/// pixels, [`plane_fit`]): what the height covariates are taken from.
pub fn plane_removed(g: &MapGrid, heights: &Array2<f64>, valid: &Array2<bool>) -> Array2<f64> {
    let (cx, cy) = g.centre_mm();
    let [pz, px, py] = plane_fit(g, heights, valid);
    Array2::from_shape_fn((g.rows, g.cols), |(i, j)| {
        heights[(i, j)] - pz - px * (g.x_mm(j) - cx) - py * (g.y_mm(i) - cy)
    })
}

/// How far the local height's fill reaches beyond the data: an unmeasured pixel `d` pixels
/// from the nearest measured one takes the measured heights' smoothing over `d / 2` pixels
/// where that is longer than the covariate's own length
/// ([`crate::grid::smooth_masked_reaching`]). Against the true corners of six round-aperture
/// runs (power-law surfaces, exponents 1.8-2.6, 0.25 mm pixels, 2 px smoothing), the fill's
/// error 1-3, 3-6 and 6-10 mm past the rim, where the tool's footprint carries it into the
/// measured removal, is 64, 95 and 123 nm RMS, against 82, 145 and 146 nm for a fill that
/// stops at the smoothing's reach; lengths of `d` (68, 99, 126 nm) and `2 d` (79, 109, 131 nm)
/// fill worse. tests/height_fill.rs checks it at 0.5 mm pixels.
pub const FILL_LENGTH_PER_PX: f64 = 0.5;

/// The local height of `heights` as a map: piston and tilt removed over the valid pixels
/// ([`plane_removed`]), Gaussian-smoothed over `sigma_mm` within the valid pixels, invalid
/// ones filled from the valid ones at a length growing with their distance from them
/// ([`crate::grid::smooth_masked_reaching`], [`FILL_LENGTH_PER_PX`]), on the grid it is
/// returned with (`g` itself below 8 px; coarser blocks beyond). `None` when that grid cannot
/// be formed.
pub fn local_height_map(
    g: &MapGrid,
    heights: &Array2<f64>,
    valid: &Array2<bool>,
    sigma_mm: f64,
) -> Option<(MapGrid, Array2<f64>)> {
    let flat = plane_removed(g, heights, valid);
    let px = sigma_mm / (0.5 * (g.dx_mm + g.dy_mm));
    // A length of many pixels is smoothed on d x d block means (at least 4 block pixels
    // per sigma): the smoothed field is then interpolated between block centres to well
    // below its own variation, and an 800^2 map at a 16 mm sigma is not a 1025-tap pass
    // per pixel (2.4 s for the three candidates' lengths, against 0.3 s for all the
    // other covariates).
    let d = ((px / 4.0).floor() as usize).max(1);
    let (rc, cc) = (g.rows.div_ceil(d), g.cols.div_ceil(d));
    let (mean_c, valid_c) = crate::grid::block_means(&flat, valid, d);
    let half = 0.5 * (d as f64 - 1.0);
    let gc = MapGrid::new(
        rc,
        cc,
        g.dx_mm * d as f64,
        g.dy_mm * d as f64,
        g.x0_mm + half * g.dx_mm,
        g.y0_mm + half * g.dy_mm,
    )
    .ok()?;
    Some((
        gc,
        crate::grid::smooth_masked_reaching(
            &mean_c,
            &valid_c,
            (px / d as f64).max(0.5),
            FILL_LENGTH_PER_PX,
        ),
    ))
}

/// [`local_height_map`] sampled at the positions (`xs`, `ys`) mm, bilinearly with positions
/// clamped to the map (off the map, the border's value); 0 where the map cannot be formed.
/// The covariate of [`Problem::local_height`]; at [`HEIGHT_SMOOTH_PX`] the `height`
/// covariate.
pub fn local_height_at(
    g: &MapGrid,
    heights: &Array2<f64>,
    valid: &Array2<bool>,
    xs: &[f64],
    ys: &[f64],
    sigma_mm: f64,
) -> Vec<f64> {
    match local_height_map(g, heights, valid, sigma_mm) {
        Some((gc, sm)) => xs
            .iter()
            .zip(ys)
            .map(|(&x, &y)| sample(&gc, &sm, x, y))
            .collect(),
        None => vec![0.0; xs.len()],
    }
}

/// Per-sub-step covariates of the commanded path.
#[derive(Debug, Clone)]
pub struct Covariates {
    pub names: Vec<&'static str>,
    pub values: Vec<Vec<f64>>,
}

impl Covariates {
    pub fn get(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| *n == name)
            .map(|i| self.values[i].as_slice())
    }
}

/// The forward model's channels at one TIF scale, shared by the threads of a calibration
/// (each channel lends a workspace per caller; see `Channels`).
pub type Kernels = Channels;

/// The data of a run, prepared once.
pub struct Problem {
    pub grid: MapGrid,
    pub before: Array2<f64>,
    pub before_valid: Array2<bool>,
    pub after: Array2<f64>,
    pub after_valid: Array2<bool>,
    pub tif: TifMap,
    pub samples: Samples,
    /// The densified commanded path (the samples' positions).
    pub path: PathLog,
    /// Flat indices (row-major) of the analysis pixels (valid in the before map).
    pub idx: Vec<usize>,
    /// Normalised coordinates of the analysis pixels for the tilt columns.
    pub xn: Vec<f64>,
    pub yn: Vec<f64>,
    pub covariates: Covariates,
    pub tif_radius_mm: f64,
    /// The instrument's declared repeatability (nm RMS of the difference between two
    /// measurements of an unchanged part, piston and tilt removed; a recipe's
    /// `[measurement] repeatability_nm`), when declared. It bounds how large a smooth
    /// difference between the two maps the instrument alone makes (`run`'s smooth check).
    pub repeatability_nm: Option<f64>,
    kernels: Mutex<Vec<Arc<Kernels>>>,
    resampler: Resampler,
    resampled: ResampleCache,
    columns: Mutex<ColumnCache>,
    /// Screening-fidelity columns (the candidates'), kept apart (see [`SCREENING_CACHE_BYTES`]).
    screening: Mutex<ColumnCache>,
    coarse: std::sync::OnceLock<Option<crate::coarse::Coarse>>,
    /// The fallback's bases over the path (they depend on the path, the grid and the aperture
    /// only, so every round asks for the same; built on first use).
    fallback_shapes: std::sync::OnceLock<Vec<Arc<crate::effects::fallback::Shape>>>,
    /// The rate map's refinement (`rate_map_fine`), built only when a round offers it.
    fallback_fine: std::sync::OnceLock<Option<Arc<crate::effects::fallback::Shape>>>,
    /// The local height at the samples by smoothing length (see [`Self::local_height`]).
    local_heights: Mutex<Vec<(u64, Arc<Vec<f64>>)>>,
}

type ResampleCache = Mutex<Vec<([f64; 3], Arc<(Array2<f64>, Array2<bool>)>)>>;

/// Memory the cached channel sets (one per TIF scale) may take, about; at least 5 sets are
/// kept, and at most 24 (enough for the scan of `tif_scale` and the scale the model sits at).
const KERNEL_CACHE_BYTES: usize = 192 << 20;

/// Bytes of full-fidelity columns kept between requests (see [`ColumnCache`]).
const COLUMN_CACHE_BYTES: usize = 128 << 20;

/// Bytes of screening columns kept between requests: the selection's candidate columns, many
/// of which each round asks for again (the same covariate, profile hat or shift on an unchanged
/// path). At 800^2 a column is 5 MB, and the full-fidelity budget above held about 25: a
/// round's 60-90 candidate columns pushed the previous round's out before they were asked for
/// again, so the rate-profile, covariate, lag and offset candidates cost 170-200 ms each round
/// instead of 2-13 ms. Kept apart from the full columns, which the refinements fill with
/// one-off Jacobian columns.
const SCREENING_CACHE_BYTES: usize = 512 << 20;

/// Forward-model columns already computed, by a 128-bit fingerprint of everything they depend
/// on: the executed path (times and positions), the TIF scale and each term's channel and rate
/// weights. Selection rounds, candidates and refinement ask for the same column many times
/// (the same covariate on an unchanged path, the baseline of every trial that moves only the
/// registration); each is computed once. Least recently asked for first out beyond its budget
/// (bytes).
struct ColumnCache {
    /// Column, whether it is the same at either fidelity, and the stamp of its last request.
    map: std::collections::HashMap<u128, (Arc<Vec<f64>>, bool, u64)>,
    /// Requests in order (key, stamp); an entry whose stamp is no longer its key's is stale.
    order: std::collections::VecDeque<(u128, u64)>,
    clock: u64,
    bytes: usize,
    budget: usize,
}

impl ColumnCache {
    fn new(budget: usize) -> ColumnCache {
        ColumnCache {
            map: Default::default(),
            order: Default::default(),
            clock: 0,
            bytes: 0,
            budget,
        }
    }

    /// The column of `key` and whether it is the same at either fidelity, if kept (it becomes
    /// the most recently asked for).
    fn get(&mut self, key: u128) -> Option<(Arc<Vec<f64>>, bool)> {
        self.clock += 1;
        let (col, free, stamp) = self.map.get_mut(&key)?;
        *stamp = self.clock;
        let hit = (col.clone(), *free);
        self.order.push_back((key, self.clock));
        // Stale entries dropped once they outnumber the live ones.
        if self.order.len() > 2 * self.map.len() + 64 {
            let map = &self.map;
            self.order
                .retain(|(k, t)| map.get(k).is_some_and(|e| e.2 == *t));
        }
        Some(hit)
    }

    fn put(&mut self, key: u128, col: Arc<Vec<f64>>, free: bool) {
        let size = 8 * col.len();
        if size > self.budget || self.map.contains_key(&key) {
            return;
        }
        while self.bytes + size > self.budget {
            let Some((old, t)) = self.order.pop_front() else {
                break;
            };
            if self.map.get(&old).is_some_and(|e| e.2 == t) {
                if let Some((c, _, _)) = self.map.remove(&old) {
                    self.bytes -= 8 * c.len();
                }
            }
        }
        self.clock += 1;
        self.bytes += size;
        self.order.push_back((key, self.clock));
        self.map.insert(key, (col, free, self.clock));
    }
}

/// Two 64-bit multiply-xorshift streams over 64-bit words: a 128-bit fingerprint, fast on the
/// hundreds of kilobytes of a path, deterministic, and with no structure the forward model's
/// inputs could align with.
struct Fingerprint([u64; 2]);

impl Fingerprint {
    const MUL: [u64; 2] = [0x9E37_79B9_7F4A_7C15, 0xD6E8_FEB8_6659_FD93];

    fn new() -> Self {
        Fingerprint([0x243F_6A88_85A3_08D3, 0x1319_8A2E_0370_7344])
    }

    fn word(&mut self, w: u64) {
        for (h, m) in self.0.iter_mut().zip(Self::MUL) {
            let x = (*h ^ w).wrapping_mul(m);
            *h = x ^ (x >> 29);
        }
    }

    /// The slice's length, then its words on [`LANES`] independent streams (word k on lane
    /// k mod LANES, each lane seeded by its index), folded in lane order, then the words past
    /// the last whole group: order-sensitive within and across lanes, and the lanes' chains
    /// of multiplies run side by side instead of one after the other.
    fn slice(&mut self, v: &[f64]) {
        const LANES: usize = 4;
        self.word(v.len() as u64);
        let mut lanes: [Fingerprint; LANES] = std::array::from_fn(|k| {
            let mut f = Fingerprint::new();
            f.word(k as u64);
            f
        });
        let groups = v.chunks_exact(LANES);
        let rest = groups.remainder();
        for g in groups {
            for (lane, x) in lanes.iter_mut().zip(g) {
                lane.word(x.to_bits());
            }
        }
        for lane in lanes {
            self.word(lane.0[0]);
            self.word(lane.0[1]);
        }
        for x in rest {
            self.word(x.to_bits());
        }
    }

    fn finish(self) -> u128 {
        ((self.0[0] as u128) << 64) | self.0[1] as u128
    }
}

/// 128-bit fingerprint of a column request.
fn fingerprint(scale: f64, exec: &PathLog, terms: &[(Channel, Option<&[f64]>)]) -> u128 {
    let mut h = Fingerprint::new();
    h.word(scale.to_bits());
    for v in [&exec.t_s, &exec.x_mm, &exec.y_mm] {
        h.slice(v);
    }
    for (ch, g) in terms {
        h.word(1 + *ch as u64);
        match g {
            None => h.word(u64::MAX),
            Some(g) => h.slice(g),
        }
    }
    h.finish()
}

impl Problem {
    pub fn new(
        before: &Surface,
        after: &Surface,
        tif: &TifMap,
        path: &PathLog,
    ) -> Result<Self, CalibrateError> {
        let grid = MapGrid::of(before)?;
        if after.dim() != before.dim() {
            return Err(CalibrateError::InvalidInput(format!(
                "after map is {:?} pixels, before map {:?}: they must share a grid",
                after.dim(),
                before.dim()
            )));
        }
        let (adx, ady) = after.pixel_mm("calibration")?;
        if (adx - grid.dx_mm).abs() > 1e-6 * grid.dx_mm
            || (ady - grid.dy_mm).abs() > 1e-6 * grid.dy_mm
        {
            return Err(CalibrateError::InvalidInput(
                "after and before maps differ in pixel size".into(),
            ));
        }
        let radius = tif
            .support_radius_mm()
            .max(2.0 * grid.dx_mm.max(grid.dy_mm));
        let tif = tif.clone();
        let (samples, path) = Samples::of(path, 0.5 * grid.dx_mm.min(grid.dy_mm));
        if samples.len() < 2 {
            return Err(CalibrateError::InvalidInput(
                "the path log has no motion".into(),
            ));
        }
        let before_valid = before.valid().clone();
        let idx: Vec<usize> = before_valid
            .iter()
            .enumerate()
            .filter_map(|(k, &v)| v.then_some(k))
            .collect();
        if idx.len() < 64 {
            return Err(CalibrateError::Processing(format!(
                "only {} valid pixels in the before map",
                idx.len()
            )));
        }
        let (cx, cy) = grid.centre_mm();
        let half = 0.5 * (grid.cols as f64 * grid.dx_mm).max(grid.rows as f64 * grid.dy_mm);
        let xn = idx
            .iter()
            .map(|&k| (grid.x_mm(k % grid.cols) - cx) / half)
            .collect();
        let yn = idx
            .iter()
            .map(|&k| (grid.y_mm(k / grid.cols) - cy) / half)
            .collect();
        let covariates = covariates(&grid, before, &samples);
        let resampler = Resampler::new(&grid, after.heights_nm(), after.valid());
        Ok(Problem {
            grid,
            before: before.heights_nm().clone(),
            before_valid,
            after: after.heights_nm().clone(),
            after_valid: after.valid().clone(),
            tif,
            samples,
            path,
            idx,
            xn,
            yn,
            covariates,
            tif_radius_mm: radius,
            repeatability_nm: None,
            kernels: Mutex::new(Vec::new()),
            resampler,
            resampled: Mutex::new(Vec::new()),
            columns: Mutex::new(ColumnCache::new(COLUMN_CACHE_BYTES)),
            screening: Mutex::new(ColumnCache::new(SCREENING_CACHE_BYTES)),
            coarse: std::sync::OnceLock::new(),
            fallback_shapes: std::sync::OnceLock::new(),
            fallback_fine: std::sync::OnceLock::new(),
            local_heights: Mutex::new(Vec::new()),
        })
    }

    /// The forward model's channels at a TIF scale, cached.
    pub fn kernels(&self, scale: f64) -> Result<Arc<Kernels>, CalibrateError> {
        let scale = scale.clamp(0.5, MAX_SCALE);
        if let Ok(mut cache) = self.kernels.lock() {
            if let Some(n) = cache.iter().position(|k| k.scale() == scale) {
                // Most recently used last: the scan of `tif_scale` builds a set per scale and
                // must not push out the scale the model sits at.
                let k = cache.remove(n);
                cache.push(k.clone());
                return Ok(k);
            }
        }
        let set = Arc::new(Channels::seen(
            self.tif.field(),
            &self.grid,
            scale,
            self.response(),
        )?);
        if let Ok(mut cache) = self.kernels.lock() {
            if cache.len() >= self.max_kernel_sets() {
                cache.remove(0);
            }
            cache.push(set.clone());
        }
        Ok(set)
    }

    /// The scan of the TIF scale up to `max_scale` over value-channel `terms` (path, rate
    /// weights): see [`bonnetlab_process::channels::ScaleScan`].
    pub fn scale_scan(
        &self,
        max_scale: f64,
        terms: &[(&PathLog, Option<&[f64]>)],
    ) -> Result<ScaleScan, CalibrateError> {
        Ok(ScaleScan::new(
            self.tif.field(),
            &self.grid,
            max_scale.min(MAX_SCALE),
            terms,
            self.response(),
        )?)
    }

    /// How the maps' pixels see the removal (the TIF's pixel sampling at the map pixel).
    pub fn response(&self) -> PixelResponse {
        self.tif.response()
    }

    /// Channel sets kept (see [`KERNEL_CACHE_BYTES`]).
    fn max_kernel_sets(&self) -> usize {
        // A set holds a few tens of grown-grid arrays (spectra of its kernels, dwell maps).
        let per_set = 20 * 8 * (self.grid.rows + 40) * (self.grid.cols + 40);
        (KERNEL_CACHE_BYTES / per_set.max(1)).clamp(5, 24)
    }

    /// Removal through one channel of the executed path `exec` with optional per-sample rate
    /// weights, on the analysis pixels.
    pub fn channel_column(
        &self,
        k: &Kernels,
        ch: Channel,
        exec: &PathLog,
        g: Option<&[f64]>,
    ) -> Result<Vec<f64>, CalibrateError> {
        self.column(k, exec, &[(ch, g)])
    }

    /// `sum_m R_{ch_m}(exec, g_m)` on the analysis pixels: the forward model through channel
    /// `ch_m` of the executed path with rate weights `g_m` (computed once per distinct request,
    /// see [`ColumnCache`]).
    pub fn column(
        &self,
        k: &Kernels,
        exec: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Vec<f64>, CalibrateError> {
        self.column_at(Fidelity::Full, k, exec, terms)
    }

    /// [`Self::column`] at a given [`Fidelity`]: `Screening` for the candidate columns of the
    /// selection (a path whose lines spread takes its motion's centred kernel; the fits and
    /// everything reported use `Full`). Cached apart from the full columns.
    pub fn column_at(
        &self,
        fidelity: Fidelity,
        k: &Kernels,
        exec: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Vec<f64>, CalibrateError> {
        self.column_shared(fidelity, k, exec, terms)
            .map(|c| c.as_ref().clone())
    }

    /// [`Self::column_at`] as the cache holds it (no copy).
    fn column_shared(
        &self,
        fidelity: Fidelity,
        k: &Kernels,
        exec: &PathLog,
        terms: &[(Channel, Option<&[f64]>)],
    ) -> Result<Arc<Vec<f64>>, CalibrateError> {
        const SCREENING_SALT: u128 = 0x5c3e_e2a1_97d4_0b6f_81f2_4c7a_d935_e068;
        let base = fingerprint(k.scale(), exec, terms);
        let (full_key, screening_key) = (base, base ^ SCREENING_SALT);
        let (key, cache, other_key, other) = match fidelity {
            Fidelity::Full => (full_key, &self.columns, screening_key, &self.screening),
            Fidelity::Screening => (screening_key, &self.screening, full_key, &self.columns),
        };
        if let Some((hit, _)) = cache.lock().ok().and_then(|mut m| m.get(key)) {
            return Ok(hit);
        }
        // A path without spread lines gives the same bits at either fidelity, so the other
        // fidelity's column answers (a candidate's screening columns are the ones its
        // refinement asks for at full fidelity).
        if let Some((hit, true)) = other.lock().ok().and_then(|mut m| m.get(other_key)) {
            return Ok(hit);
        }
        let (map, free) = match terms {
            [(ch, g)] => k.removal_checked(fidelity, *ch, exec, *g)?,
            _ => k.removal_sum_checked(fidelity, exec, terms)?,
        };
        let col = Arc::new(self.compress(&map));
        if let Ok(mut m) = cache.lock() {
            m.put(key, col.clone(), free);
        }
        Ok(col)
    }

    /// The fallback's bases of this problem (see [`crate::effects::fallback::Shape::all_of`]),
    /// built once.
    pub fn fallback_shapes(&self) -> &[Arc<crate::effects::fallback::Shape>] {
        self.fallback_shapes
            .get_or_init(|| crate::effects::fallback::Shape::all_of(self))
    }

    /// The rate map's refinement of this problem (see
    /// [`crate::effects::fallback::Basis::MapFine`]), built on first use: it is offered only
    /// over an accepted rate map, and its many bases over every sample are not built before.
    pub fn fallback_fine(&self) -> Option<&Arc<crate::effects::fallback::Shape>> {
        self.fallback_fine
            .get_or_init(|| {
                use crate::effects::fallback::{Basis, Shape};
                Shape::of(Basis::MapFine, self, None).map(Arc::new)
            })
            .as_ref()
    }

    /// The local height at every sample (nm): the before map with piston and tilt removed,
    /// Gaussian-smoothed over `sigma_mm` within the valid pixels, at the sample's position
    /// (the covariate of [`crate::effects::rate_covariate::LocalHeight`]). The last few
    /// lengths asked for are kept.
    pub fn local_height(&self, sigma_mm: f64) -> Arc<Vec<f64>> {
        let key = sigma_mm.to_bits();
        if let Ok(c) = self.local_heights.lock() {
            if let Some((_, v)) = c.iter().find(|(k, _)| *k == key) {
                return v.clone();
            }
        }
        let s = &self.samples;
        let v = Arc::new(local_height_at(
            &self.grid,
            &self.before,
            &self.before_valid,
            &s.x_mm,
            &s.y_mm,
            sigma_mm,
        ));
        if let Ok(mut c) = self.local_heights.lock() {
            if c.len() >= 8 {
                c.remove(0);
            }
            c.push((key, v.clone()));
        }
        v
    }

    /// Column of the rate term `g` (per sample) centred on its dwell mean, `R(exec, g - mean)`
    /// on the analysis pixels at `fidelity`, and the mean. A term that is zero on most samples
    /// (a raster line, a time window, a knot of a rate map) is formed as `R(g) - mean R(1)`,
    /// the same by linearity: `R(g)` then splats and transforms only the term's own dwell, and
    /// `R(1)` is the plain path's column, shared by every term.
    pub fn rate_term_column(
        &self,
        fidelity: Fidelity,
        k: &Kernels,
        exec: &PathLog,
        g: &[f64],
    ) -> Result<(Vec<f64>, f64), CalibrateError> {
        let mean = self.samples.dwell_mean(g);
        let zeros = g.iter().filter(|v| **v == 0.0).count();
        if 2 * zeros >= g.len() && mean != 0.0 {
            let cg = self.column_shared(fidelity, k, exec, &[(Channel::Value, Some(g))])?;
            let one = self.column_shared(fidelity, k, exec, &[(Channel::Value, None)])?;
            let c = cg
                .iter()
                .zip(one.iter())
                .map(|(a, b)| a - mean * b)
                .collect();
            return Ok((c, mean));
        }
        let gc: Vec<f64> = g.iter().map(|v| v - mean).collect();
        let c = self.column_at(fidelity, k, exec, &[(Channel::Value, Some(&gc))])?;
        Ok((c, mean))
    }

    /// The coarse registration of the after map onto the before map (computed once).
    pub fn coarse(&self) -> Option<crate::coarse::Coarse> {
        *self.coarse.get_or_init(|| {
            crate::coarse::coarse_registration(
                &self.grid,
                &self.before,
                &self.before_valid,
                &self.after,
                &self.after_valid,
            )
        })
    }

    /// Compresses a full map to the analysis pixels.
    pub fn compress(&self, a: &Array2<f64>) -> Vec<f64> {
        let s = a.as_slice();
        match s {
            Some(s) => self.idx.iter().map(|&k| s[k]).collect(),
            None => self
                .idx
                .iter()
                .map(|&k| a[(k / self.grid.cols, k % self.grid.cols)])
                .collect(),
        }
    }

    /// Expands analysis-pixel values to a full map (0 elsewhere) with its mask.
    pub fn expand(&self, v: &[f64], w: &[f64]) -> (Array2<f64>, Array2<bool>) {
        let mut a = Array2::<f64>::zeros((self.grid.rows, self.grid.cols));
        let mut m = Array2::from_elem((self.grid.rows, self.grid.cols), false);
        for (n, &k) in self.idx.iter().enumerate() {
            if w[n] > 0.0 {
                let p = (k / self.grid.cols, k % self.grid.cols);
                a[p] = v[n];
                m[p] = true;
            }
        }
        (a, m)
    }

    /// The after map resampled through the registration (dx, dy, theta): value at each pixel
    /// centre x of `after_file(R(theta) (x - c) + c + d)`, band-limited (see `resample`), with
    /// its validity. The last few results are cached: refinement of the other effects asks
    /// for the same registration many times.
    pub fn resample_after(&self, reg: [f64; 3]) -> (Array2<f64>, Array2<bool>) {
        if let Ok(cache) = self.resampled.lock() {
            if let Some((_, hit)) = cache.iter().find(|(r, _)| *r == reg) {
                return (hit.0.clone(), hit.1.clone());
            }
        }
        let res = Arc::new(self.resampler.resample(reg));
        if let Ok(mut cache) = self.resampled.lock() {
            if cache.len() >= 4 {
                cache.remove(0);
            }
            cache.push((reg, res.clone()));
        }
        (res.0.clone(), res.1.clone())
    }
}

/// Smoothing (Gaussian sigma, map pixels) of the `height` and `slope` covariates.
pub const HEIGHT_SMOOTH_PX: f64 = 2.0;

/// [`HEIGHT_SMOOTH_PX`] in mm on grid `g` (the local height's length for the `height`
/// covariate, [`local_height_at`]).
pub fn height_smooth_mm(g: &MapGrid) -> f64 {
    HEIGHT_SMOOTH_PX * 0.5 * (g.dx_mm + g.dy_mm)
}

/// Per-sub-step covariates: time (s from start), x, y (mm), feed (mm/s), height (nm) and slope
/// (nm/mm) of the before map with piston and tilt removed and lightly smoothed (sigma 2 px, so
/// measurement noise does not dominate the slope), signed distance to the part edge (mm).
fn covariates(g: &MapGrid, before: &Surface, s: &Samples) -> Covariates {
    let valid = before.valid();
    // The local height at 2 px: on the map's own grid (no blocks below 8 px, so the map's
    // grid always forms; zero, as `local_height_at` gives, if it did not).
    let sm = local_height_map(g, before.heights_nm(), valid, height_smooth_mm(g))
        .map(|(_, sm)| sm)
        .unwrap_or_else(|| Array2::zeros((g.rows, g.cols)));
    let slope = Array2::from_shape_fn((g.rows, g.cols), |(i, j)| {
        let jp = (j + 1).min(g.cols - 1);
        let jm = j.saturating_sub(1);
        let ip = (i + 1).min(g.rows - 1);
        let im = i.saturating_sub(1);
        let gx = (sm[(i, jp)] - sm[(i, jm)]) / ((jp - jm).max(1) as f64 * g.dx_mm);
        let gy = (sm[(ip, j)] - sm[(im, j)]) / ((ip - im).max(1) as f64 * g.dy_mm);
        gx.hypot(gy)
    });
    let edge = signed_edge_distance(valid, g.dx_mm, g.dy_mm);
    let n = s.len();
    let mut height = Vec::with_capacity(n);
    let mut sl = Vec::with_capacity(n);
    let mut ed = Vec::with_capacity(n);
    let (xmin, xmax) = (g.x0_mm, g.x_mm(g.cols - 1));
    let (ymin, ymax) = (g.y0_mm, g.y_mm(g.rows - 1));
    for k in 0..n {
        let (x, y) = (s.x_mm[k], s.y_mm[k]);
        height.push(sample(g, &sm, x, y));
        sl.push(sample(g, &slope, x, y));
        // Off the map: continue the border value outwards (the part ends at the map edge).
        let beyond = (xmin - x)
            .max(0.0)
            .max(x - xmax)
            .hypot((ymin - y).max(0.0).max(y - ymax));
        ed.push(sample(g, &edge, x, y) - beyond);
    }
    let time: Vec<f64> = s.t_s.iter().map(|t| t - s.t0_s).collect();
    Covariates {
        names: vec!["time", "x", "y", "feed", "height", "slope", "edge_distance"],
        values: vec![
            time,
            s.x_mm.clone(),
            s.y_mm.clone(),
            s.feed_mm_per_s.clone(),
            height,
            sl,
            ed,
        ],
    }
}

/// A model evaluated at one state of the accepted effects.
pub struct Eval {
    pub names: Vec<String>,
    /// Columns on the analysis pixels.
    pub cols: Vec<Vec<f64>>,
    /// Dwell means used to centre rate columns (0 for baseline and nuisance).
    pub means: Vec<f64>,
    /// Measured removal on the analysis pixels and the 0/1 weights (common valid aperture).
    pub m: Vec<f64>,
    pub w: Vec<f64>,
    /// Executed positions and the TIF scale of this state.
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    pub scale: f64,
    pub reg: [f64; 3],
    /// Resampled after map (full grid) and its mask.
    pub after_res: Array2<f64>,
    pub after_res_valid: Array2<bool>,
    /// The executed path (samples at `xs`, `ys`) and the forward model's channels at `scale`.
    pub exec: PathLog,
    pub kernels: Arc<Kernels>,
    /// Key of the path/kernel state (to reuse columns when only the registration moves).
    pub path_key: Vec<f64>,
}

fn path_key(effects: &[Box<dyn Effect>]) -> Vec<f64> {
    let mut k = Vec::new();
    for e in effects {
        if e.registration().is_none() {
            k.extend(e.nl());
            k.push(f64::from_bits(e.key().len() as u64));
        }
    }
    k
}

/// Evaluates the model state; `reuse` lends the columns of a previous evaluation whose path
/// state is the same.
pub fn evaluate(
    p: &Problem,
    effects: &[Box<dyn Effect>],
    reuse: Option<&Eval>,
) -> Result<Eval, CalibrateError> {
    let key = path_key(effects);
    let mut reg = [0.0; 3];
    for e in effects {
        if let Some(r) = e.registration() {
            for (a, b) in reg.iter_mut().zip(r) {
                *a += b;
            }
        }
    }
    let (after_res, after_res_valid) = p.resample_after(reg);
    // Row-major views of the maps (copied only if a map is not contiguous).
    fn flat<T: Clone>(a: &Array2<T>) -> std::borrow::Cow<'_, [T]> {
        match a.as_slice() {
            Some(s) => std::borrow::Cow::Borrowed(s),
            None => std::borrow::Cow::Owned(a.iter().cloned().collect()),
        }
    }
    let (before_s, ar, av) = (flat(&p.before), flat(&after_res), flat(&after_res_valid));
    let m: Vec<f64> = p.idx.iter().map(|&k| before_s[k] - ar[k]).collect();
    let w: Vec<f64> = p
        .idx
        .iter()
        .map(|&k| if av[k] { 1.0 } else { 0.0 })
        .collect();
    drop((before_s, ar, av));

    if let Some(prev) = reuse {
        if prev.path_key == key {
            return Ok(Eval {
                names: prev.names.clone(),
                cols: prev.cols.clone(),
                means: prev.means.clone(),
                m,
                w,
                xs: prev.xs.clone(),
                ys: prev.ys.clone(),
                scale: prev.scale,
                reg,
                after_res,
                after_res_valid,
                exec: prev.exec.clone(),
                kernels: prev.kernels.clone(),
                path_key: key,
            });
        }
    }
    let mut xs = p.samples.x_mm.clone();
    let mut ys = p.samples.y_mm.clone();
    let mut scale = 1.0;
    for e in effects {
        e.perturb(p, &mut xs, &mut ys);
        scale *= e.scale();
    }
    let kernels = p.kernels(scale)?;
    let exec = p.samples.path_through(&xs, &ys);
    let mut names = vec!["baseline".to_string()];
    let terms: Vec<(String, Vec<f64>)> = effects.iter().flat_map(|e| e.rate_terms(p)).collect();
    // The baseline column beside the rate terms' (each takes a workspace of its own).
    let (base, built) = rayon::join(
        || p.channel_column(&kernels, Channel::Value, &exec, None),
        || terms_columns(p, &exec, &kernels, terms),
    );
    let mut cols = vec![base?];
    let mut means = vec![0.0];
    for (n, c, mean) in built? {
        names.push(n);
        cols.push(c);
        means.push(mean);
    }
    for (n, v) in [
        ("nuisance:piston", vec![1.0; p.idx.len()]),
        ("nuisance:tilt_x", p.xn.clone()),
        ("nuisance:tilt_y", p.yn.clone()),
    ] {
        names.push(n.into());
        cols.push(v);
        means.push(0.0);
    }
    Ok(Eval {
        names,
        cols,
        means,
        m,
        w,
        xs,
        ys,
        scale,
        reg,
        after_res,
        after_res_valid,
        exec,
        kernels,
        path_key: key,
    })
}

/// Columns `R(exec, g - mean(g))` for rate terms (see [`Problem::rate_term_column`]).
pub fn terms_columns(
    p: &Problem,
    exec: &PathLog,
    kernels: &Kernels,
    terms: Vec<(String, Vec<f64>)>,
) -> Result<Vec<(String, Vec<f64>, f64)>, CalibrateError> {
    // Side by side, collected in order.
    terms
        .into_par_iter()
        .map(|(n, g)| {
            let (c, mean) = p.rate_term_column(Fidelity::Full, kernels, exec, &g)?;
            Ok((n, c, mean))
        })
        .collect()
}

/// Result of a linear fit.
pub struct Fit {
    pub coef: Vec<f64>,
    /// Residual m - prediction on the analysis pixels (0 where w = 0).
    pub resid: Vec<f64>,
    pub rss: f64,
    pub n: f64,
}

impl Fit {
    pub fn rms(&self) -> f64 {
        (self.rss / self.n.max(1.0)).sqrt()
    }
}

/// Joint least-squares fit of all columns (plus `extra`) to m over the weighted pixels.
pub fn fit(ev: &Eval, extra: &[Vec<f64>]) -> Result<Fit, CalibrateError> {
    let cols: Vec<&[f64]> = ev
        .cols
        .iter()
        .chain(extra.iter())
        .map(|c| c.as_slice())
        .collect();
    fit_columns(&cols, &ev.m, &ev.w)
}

/// Joint least-squares fit of `cols` to `m` over the pixels of weight `w` > 0 (see [`fit`]).
pub fn fit_columns(cols: &[&[f64]], m: &[f64], w: &[f64]) -> Result<Fit, CalibrateError> {
    let (g, r) = lsq::gram(cols, m, w, None);
    let coef = lsq::solve(&g, &r)
        .ok_or_else(|| CalibrateError::Processing("singular least-squares fit".into()))?;
    // Per pixel: `pred = sum_a coef_a col_a[i]` (columns in order, from 0.0), `resid = m -
    // pred`, `rss += resid^2` in ascending pixel order; the predictions are formed over blocks
    // of pixels column by column (contiguous reads), each the same sequential sum.
    const BLOCK: usize = 512;
    let mut resid = m.to_vec();
    let mut rss = 0.0;
    let mut n = 0.0;
    let mut pred = [0.0f64; BLOCK];
    let mut lo = 0;
    while lo < resid.len() {
        let hi = (lo + BLOCK).min(resid.len());
        let pred = &mut pred[..hi - lo];
        pred.fill(0.0);
        for (c, col) in coef.iter().zip(cols) {
            for (p, v) in pred.iter_mut().zip(&col[lo..hi]) {
                *p += c * v;
            }
        }
        for ((r, w), p) in resid[lo..hi].iter_mut().zip(&w[lo..hi]).zip(pred.iter()) {
            if *w > 0.0 {
                *r -= p;
                rss += *r * *r;
                n += 1.0;
            } else {
                *r = 0.0;
            }
        }
        lo = hi;
    }
    Ok(Fit {
        coef,
        resid,
        rss,
        n,
    })
}

impl Eval {
    pub fn linear(&self, f: &Fit) -> Linear {
        Linear {
            names: self.names.clone(),
            coef: f.coef[..self.names.len()].to_vec(),
            means: self.means.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_cache_drops_the_least_recently_asked_for_first() {
        // Budget for three columns of 4 values; 1 is asked for again before 4 comes in, so 2
        // (the least recently asked for) goes, then 3 when 5 comes.
        let mut c = ColumnCache::new(3 * 32);
        let col = |v: f64| Arc::new(vec![v; 4]);
        for k in 1..=3u128 {
            c.put(k, col(k as f64), true);
        }
        for _ in 0..200 {
            assert_eq!(c.get(1).unwrap().0[0], 1.0);
        }
        c.put(4, col(4.0), true);
        assert!(c.get(2).is_none());
        assert!(c.get(1).is_some() && c.get(3).is_some() && c.get(4).is_some());
        c.put(5, col(5.0), false);
        assert!(
            c.get(1).is_none(),
            "1 was asked for before 3 and 4 in the last pass"
        );
        assert_eq!(c.get(5).unwrap(), (col(5.0), false));
        assert_eq!(c.bytes, 3 * 32);
        assert!(c.order.len() <= 2 * c.map.len() + 64);
    }

    fn of(v: &[f64]) -> u128 {
        let mut h = Fingerprint::new();
        h.slice(v);
        h.finish()
    }

    #[test]
    fn fingerprints_tell_reordered_and_shifted_slices_apart() {
        let v: Vec<f64> = (0..37).map(|k| (k as f64 * 0.37).sin()).collect();
        assert_eq!(of(&v), of(&v.clone()));
        let mut seen = std::collections::HashSet::new();
        seen.insert(of(&v));
        // Two words swapped within a lane group and across lanes, one word changed, one
        // dropped, one lane's words moved to the next lane, and the slice split in two.
        for (a, b) in [(0, 1), (0, 4), (35, 36)] {
            let mut w = v.clone();
            w.swap(a, b);
            assert!(seen.insert(of(&w)), "swap {a} {b}");
        }
        let mut w = v.clone();
        w[17] = f64::from_bits(w[17].to_bits() ^ 1);
        assert!(seen.insert(of(&w)));
        assert!(seen.insert(of(&v[..36])));
        assert!(seen.insert(of(&v[1..])));
        let mut h = Fingerprint::new();
        h.slice(&v[..20]);
        h.slice(&v[20..]);
        assert!(seen.insert(h.finish()));
        let z = vec![0.0; 8];
        assert_ne!(of(&z), of(&z[..4]));
    }
}
