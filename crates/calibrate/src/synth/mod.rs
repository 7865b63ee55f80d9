//! Generator of synthetic measured runs, independent of the calibration's fast model.
//!
//! A run: a true initial surface on a fine grid ([`field`]: a power-law random field with detail
//! down to the pixel scale, a real measured map resampled, or smooth figure + MSF content), a
//! raster whose feed realises a dwell map derived from that surface ([`path`]), a measured spot
//! (the true TIF dwelled at a point, as a noisy height map), and the after map made by the
//! process crate's exact time-domain deposition
//! ([`bonnetlab_process::modulated::deposit_exact_modulated`], fine sub-steps, never the FFT
//! model) of the true analytic TIF ([`true_tif`]) along the *executed* motion at the *true*
//! instantaneous rate and spot width, then misregistered, tilted, noised and given dropouts.
//! Effects the model is not told about are injected through [`Injected`]; several are outside
//! the calibration library's forms on purpose.
//!
//! Conventions of the injected effects (what the calibration should report):
//! - rate factors multiply: `rate(t) = rate_0 * prod(factors)`; `RateDrift`: `1 + f * tau`
//!   (tau = run-time fraction 0..1); `RateCovariate`: `1 + c * q` with q in natural units (x, y, mm;
//!   feed mm/s; height nm and slope nm/mm of the before surface without piston/tilt; signed
//!   distance to the part edge mm; time s);
//! - executed position = logged - lag * u (u = unit travel direction) + path error;
//! - registration: a feature at true position p appears in the after map at
//!   `R(theta) (p - c) + c + (dx, dy)`, c = map centre.
//!
//! Random draws are seeded and split by purpose (surface, noise, dropouts, spot, per-line
//! rates, rate map), so a run with an effect and its null twin share surface and noise.

pub mod field;
pub mod path;
pub mod true_tif;
pub mod write;

use std::path::PathBuf;

use bonnetlab_process::modulated::{deposit_exact_modulated, Modulation, SubStep};
use bonnetlab_process::removal::ExactOptions;
use bonnetlab_process::{Grid, PathLog};
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use ndarray::Array2;

use crate::error::CalibrateError;
use field::TruthSurface;
use path::RasterPlan;
use true_tif::TrueTif;

/// Shape of a periodic path error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Waveform {
    Sine,
    /// Symmetric triangle wave of the same amplitude and period (outside the library's form).
    Triangle,
}

/// What a periodic path error's phase runs with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WiggleCoord {
    /// Logged x (mm).
    X,
    /// Logged y (mm).
    Y,
    /// Arc length along the motion (mm).
    Arc,
}

/// An effect injected into a run (the calibration is not told).
#[derive(Debug, Clone, PartialEq)]
pub enum Injected {
    Registration {
        dx_mm: f64,
        dy_mm: f64,
        rotation_deg: f64,
    },
    RateDrift {
        fraction_per_run: f64,
    },
    TifScale {
        scale: f64,
    },
    DirectionLag {
        lag_mm: f64,
    },
    PeriodicPathError {
        axis_x: bool,
        amplitude_mm: f64,
        period_mm: f64,
        phase_rad: f64,
        coord: WiggleCoord,
        waveform: Waveform,
    },
    RateCovariate {
        covariate: String,
        coefficient: f64,
    },
    /// Rate oscillating in time: factor 1 + a sin(2 pi t / period_s).
    RateOscillation {
        amplitude_fraction: f64,
        period_s: f64,
    },
    /// Pressure drift step: factor 1 + fraction after run-time fraction `at_tau`.
    RateStep {
        at_tau: f64,
        fraction: f64,
    },
    /// Rate history piecewise linear in run-time fraction between equally spaced knots:
    /// factor `1 + knots[m]` at tau = m / (n - 1) (knots[0] is normally 0).
    RateProfile {
        knots: Vec<f64>,
    },
    /// A local pit in the after surface (not removal by the tool): Gaussian, depth nm.
    LocalDefect {
        x_mm: f64,
        y_mm: f64,
        radius_mm: f64,
        depth_nm: f64,
    },
    /// Constant offset of the executed spot from the logged position.
    PathOffset {
        dx_mm: f64,
        dy_mm: f64,
    },
    // ---- Outside the calibration library (never offered to its selection) ----
    /// Rate `1 + fraction` while travelling in +x, `1 - fraction` in -x (1 otherwise).
    DirectionRate {
        fraction: f64,
    },
    /// Every raster line (by its logged y) has its own rate factor `1 + rms_fraction * N(0, 1)`.
    LineRate {
        rms_fraction: f64,
    },
    /// The working spot is wider than the measured one and grows in time: widening
    /// `start_scale + (end_scale - start_scale) * tau`.
    GrowingSpot {
        start_scale: f64,
        end_scale: f64,
    },
    /// Rate `1 + per_sigma * z`, z the initial height low-passed (Gaussian, `smooth_mm`) and
    /// standardised over the part, at the logged position.
    HeightRate {
        per_sigma: f64,
        smooth_mm: f64,
    },
    /// A smooth random rate map over the part: `1 + amplitude_fraction * m(x, y)`, m of unit RMS
    /// with Gaussian correlation length `correlation_mm`.
    RateMap {
        amplitude_fraction: f64,
        correlation_mm: f64,
    },
}

impl Injected {
    /// The wiggle of the project's synthetic suite and tests: the path displaced along y by
    /// 0.3 mm, a sine of 12 mm period in x at phase 0.5 rad.
    pub fn reference_wiggle() -> Injected {
        Injected::PeriodicPathError {
            axis_x: false,
            amplitude_mm: 0.3,
            period_mm: 12.0,
            phase_rad: 0.5,
            coord: WiggleCoord::X,
            waveform: Waveform::Sine,
        }
    }
}

/// The true initial surface.
#[derive(Debug, Clone, PartialEq)]
pub enum InitialSurface {
    /// Smooth: figure (0.5 to 3 cycles over the part) and MSF (0.04 to 0.2 cycles/mm) bands.
    Smooth { figure_rms_nm: f64, msf_rms_nm: f64 },
    /// Power-law random field, ONE-SIDED 1-D PSD ~ f^-exponent, detail to the truth pixel.
    PowerLaw { exponent: f64, rms_nm: f64 },
    /// A real map resampled over the part, scaled to `rms_nm`, plus a power-law texture.
    Real {
        path: PathBuf,
        rms_nm: f64,
        texture_exponent: f64,
        texture_rms_nm: f64,
    },
}

impl InitialSurface {
    /// The realistic texture of the calibration's realistic runs: a power-law random field of
    /// 140 nm RMS, ONE-SIDED 1-D PSD ~ f^-`exponent` (1.8 to 2.6 in the tests), detail down to the
    /// truth pixel.
    pub fn realistic_texture(exponent: f64) -> InitialSurface {
        InitialSurface::PowerLaw {
            exponent,
            rms_nm: 140.0,
        }
    }

    fn scale_nm(&self) -> f64 {
        match self {
            InitialSurface::Smooth { figure_rms_nm, .. } => *figure_rms_nm,
            InitialSurface::PowerLaw { rms_nm, .. } | InitialSurface::Real { rms_nm, .. } => {
                *rms_nm
            }
        }
    }
}

#[derive(Debug, Clone)]
pub struct SynthConfig {
    pub seed: u64,
    pub rows: usize,
    pub cols: usize,
    pub pixel_mm: f64,
    pub surface: InitialSurface,
    /// Truth grid pixel = map pixel / this (the initial surface has detail down to it).
    pub truth_oversample: usize,
    /// How a map pixel sees the surface: 1 (or 0) a point sample at its centre; n, the mean
    /// of n x n point samples spread evenly over the pixel's square (a camera pixel integrates
    /// the fringe over its area: content above the map's Nyquist is attenuated by the pixel's
    /// sinc instead of folding back in full). The removal is then deposited exactly at the
    /// sub-samples themselves (a grid n times finer: n^2 the deposition's cost), not
    /// interpolated between pixel centres. The measured spot's pixels too, over their own
    /// pixel (`spot_pixel_mm`).
    pub pixel_average: usize,
    pub tif: TrueTif,
    pub pitch_mm: f64,
    pub feed_min_mm_per_s: f64,
    pub feed_max_mm_per_s: f64,
    /// Path log sample rate (Hz).
    pub sample_hz: f64,
    /// Exact deposition sub-step along the motion (mm).
    pub deposit_step_mm: f64,
    pub spot_dwell_s: f64,
    pub spot_noise_nm: f64,
    /// Pixel of the measured spot map (mm); `None`: the map pixel.
    pub spot_pixel_mm: Option<f64>,
    /// Where the spot's dip sits in its map, (x, y) mm from the map's centre pixel (a real
    /// spot is never exactly centred).
    pub spot_offset_mm: (f64, f64),
    /// White measurement noise RMS of the before map (nm).
    pub noise_nm: f64,
    /// White noise of the after map (nm); `None`: `noise_nm`.
    pub noise_after_nm: Option<f64>,
    pub dropout_fraction: f64,
    /// Circular dropouts in the after map: count and radius range (mm).
    pub dropout_discs: usize,
    pub dropout_disc_radius_mm: (f64, f64),
    /// Set-up tilt of the after map (nm across the map) and piston (nm).
    pub setup_tilt_nm: f64,
    pub setup_piston_nm: f64,
    /// The instrument's smooth drift between the two measurements (air, temperature,
    /// alignment): a smooth random field of this RMS (nm over the map, before its plane is
    /// taken out) and Gaussian correlation length `drift_correlation_mm`, added to the after
    /// map only. 0 (the default): a drift-free instrument, and no random draw is made.
    pub drift_nm: f64,
    pub drift_correlation_mm: f64,
    /// Clear aperture: a disc of this diameter (mm) about the map centre; pixels outside it
    /// are invalid in both maps (a round part). `None`: the whole map is the part.
    pub aperture_diameter_mm: Option<f64>,
    pub effects: Vec<Injected>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            seed: 1,
            rows: 160,
            cols: 180,
            pixel_mm: 0.5,
            surface: InitialSurface::Smooth {
                figure_rms_nm: 40.0,
                msf_rms_nm: 4.0,
            },
            truth_oversample: 2,
            pixel_average: 1,
            tif: TrueTif::default(),
            pitch_mm: 3.0,
            feed_min_mm_per_s: 2.0,
            feed_max_mm_per_s: 12.0,
            sample_hz: 10.0,
            deposit_step_mm: 0.1,
            spot_dwell_s: 20.0,
            spot_noise_nm: 0.3,
            spot_pixel_mm: None,
            spot_offset_mm: (0.0, 0.0),
            noise_nm: 0.3,
            noise_after_nm: None,
            dropout_fraction: 0.003,
            dropout_discs: 0,
            dropout_disc_radius_mm: (0.5, 2.0),
            setup_tilt_nm: 15.0,
            setup_piston_nm: 7.0,
            drift_nm: 0.0,
            drift_correlation_mm: 20.0,
            aperture_diameter_mm: None,
            effects: Vec::new(),
        }
    }
}

impl SynthConfig {
    /// The reference large run of the calibration bench and the examples: an n x n map of a
    /// 100 mm part (pixel 100 / n mm, deposition every 0.2 mm), seed 5, with a rate drift of
    /// -20 % and a misregistration of (0.2, -0.15) mm and 0.05 deg.
    pub fn reference_large_run(n: usize) -> SynthConfig {
        SynthConfig {
            rows: n,
            cols: n,
            pixel_mm: 100.0 / n as f64,
            deposit_step_mm: 0.2,
            seed: 5,
            effects: vec![
                Injected::RateDrift {
                    fraction_per_run: -0.2,
                },
                Injected::Registration {
                    dx_mm: 0.2,
                    dy_mm: -0.15,
                    rotation_deg: 0.05,
                },
            ],
            ..SynthConfig::default()
        }
    }

    /// A realistic measured run (what the calibration's realistic tests and the validation
    /// example measure on): an `n` x `n` map of a square part `part_mm` across (pixel
    /// `part_mm / n` mm), the initial `surface` with the truth grid twice as fine as the map, the
    /// paper's bonnet spot ([`TrueTif::bonnet`], 800 nm mm^2/s), a raster at 3 mm pitch with a
    /// 2 to 12 mm/s feed logged at 10 Hz and deposited every 0.06 mm, a measured spot dwelled
    /// 20 s with 0.5 nm noise and its dip 0.15 mm, -0.2 mm off its map's centre, white noise
    /// 1.0 nm in the before map and 1.4 nm in the after map, 0.1 % dropout pixels and 3 circular
    /// dropouts of 0.5 to 2 mm radius, a 15 nm set-up tilt and 7 nm piston, the whole map as the
    /// part (no aperture) and nothing injected. Tests change what they vary with struct update
    /// syntax or [`SynthConfig::with_noise_nm`] / [`SynthConfig::with_round_aperture`].
    pub fn realistic(seed: u64, n: usize, part_mm: f64, surface: InitialSurface) -> SynthConfig {
        SynthConfig {
            seed,
            rows: n,
            cols: n,
            pixel_mm: part_mm / n as f64,
            surface,
            truth_oversample: 2,
            pixel_average: 1,
            tif: TrueTif::bonnet(800.0),
            pitch_mm: 3.0,
            feed_min_mm_per_s: 2.0,
            feed_max_mm_per_s: 12.0,
            sample_hz: 10.0,
            deposit_step_mm: 0.06,
            spot_dwell_s: 20.0,
            spot_noise_nm: 0.5,
            spot_pixel_mm: None,
            spot_offset_mm: (0.15, -0.2),
            noise_nm: 1.0,
            noise_after_nm: Some(1.4),
            dropout_fraction: 0.001,
            dropout_discs: 3,
            dropout_disc_radius_mm: (0.5, 2.0),
            setup_tilt_nm: 15.0,
            setup_piston_nm: 7.0,
            drift_nm: 0.0,
            drift_correlation_mm: 20.0,
            aperture_diameter_mm: None,
            effects: Vec::new(),
        }
    }

    /// This run with white noise `before_nm` in the before map and `after_nm` in the after map
    /// (RMS, nm).
    pub fn with_noise_nm(self, before_nm: f64, after_nm: f64) -> SynthConfig {
        SynthConfig {
            noise_nm: before_nm,
            noise_after_nm: Some(after_nm),
            ..self
        }
    }

    /// This run on a round part when `round`: a clear aperture `diameter_mm` across about the
    /// map centre (pixels outside it invalid in both maps); the whole map otherwise.
    pub fn with_round_aperture(self, round: bool, diameter_mm: f64) -> SynthConfig {
        SynthConfig {
            aperture_diameter_mm: round.then_some(diameter_mm),
            ..self
        }
    }

    /// White-noise floor of the removal (before - after): the two maps' noise in quadrature.
    pub fn true_noise_floor_nm(&self) -> f64 {
        self.noise_nm
            .hypot(self.noise_after_nm.unwrap_or(self.noise_nm))
    }
}

/// A generated run.
#[derive(Debug, Clone)]
pub struct SynthRun {
    pub before: Surface,
    pub after: Surface,
    pub spot: Surface,
    pub spot_dwell_s: f64,
    /// The path log (what the calibration is given).
    pub path: PathLog,
    /// The motion the tool made (before any injected displacement).
    pub motion: PathLog,
    pub pitch_mm: f64,
    /// The removal actually deposited (nm, true frame, map grid, no noise) for checks.
    pub true_removal_nm: Array2<f64>,
    /// White-noise floor of before - after (nm).
    pub true_noise_floor_nm: f64,
    /// The true initial surface's plane over the before map's valid pixels less its plane
    /// over the whole map grid (the one the `height` and `slope` covariates are taken about),
    /// as `(p0, a, b)`: `p0 + a x + b y` nm at (x, y) mm. Zero on a part measured whole. A
    /// rate `1 + c (h - P_grid)` is `(1 + c A) + c (h - P_valid)` with `A` this plane, so a
    /// calibration that takes the height about the measured pixels' plane finds the
    /// coefficient `c / (1 + c A)` with `A` at its reference point.
    pub valid_plane_offset_nm: (f64, f64, f64),
}

impl SynthRun {
    /// The calibration problem of this run, built as the CLI builds it from a run directory
    /// (`pipeline::problem_with_spot`: the measured spot, its dwell and the path log).
    pub fn problem(&self) -> Result<crate::model::Problem, CalibrateError> {
        self.problem_seen(bonnetlab_process::pixel::PixelSampling::Point)
    }

    /// [`Self::problem`] with the maps' and the spot's pixels taken to sample as `pixels`
    /// says (a recipe's `[measurement] pixels`).
    pub fn problem_seen(
        &self,
        pixels: bonnetlab_process::pixel::PixelSampling,
    ) -> Result<crate::model::Problem, CalibrateError> {
        crate::pipeline::problem_from_parts_seen(
            &self.before,
            &self.after,
            &bonnetlab_process::recipe::TifSource::Spot {
                path: std::path::PathBuf::from("spot"),
                dwell_s: self.spot_dwell_s,
            },
            Some(&self.spot),
            &self.path,
            pixels,
        )
    }
}

/// A run on an instrument's own measurements: `cfg`'s path, spot and exactly deposited removal
/// on the grid of `before`, with the before map `before` as read and the after map `after` less
/// the run's true removal (valid where `after` is). The measurement error is then the
/// instrument's (its pixel-scale noise and the smooth drift between two measurements), not a
/// model of it; `cfg`'s own noise, dropouts and set-up terms are not used, and the run's
/// `true_noise_floor_nm` is the white floor of the two measurements' difference. `cfg` must be on
/// `before`'s grid ([`SynthConfig::on_grid_of`]) and must not inject a registration (the maps
/// are not moved), and `after` must share that grid.
pub fn on_measured_maps(
    cfg: &SynthConfig,
    before: &Surface,
    after: &Surface,
) -> Result<SynthRun, CalibrateError> {
    if before.dim() != (cfg.rows, cfg.cols) || after.dim() != before.dim() {
        return Err(CalibrateError::InvalidInput(format!(
            "measured maps {:?} and {:?} against a run of {} x {} pixels: they must share its grid",
            before.dim(),
            after.dim(),
            cfg.rows,
            cfg.cols
        )));
    }
    if cfg
        .effects
        .iter()
        .any(|e| matches!(e, Injected::Registration { .. }))
    {
        return Err(CalibrateError::InvalidInput(
            "a run on measured maps cannot inject a registration (the maps are not moved)".into(),
        ));
    }
    let run = generate(cfg)?;
    let swap = |on: &Surface, h: Array2<f64>, valid: &Array2<bool>| {
        on.with_heights(h)
            .and_then(|s| s.with_valid(valid.clone()))
            .map_err(CalibrateError::from)
    };
    let before_s = swap(&run.before, before.heights_nm().clone(), before.valid())?;
    let after_s = swap(
        &run.after,
        after.heights_nm() - &run.true_removal_nm,
        after.valid(),
    )?;
    // The white floor of the two measurements' own difference (the pixel-scale estimator of
    // `noise`, on maps no model touched); the smooth drift between them is not in it.
    let floor = crate::noise::removal_noise_floor(
        before.heights_nm(),
        before.valid(),
        after.heights_nm(),
        after.valid(),
    )
    .unwrap_or(0.0);
    Ok(SynthRun {
        before: before_s,
        after: after_s,
        true_noise_floor_nm: floor,
        ..run
    })
}

impl SynthConfig {
    /// [`SynthConfig::realistic`] on the grid of a measured map `m` (its rows, columns and
    /// pixel), raster pitch `pitch_mm`, with no noise, dropouts or set-up terms of its own: the
    /// configuration of [`on_measured_maps`]. The initial surface the dwell is designed from is
    /// the realistic texture (exponent 2.2).
    pub fn on_grid_of(
        m: &Surface,
        seed: u64,
        pitch_mm: f64,
    ) -> Result<SynthConfig, CalibrateError> {
        let (rows, cols) = m.dim();
        let (dx, dy) = m.pixel_mm("a run on measured maps")?;
        if (dx - dy).abs() > 1e-9 * dx {
            return Err(CalibrateError::InvalidInput(format!(
                "a run on measured maps needs square pixels, got {dx} x {dy} mm"
            )));
        }
        Ok(SynthConfig {
            rows,
            cols,
            pixel_mm: dx,
            pitch_mm,
            noise_nm: 0.0,
            noise_after_nm: Some(0.0),
            dropout_fraction: 0.0,
            dropout_discs: 0,
            setup_tilt_nm: 0.0,
            setup_piston_nm: 0.0,
            ..SynthConfig::realistic(
                seed,
                rows,
                dx * rows as f64,
                InitialSurface::realistic_texture(2.2),
            )
        })
    }
}

/// Independent random streams of one run.
fn stream(seed: u64, purpose: u64) -> Rng {
    Rng::new(seed ^ purpose.wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

fn wave(w: Waveform, phase: f64) -> f64 {
    match w {
        Waveform::Sine => phase.sin(),
        Waveform::Triangle => {
            let p = (phase / (2.0 * std::f64::consts::PI)).rem_euclid(1.0);
            // triangle with sin's phase: 0 at 0, +1 at 1/4, -1 at 3/4
            if p < 0.25 {
                4.0 * p
            } else if p < 0.75 {
                2.0 - 4.0 * p
            } else {
                4.0 * p - 4.0
            }
        }
    }
}

/// `a` (a field periodic over its grid) on a grid `offset` pixels wider on every side:
/// `rows x cols`, element (i, j) = `a[(i - offset) mod n0, (j - offset) mod n1]`.
fn periodic_extend(a: &Array2<f64>, offset: usize, rows: usize, cols: usize) -> Array2<f64> {
    let (n0, n1) = a.dim();
    if offset == 0 && (rows, cols) == (n0, n1) {
        return a.clone();
    }
    let wrap = |k: usize, n: usize| (k as isize - offset as isize).rem_euclid(n as isize) as usize;
    Array2::from_shape_fn((rows, cols), |(i, j)| a[(wrap(i, n0), wrap(j, n1))])
}

/// Least-squares plane of the truth over the map grid's pixels (all of them, or those `valid`
/// marks), as `z = p0 + a x + b y` (nm, nm/mm; x, y in mm): `(p0, a, b)`. The slopes are the
/// moments about the grid's centre over the pixels taken (the calibration's
/// `model::plane_fit`, exact for a mask symmetric about the centre).
fn plane_fit(f: &TruthSurface, g: &Grid, valid: Option<&Array2<bool>>) -> (f64, f64, f64) {
    let (cx, cy) = (
        0.5 * (g.x_mm(0) + g.x_mm(g.cols - 1)),
        0.5 * (g.y_mm(0) + g.y_mm(g.rows - 1)),
    );
    let (mut sz, mut sxz, mut syz, mut sxx, mut syy, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..g.rows {
        for j in 0..g.cols {
            if valid.is_some_and(|v| !v[(i, j)]) {
                continue;
            }
            let (x, y) = (g.x_mm(j) - cx, g.y_mm(i) - cy);
            let z = f.value(g.x_mm(j), g.y_mm(i));
            sz += z;
            sxz += x * z;
            syz += y * z;
            sxx += x * x;
            syy += y * y;
            n += 1.0;
        }
    }
    let (a, b) = (sxz / sxx, syz / syy);
    (sz / n - a * cx - b * cy, a, b)
}

/// Standardises a field over the map's part (mean 0, RMS 1 over the map grid's extent).
fn standardised(f: TruthSurface, g: &Grid) -> TruthSurface {
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
    for i in 0..g.rows {
        for j in 0..g.cols {
            let v = f.value(g.x_mm(j), g.y_mm(i));
            s += v;
            s2 += v * v;
            n += 1.0;
        }
    }
    let m = s / n;
    let sd = (s2 / n - m * m).max(1e-300).sqrt();
    TruthSurface {
        heights_nm: f.heights_nm.mapv(|v| (v - m) / sd),
        grid: f.grid,
    }
}

/// Everything the per-instant modulation needs besides the effect list.
struct Context<'a> {
    t0: f64,
    t1: f64,
    truth: &'a TruthSurface,
    plane: (f64, f64, f64),
    part: (f64, f64, f64, f64),
    /// Cumulative arc length of the motion at each sample.
    arc: Vec<f64>,
    first_line_mm: f64,
    pitch_mm: f64,
    line_factors: Vec<f64>,
    height_z: Option<TruthSurface>,
    rate_map: Option<TruthSurface>,
}

const COVARIATES: [&str; 7] = ["time", "x", "y", "feed", "height", "slope", "edge_distance"];

impl Context<'_> {
    fn covariate(&self, name: &str, s: &SubStep) -> f64 {
        let (x, y) = (s.x_mm, s.y_mm);
        match name {
            "time" => s.t_s - self.t0,
            "x" => x,
            "y" => y,
            "feed" => s.vx_mm_per_s.hypot(s.vy_mm_per_s),
            "height" => {
                self.truth.value(x, y) - (self.plane.0 + self.plane.1 * x + self.plane.2 * y)
            }
            "slope" => {
                let (gx, gy) = self.truth.gradient(x, y);
                (gx - self.plane.1).hypot(gy - self.plane.2)
            }
            "edge_distance" => {
                let (x0, x1, y0, y1) = self.part;
                if x >= x0 && x <= x1 && y >= y0 && y <= y1 {
                    (x - x0).min(x1 - x).min(y - y0).min(y1 - y)
                } else {
                    let ddx = (x0 - x).max(0.0).max(x - x1);
                    let ddy = (y0 - y).max(0.0).max(y - y1);
                    -ddx.hypot(ddy)
                }
            }
            _ => 0.0,
        }
    }

    fn modulation(&self, effects: &[Injected], s: &SubStep, path: &PathLog) -> Modulation {
        let tau = ((s.t_s - self.t0) / (self.t1 - self.t0)).clamp(0.0, 1.0);
        let speed = s.vx_mm_per_s.hypot(s.vy_mm_per_s);
        let (ux, uy) = if speed > 1e-9 {
            (s.vx_mm_per_s / speed, s.vy_mm_per_s / speed)
        } else {
            (0.0, 0.0)
        };
        let mut m = Modulation::default();
        for e in effects {
            match e {
                Injected::RateDrift { fraction_per_run } => m.rate *= 1.0 + fraction_per_run * tau,
                Injected::TifScale { scale } => m.scale *= scale,
                Injected::DirectionLag { lag_mm } => {
                    m.dx_mm -= lag_mm * ux;
                    m.dy_mm -= lag_mm * uy;
                }
                Injected::PeriodicPathError {
                    axis_x,
                    amplitude_mm,
                    period_mm,
                    phase_rad,
                    coord,
                    waveform,
                } => {
                    let q = match coord {
                        WiggleCoord::X => s.x_mm,
                        WiggleCoord::Y => s.y_mm,
                        WiggleCoord::Arc => {
                            let k = s.segment;
                            let fr = (s.t_s - path.t_s[k]) / (path.t_s[k + 1] - path.t_s[k]);
                            self.arc[k] + fr * (self.arc[k + 1] - self.arc[k])
                        }
                    };
                    let v = amplitude_mm
                        * wave(
                            *waveform,
                            2.0 * std::f64::consts::PI * q / period_mm + phase_rad,
                        );
                    if *axis_x {
                        m.dx_mm += v;
                    } else {
                        m.dy_mm += v;
                    }
                }
                Injected::RateCovariate {
                    covariate,
                    coefficient,
                } => m.rate *= 1.0 + coefficient * self.covariate(covariate, s),
                Injected::RateOscillation {
                    amplitude_fraction,
                    period_s,
                } => {
                    m.rate *= 1.0
                        + amplitude_fraction
                            * (2.0 * std::f64::consts::PI * (s.t_s - self.t0) / period_s).sin()
                }
                Injected::RateStep { at_tau, fraction } if tau >= *at_tau => {
                    m.rate *= 1.0 + fraction
                }
                Injected::RateProfile { knots } if knots.len() >= 2 => {
                    let x = tau * (knots.len() - 1) as f64;
                    let j = (x.floor() as usize).min(knots.len() - 2);
                    let f = x - j as f64;
                    m.rate *= 1.0 + knots[j] + f * (knots[j + 1] - knots[j]);
                }
                Injected::PathOffset { dx_mm, dy_mm } => {
                    m.dx_mm += dx_mm;
                    m.dy_mm += dy_mm;
                }
                Injected::DirectionRate { fraction } if ux.abs() > 0.7 => {
                    m.rate *= 1.0 + fraction * ux.signum();
                }
                Injected::LineRate { .. } => {
                    let l = ((s.y_mm - self.first_line_mm) / self.pitch_mm).round();
                    let l = (l.max(0.0) as usize).min(self.line_factors.len().saturating_sub(1));
                    m.rate *= self.line_factors.get(l).copied().unwrap_or(1.0);
                }
                Injected::GrowingSpot {
                    start_scale,
                    end_scale,
                } => m.scale *= start_scale + (end_scale - start_scale) * tau,
                Injected::HeightRate { per_sigma, .. } => {
                    if let Some(z) = &self.height_z {
                        m.rate *= 1.0 + per_sigma * z.value(s.x_mm, s.y_mm);
                    }
                }
                Injected::RateMap {
                    amplitude_fraction, ..
                } => {
                    if let Some(r) = &self.rate_map {
                        m.rate *= 1.0 + amplitude_fraction * r.value(s.x_mm, s.y_mm);
                    }
                }
                _ => {}
            }
        }
        m
    }
}

fn perr(e: impl std::fmt::Display) -> CalibrateError {
    CalibrateError::InvalidInput(format!("synthetic run: {e}"))
}

/// The true initial surface on the truth grid.
fn initial_surface(
    cfg: &SynthConfig,
    tg: &Grid,
    part_mm: f64,
) -> Result<Array2<f64>, CalibrateError> {
    let mut rng = stream(cfg.seed, 1);
    Ok(match &cfg.surface {
        InitialSurface::Smooth {
            figure_rms_nm,
            msf_rms_nm,
        } => {
            let mut a =
                field::band_field(&mut rng, tg, 0.5 / part_mm, 3.0 / part_mm, *figure_rms_nm);
            if *msf_rms_nm > 0.0 {
                a += &field::band_field(&mut rng, tg, 0.04, 0.2, *msf_rms_nm);
            }
            a
        }
        InitialSurface::PowerLaw { exponent, rms_nm } => {
            field::power_law(&mut rng, tg, *exponent, *rms_nm)
        }
        InitialSurface::Real {
            path,
            rms_nm,
            texture_exponent,
            texture_rms_nm,
        } => {
            let mut a = field::from_real_map(path, tg, *rms_nm)?;
            if *texture_rms_nm > 0.0 {
                a += &field::power_law(&mut rng, tg, *texture_exponent, *texture_rms_nm);
            }
            a
        }
    })
}

/// Offsets (mm) from a pixel's centre of `n x n` points spread evenly over its `dx x dy` square
/// (the centre alone for `n` = 1), row by row.
fn pixel_offsets(n: usize, dx: f64, dy: f64) -> Vec<(f64, f64)> {
    (0..n * n)
        .map(|k| {
            let (a, b) = ((k / n) as f64, (k % n) as f64);
            (
                ((b + 0.5) / n as f64 - 0.5) * dx,
                ((a + 0.5) / n as f64 - 0.5) * dy,
            )
        })
        .collect()
}

/// The deposition step of [`generate_with`]: the removal (nm) on `grid` of the true TIF
/// `field` moved along `motion` (the realised tool motion), with the per-instant `modulation`
/// of the injected effects (executed offset, rate factor, widening) applied.
pub trait Deposition {
    fn deposit(
        &mut self,
        motion: &PathLog,
        field: &dyn bonnetlab_process::tif::RateField,
        grid: &Grid,
        modulation: &dyn Fn(&SubStep) -> Modulation,
    ) -> Result<Array2<f64>, CalibrateError>;
}

/// The generator's own deposition: the process crate's exact time-domain deposition
/// ([`deposit_exact_modulated`]) at sub-steps of at most `max_step_mm`.
pub struct ExactDeposition {
    pub max_step_mm: f64,
}

impl Deposition for ExactDeposition {
    fn deposit(
        &mut self,
        motion: &PathLog,
        field: &dyn bonnetlab_process::tif::RateField,
        grid: &Grid,
        modulation: &dyn Fn(&SubStep) -> Modulation,
    ) -> Result<Array2<f64>, CalibrateError> {
        let opts = ExactOptions {
            max_step_mm: Some(self.max_step_mm),
            ..ExactOptions::default()
        };
        deposit_exact_modulated(motion, field, grid, &opts, modulation).map_err(perr)
    }
}

/// Generates a run.
pub fn generate(cfg: &SynthConfig) -> Result<SynthRun, CalibrateError> {
    generate_with(
        cfg,
        &mut ExactDeposition {
            max_step_mm: cfg.deposit_step_mm,
        },
    )
}

/// [`generate`] with another deposition of the same motion and modulation (for example one
/// that adds a vibration model's instantaneous TIF); everything else (surface, path, effects,
/// registration, noise, dropouts, spot) is the same.
pub fn generate_with(
    cfg: &SynthConfig,
    deposition: &mut dyn Deposition,
) -> Result<SynthRun, CalibrateError> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if cfg.rows < 16 || cfg.cols < 16 || !positive(cfg.pixel_mm) || !positive(cfg.pitch_mm) {
        return Err(CalibrateError::InvalidInput(
            "synthetic run: grid or pitch too small".into(),
        ));
    }
    for e in &cfg.effects {
        if let Injected::RateCovariate { covariate, .. } = e {
            if !COVARIATES.contains(&covariate.as_str()) {
                return Err(CalibrateError::InvalidInput(format!(
                    "unknown covariate '{covariate}'"
                )));
            }
        }
    }
    let d = cfg.pixel_mm;
    let grid = Grid::new(cfg.rows, cfg.cols, d, d, 0.0, 0.0).map_err(perr)?;
    let (wx, wy) = ((cfg.cols - 1) as f64 * d, (cfg.rows - 1) as f64 * d);
    let (cx, cy) = (0.5 * wx, 0.5 * wy);
    let field = cfg.tif.field()?;
    let (ext, _) = field.half_extent_mm();

    // Registration (summed) and how far the after map reaches outside the part.
    let (mut rdx, mut rdy, mut rth) = (0.0, 0.0, 0.0f64);
    for e in &cfg.effects {
        if let Injected::Registration {
            dx_mm,
            dy_mm,
            rotation_deg,
        } = e
        {
            rdx += dx_mm;
            rdy += dy_mm;
            rth += rotation_deg.to_radians();
        }
    }
    let reach = rdx.hypot(rdy) + rth.abs() * cx.hypot(cy) + 2.0 * d;

    // Truth grid: finer than the map, wider than the part. The part is drawn on a canonical
    // grid whose margin does not depend on the injected registration (the margin of a run
    // without one) and extended periodically to the margin the registration needs (the
    // random fields are periodic over their FFT domain), so one seed gives one part whatever
    // the registration. A registration reaching beyond the canonical margin (6 pixels + 2 mm)
    // samples the periodic continuation there.
    let os = cfg.truth_oversample.max(1);
    let td = d / os as f64;
    let truth_grid = |m_px: usize| {
        Grid::new(
            (cfg.rows - 1) * os + 1 + 2 * m_px,
            (cfg.cols - 1) * os + 1 + 2 * m_px,
            td,
            td,
            -(m_px as f64) * td,
            -(m_px as f64) * td,
        )
        .map_err(perr)
    };
    let margin_px = |reach: f64| ((reach + 4.0 * d + 2.0) / td).ceil() as usize;
    // (2 d is the reach without a registration: the same arithmetic as `reach` above.)
    let m0_px = margin_px(2.0 * d);
    let m_px = margin_px(reach).max(m0_px);
    let cg = truth_grid(m0_px)?;
    let tg = truth_grid(m_px)?;
    let extend = |a: &Array2<f64>| periodic_extend(a, m_px - m0_px, tg.rows, tg.cols);
    let canonical = initial_surface(cfg, &cg, wx.max(wy))?;
    let truth = TruthSurface {
        heights_nm: extend(&canonical),
        grid: tg,
    };
    let plane = plane_fit(&truth, &grid, None);

    // Dwell map on a 1 mm grid over the raster: more dwell (slower) where the low-passed
    // surface is high.
    let over = ext * 0.8;
    let fig = extend(&field::smooth(&canonical, &cg, 5.0));
    let fig_t = TruthSurface {
        heights_nm: fig,
        grid: tg,
    };
    let fig_rms = cfg.surface.scale_nm().max(1e-9);
    let (vmin, vmax) = (cfg.feed_min_mm_per_s, cfg.feed_max_mm_per_s);
    let dg_pitch = 1.0;
    let n_dx = ((wx + 2.0 * over + 4.0) / dg_pitch).ceil() as usize + 1;
    let n_dy = ((wy + 2.0 * over + 4.0) / dg_pitch).ceil() as usize + 1;
    let dgrid =
        Grid::new(n_dy, n_dx, dg_pitch, dg_pitch, -over - 2.0, -over - 2.0).map_err(perr)?;
    let dens = Array2::from_shape_fn((n_dy, n_dx), |(i, j)| {
        let (x, y) = (dgrid.x_mm(j).clamp(0.0, wx), dgrid.y_mm(i).clamp(0.0, wy));
        let h = ((fig_t.value(x, y) - (plane.0 + plane.1 * x + plane.2 * y)) / (2.5 * fig_rms))
            .clamp(-1.0, 1.0);
        (1.0 / (vmax * cfg.pitch_mm)) * (1.0 - (h + 1.0) / 2.0)
            + (1.0 / (vmin * cfg.pitch_mm)) * ((h + 1.0) / 2.0)
    });
    let plan = RasterPlan {
        x_range_mm: (-over, wx + over),
        y_range_mm: (-over, wy + over),
        pitch_mm: cfg.pitch_mm,
        feed_min_mm_per_s: vmin,
        feed_max_mm_per_s: vmax,
        sample_hz: cfg.sample_hz,
    };
    let (motion, log) = path::raster_motion(&plan, &dens, &dgrid)?;

    // Per-instant modulation.
    let mut arc = vec![0.0; motion.len()];
    for k in 1..motion.len() {
        arc[k] = arc[k - 1]
            + (motion.x_mm[k] - motion.x_mm[k - 1]).hypot(motion.y_mm[k] - motion.y_mm[k - 1]);
    }
    let n_lines = ((wy + 2.0 * over) / cfg.pitch_mm).floor() as usize + 1;
    let mut line_rng = stream(cfg.seed, 5);
    let line_rms = cfg
        .effects
        .iter()
        .find_map(|e| match e {
            Injected::LineRate { rms_fraction } => Some(*rms_fraction),
            _ => None,
        })
        .unwrap_or(0.0);
    let line_factors = (0..n_lines)
        .map(|_| 1.0 + line_rms * line_rng.normal())
        .collect();
    let height_z = cfg.effects.iter().find_map(|e| match e {
        Injected::HeightRate { smooth_mm, .. } => Some(standardised(
            TruthSurface {
                heights_nm: extend(&field::smooth(&canonical, &cg, *smooth_mm)),
                grid: tg,
            },
            &grid,
        )),
        _ => None,
    });
    let rate_map = cfg.effects.iter().find_map(|e| match e {
        Injected::RateMap { correlation_mm, .. } => Some(standardised(
            TruthSurface {
                heights_nm: extend(&field::smooth_random(
                    &mut stream(cfg.seed, 6),
                    &cg,
                    *correlation_mm,
                )),
                grid: tg,
            },
            &grid,
        )),
        _ => None,
    });
    let ctx = Context {
        t0: motion.t_s[0],
        t1: motion.t_s[motion.len() - 1],
        truth: &truth,
        plane,
        part: (-0.5 * d, wx + 0.5 * d, -0.5 * d, wy + 0.5 * d),
        arc,
        first_line_mm: -over,
        pitch_mm: cfg.pitch_mm,
        line_factors,
        height_z,
        rate_map,
    };

    // Exact deposition on the map grid grown so that misregistered samples stay inside; with
    // `pixel_average` n, on a grid n times finer whose nodes are the pixels' sub-samples, so a
    // pixel's mean is the mean of the exact removal there, not of an interpolant between pixel
    // centres (which misses a square-root rim's detail between them).
    let na = cfg.pixel_average.max(1);
    let grow = (reach / d).ceil() as usize + 3;
    let rgrid = {
        let g = grid.grown(grow, grow);
        let f = na as f64;
        bonnetlab_process::Grid::new(
            g.rows * na,
            g.cols * na,
            g.dx_mm / f,
            g.dy_mm / f,
            g.x0_mm + (0.5 / f - 0.5) * g.dx_mm,
            g.y0_mm + (0.5 / f - 0.5) * g.dy_mm,
        )
        .map_err(|e| CalibrateError::InvalidInput(e.to_string()))?
    };
    let removal = deposition.deposit(&motion, field.as_ref(), &rgrid, &|s| {
        ctx.modulation(&cfg.effects, s, &motion)
    })?;
    let removal_at = |x: f64, y: f64| {
        let (u, v) = rgrid.frac_index(x, y);
        bonnetlab_process::interp::catmull_rom(&removal, u, v)
    };

    // Before map: truth at the map's pixel centres (or averaged over each pixel, see
    // `pixel_average`). After map: truth minus removal at the misregistered positions.
    let offsets = pixel_offsets(na, grid.dx_mm, grid.dy_mm);
    let pixel_mean = |f: &dyn Fn(f64, f64) -> f64, x: f64, y: f64| -> f64 {
        offsets
            .iter()
            .map(|(ox, oy)| f(x + ox, y + oy))
            .sum::<f64>()
            / offsets.len() as f64
    };
    let mut before = Array2::from_shape_fn((cfg.rows, cfg.cols), |(i, j)| {
        pixel_mean(&|x, y| truth.value(x, y), grid.x_mm(j), grid.y_mm(i))
    });
    let mut after = Array2::from_shape_fn((cfg.rows, cfg.cols), |(i, j)| {
        // after-map pixel q shows the true point p = R(-theta) (q - c - d) + c
        let (c, s) = (rth.cos(), rth.sin());
        let seen = |x: f64, y: f64| {
            let (qx, qy) = (x - cx - rdx, y - cy - rdy);
            let (px, py) = (c * qx + s * qy + cx, -s * qx + c * qy + cy);
            truth.value(px, py) - removal_at(px, py)
        };
        let (qx, qy) = (grid.x_mm(j) - cx - rdx, grid.y_mm(i) - cy - rdy);
        let (px, py) = (c * qx + s * qy + cx, -s * qx + c * qy + cy);
        let mut h = if na == 1 {
            truth.value(px, py) - removal_at(px, py)
        } else {
            pixel_mean(&seen, grid.x_mm(j), grid.y_mm(i))
        };
        for e in &cfg.effects {
            if let Injected::LocalDefect {
                x_mm,
                y_mm,
                radius_mm,
                depth_nm,
            } = e
            {
                let r2 = (px - x_mm).powi(2) + (py - y_mm).powi(2);
                h -= depth_nm * (-0.5 * r2 / (radius_mm * radius_mm)).exp();
            }
        }
        h
    });
    if cfg.drift_nm > 0.0 {
        // Its own stream, so a run with drift keeps its drift-free twin's noise and dropouts.
        let mut f = field::smooth_random(&mut stream(cfg.seed, 7), &grid, cfg.drift_correlation_mm);
        field::scale_to(&mut f, cfg.drift_nm);
        after += &f;
    }
    let mut vb = Array2::from_elem((cfg.rows, cfg.cols), true);
    let mut va = Array2::from_elem((cfg.rows, cfg.cols), true);
    let mut noise_rng = stream(cfg.seed, 2);
    let mut drop_rng = stream(cfg.seed, 3);
    let noise_after = cfg.noise_after_nm.unwrap_or(cfg.noise_nm);
    for (map, valid, setup) in [(&mut before, &mut vb, false), (&mut after, &mut va, true)] {
        let (tx, ty) = if setup {
            (
                cfg.setup_tilt_nm * (drop_rng.uniform() - 0.5) * 2.0,
                cfg.setup_tilt_nm * (drop_rng.uniform() - 0.5) * 2.0,
            )
        } else {
            (0.0, 0.0)
        };
        let piston = if setup { cfg.setup_piston_nm } else { 0.0 };
        let sigma = if setup { noise_after } else { cfg.noise_nm };
        for ((i, j), h) in map.indexed_iter_mut() {
            *h += piston
                + tx * (grid.x_mm(j) / wx - 0.5)
                + ty * (grid.y_mm(i) / wy - 0.5)
                + sigma * noise_rng.normal();
        }
        // Dropouts: isolated pixels plus a few small clusters.
        let n_drop = (cfg.dropout_fraction * (cfg.rows * cfg.cols) as f64) as usize;
        for _ in 0..n_drop {
            valid[(drop_rng.below(cfg.rows), drop_rng.below(cfg.cols))] = false;
        }
        for _ in 0..3.min(n_drop) {
            let (ci, cj) = (drop_rng.below(cfg.rows), drop_rng.below(cfg.cols));
            for i in ci.saturating_sub(2)..(ci + 3).min(cfg.rows) {
                for j in cj.saturating_sub(2)..(cj + 3).min(cfg.cols) {
                    valid[(i, j)] = false;
                }
            }
        }
        // Circular dropouts in the after map (dust, a fiducial, a reflection).
        if setup {
            let (r0, r1) = cfg.dropout_disc_radius_mm;
            for _ in 0..cfg.dropout_discs {
                let (x, y) = (drop_rng.uniform() * wx, drop_rng.uniform() * wy);
                let r = r0 + (r1 - r0) * drop_rng.uniform();
                for ((i, j), ok) in valid.indexed_iter_mut() {
                    if (grid.x_mm(j) - x).powi(2) + (grid.y_mm(i) - y).powi(2) <= r * r {
                        *ok = false;
                    }
                }
            }
        }
    }
    if let Some(dia) = cfg.aperture_diameter_mm {
        let r2 = 0.25 * dia * dia;
        for v in [&mut vb, &mut va] {
            for ((i, j), ok) in v.indexed_iter_mut() {
                if (grid.x_mm(j) - cx).powi(2) + (grid.y_mm(i) - cy).powi(2) > r2 {
                    *ok = false;
                }
            }
        }
    }
    let valid_plane = if vb.iter().all(|v| *v) {
        plane
    } else {
        plane_fit(&truth, &grid, Some(&vb))
    };
    let mk = |h: Array2<f64>, v: Array2<bool>, name: &str| -> Result<Surface, CalibrateError> {
        let mut s = Surface::with_mask(h, v, Some(d), Some(d))?;
        s.provenance.format = "synthetic".into();
        s.provenance.comment = Some(name.into());
        Ok(s)
    };

    // Measured spot: odd-sized map of the (unscaled) true TIF dwelled at its centre, point
    // samples (or pixel means, see `pixel_average`) plus white noise.
    let sd = cfg.spot_pixel_mm.unwrap_or(d);
    let off = cfg.spot_offset_mm.0.abs().max(cfg.spot_offset_mm.1.abs());
    let half = ((ext * 1.25 + off) / sd).ceil() as usize;
    let n = 2 * half + 1;
    let mut spot_rng = stream(cfg.seed, 4);
    // With `pixel_average`, each spot pixel is the mean over its own square, as the maps'.
    let spot_offsets = pixel_offsets(na, sd, sd);
    let spot_h = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = ((j as f64 - half as f64) * sd, (i as f64 - half as f64) * sd);
        let (ox, oy) = cfg.spot_offset_mm;
        let rate = if na == 1 {
            field.rate_at_mm(x - ox, y - oy)
        } else {
            spot_offsets
                .iter()
                .map(|(px, py)| field.rate_at_mm(x + px - ox, y + py - oy))
                .sum::<f64>()
                / spot_offsets.len() as f64
        };
        3.0 - cfg.spot_dwell_s * rate + cfg.spot_noise_nm * spot_rng.normal()
    });
    let mut spot = Surface::new(spot_h, Some(sd), Some(sd))?;
    spot.provenance.format = "synthetic".into();
    spot.origin_mm = (-(half as f64) * sd, -(half as f64) * sd);

    // At the map's pixels: each pixel's n x n sub-samples averaged (n = 1: its centre).
    let true_removal_nm = Array2::from_shape_fn((cfg.rows, cfg.cols), |(i, j)| {
        let (i0, j0) = ((grow + i) * na, (grow + j) * na);
        removal
            .slice(ndarray::s![i0..i0 + na, j0..j0 + na])
            .mean()
            .unwrap_or(0.0)
    });
    Ok(SynthRun {
        before: mk(before, vb, "before")?,
        after: mk(after, va, "after")?,
        spot,
        spot_dwell_s: cfg.spot_dwell_s,
        path: log,
        motion,
        pitch_mm: cfg.pitch_mm,
        true_removal_nm,
        true_noise_floor_nm: cfg.true_noise_floor_nm(),
        valid_plane_offset_nm: (
            valid_plane.0 - plane.0,
            valid_plane.1 - plane.1,
            valid_plane.2 - plane.2,
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The part's texture does not depend on the margin an injected registration needs: one
    /// seed, with and without a registration (and with a larger one), gives the same before map
    /// bit for bit (before this, the truth grid's size, and so the power-law realisation,
    /// followed the registration's reach).
    #[test]
    fn same_seed_same_part_whatever_the_registration() {
        let base = SynthConfig {
            rows: 40,
            cols: 48,
            pixel_mm: 0.5,
            surface: InitialSurface::PowerLaw {
                exponent: 2.0,
                rms_nm: 20.0,
            },
            deposit_step_mm: 0.5,
            feed_min_mm_per_s: 10.0,
            feed_max_mm_per_s: 30.0,
            ..SynthConfig::default()
        };
        let registered = |dx: f64, rot: f64| {
            let mut c = base.clone();
            c.effects.push(Injected::Registration {
                dx_mm: dx,
                dy_mm: -0.4 * dx,
                rotation_deg: rot,
            });
            c
        };
        let plain = generate(&base).unwrap();
        for cfg in [registered(0.3, 0.0), registered(2.5, 0.2)] {
            let r = generate(&cfg).unwrap();
            assert!(
                r.before.heights_nm() == plain.before.heights_nm(),
                "before maps differ with {:?}",
                cfg.effects.last()
            );
            assert!(r.after.heights_nm() != plain.after.heights_nm());
            // The same tool motion: the same path log.
            assert!(r.path.x_mm == plain.path.x_mm && r.path.y_mm == plain.path.y_mm);
        }
    }

    /// A run on measured maps keeps both maps' bits (the before map as read, the after map less
    /// exactly the deposited removal), so `before - after - removal` is the two measurements'
    /// own difference to the last bit; its white floor is the two maps' noise in quadrature
    /// (independent 1.0 and 0.7 nm on a shared smooth surface: 1.22 nm, within 10 %). Grids
    /// that differ, an injected registration and oblong pixels are refused with the reason.
    #[test]
    fn measured_maps_carry_the_removal_and_nothing_else() {
        let (r, c, d) = (96, 112, 0.5);
        let mut rng = Rng::new(17);
        let shape = Array2::from_shape_fn((r, c), |(i, j)| {
            30.0 * ((i as f64) / 9.0).sin() + 20.0 * ((j as f64) / 13.0).cos()
        });
        let valid = Array2::from_shape_fn((r, c), |(i, j)| {
            (i as f64 - 47.5).hypot(j as f64 - 55.5) < 45.0
        });
        let mut measured = |sigma: f64| {
            let h = shape.mapv(|v| v + sigma * rng.normal());
            Surface::with_mask(h, valid.clone(), Some(d), Some(d)).unwrap()
        };
        let (m1, m2) = (measured(1.0), measured(0.7));
        let cfg = SynthConfig {
            deposit_step_mm: 0.25,
            ..SynthConfig::on_grid_of(&m1, 3, 3.0).unwrap()
        };
        let run = on_measured_maps(&cfg, &m1, &m2).unwrap();
        assert!(run.before.heights_nm() == m1.heights_nm() && *run.before.valid() == valid);
        assert!(*run.after.valid() == valid);
        let removal = &run.true_removal_nm;
        assert!(removal.iter().any(|v| *v > 1.0), "no removal deposited");
        for ((i, j), &ok) in valid.indexed_iter() {
            if ok {
                let got = run.before.heights_nm()[(i, j)]
                    - run.after.heights_nm()[(i, j)]
                    - removal[(i, j)];
                let own = m1.heights_nm()[(i, j)] - m2.heights_nm()[(i, j)];
                assert!((got - own).abs() <= 1e-9 * (1.0 + own.abs()), "({i}, {j})");
            }
        }
        let truth = 1.0f64.hypot(0.7);
        assert!(
            (run.true_noise_floor_nm / truth - 1.0).abs() < 0.1,
            "floor {} vs {truth}",
            run.true_noise_floor_nm
        );
        // Refusals, each with its reason.
        let small = Surface::new(Array2::zeros((r - 1, c)), Some(d), Some(d)).unwrap();
        let e = on_measured_maps(&cfg, &m1, &small).unwrap_err().to_string();
        assert!(e.contains("share its grid"), "{e}");
        let mut moved = cfg.clone();
        moved.effects.push(Injected::Registration {
            dx_mm: 0.1,
            dy_mm: 0.0,
            rotation_deg: 0.0,
        });
        let e = on_measured_maps(&moved, &m1, &m2).unwrap_err().to_string();
        assert!(e.contains("registration"), "{e}");
        let oblong = Surface::new(Array2::zeros((r, c)), Some(d), Some(2.0 * d)).unwrap();
        let e = SynthConfig::on_grid_of(&oblong, 3, 3.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("square pixels"), "{e}");
    }

    /// A camera pixel averages the surface over its square (`pixel_average`): against point
    /// samples of the same field, the map's pixel-scale content is attenuated (first
    /// differences along a row, which weigh the highest frequencies most) and its low-passed
    /// content (9 x 9 pixel means) is the same to a few per cent; the default (1) is the point
    /// sample, bit for bit.
    #[test]
    fn pixel_average_attenuates_the_pixel_scale_and_keeps_the_low_passed_map() {
        let cfg = |n: usize| SynthConfig {
            rows: 64,
            cols: 64,
            pixel_mm: 0.5,
            surface: InitialSurface::PowerLaw {
                exponent: 1.5,
                rms_nm: 20.0,
            },
            deposit_step_mm: 0.5,
            feed_min_mm_per_s: 10.0,
            feed_max_mm_per_s: 30.0,
            pixel_average: n,
            ..SynthConfig::default().with_noise_nm(0.0, 0.0)
        };
        let map = |n: usize| generate(&cfg(n)).unwrap().before.heights_nm().clone();
        let (point, one, avg) = (map(0), map(1), map(4));
        assert!(point == one);
        let d1 = |a: &Array2<f64>| {
            let (mut s, mut k) = (0.0, 0.0);
            for row in a.rows() {
                for w in row.as_slice().unwrap().windows(2) {
                    s += (w[1] - w[0]).powi(2);
                    k += 1.0;
                }
            }
            (s / k).sqrt()
        };
        let low = |a: &Array2<f64>| {
            Array2::from_shape_fn((a.nrows() - 8, a.ncols() - 8), |(i, j)| {
                a.slice(ndarray::s![i..i + 9, j..j + 9]).mean().unwrap()
            })
        };
        let rms = |a: &Array2<f64>| (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
        let (lp, la) = (low(&point), low(&avg));
        let low_change = rms(&(&la - &lp)) / rms(&lp);
        let ratio = d1(&avg) / d1(&point);
        eprintln!("first differences {ratio:.3}, low-passed change {low_change:.4}");
        assert!(
            ratio < 0.85,
            "first differences {ratio:.3} of the point samples'"
        );
        assert!(
            low_change < 0.05,
            "low-passed map changed by {low_change:.4}"
        );
    }

    #[test]
    fn periodic_extension_wraps_by_the_offset() {
        let a = Array2::from_shape_fn((3, 4), |(i, j)| (10 * i + j) as f64);
        let e = periodic_extend(&a, 1, 5, 6);
        assert_eq!(e[(0, 0)], a[(2, 3)]);
        assert_eq!(e[(1, 1)], a[(0, 0)]);
        assert_eq!(e[(4, 5)], a[(0, 0)]);
        assert_eq!(periodic_extend(&a, 0, 3, 4), a);
    }

    #[test]
    fn triangle_wave_has_sine_phase_and_unit_amplitude() {
        let q = std::f64::consts::FRAC_PI_2;
        assert!((wave(Waveform::Triangle, q) - 1.0).abs() < 1e-12);
        assert!((wave(Waveform::Triangle, 3.0 * q) + 1.0).abs() < 1e-12);
        assert!(wave(Waveform::Triangle, 0.0).abs() < 1e-12);
    }
}
