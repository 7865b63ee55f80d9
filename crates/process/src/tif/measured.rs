//! A TIF measured from a fixed-point spot: a height map of a dip polished for `dwell_s` seconds.
//! This is the one spot-to-TIF conversion of the project (simulate, calibrate, the vibration
//! coupling and the reports all use it).
//!
//! Steps and conventions:
//! 1. Background: a plane (piston + tilt) fitted by least squares on the border ring (valid
//!    pixels within `ring_fraction` of the smaller map side from the edge, at least 2 pixels),
//!    where the tool never touched; subtracting it removes set-up piston and tilt.
//! 2. Sign: removal = -(height - background), positive where material was removed.
//! 3. Rate: removal / dwell_s (nm/s), kept at the spot map's own pixel: a spot measured finer
//!    than the map is never resampled down first ([`MeasuredTif`] is a continuous field).
//! 4. Centre: the centroid of the removal above 10 % of its maximum gives a first estimate; it
//!    is refined without threshold as the centroid of the whole removal inside a disc reaching
//!    past the footprint. With the default [`Rim::ModelPlusResidual`] the tool centre is then
//!    the centre of the precessing-bonnet shape fitted to the spot ([`super::spotfit`]), which
//!    carries no bias whatever the spot's sub-pixel position (the truth suite checks spots 0.25
//!    and 0.8 mm off their map centre).
//! 5. Support: the footprint radius is where the azimuthal mean of the rate no longer stands out
//!    of the measurement noise (three standard errors of an annulus mean, the noise taken from
//!    the border ring) or falls below 0.5 % of the peak (a lower floor lets calibrate accept a
//!    spurious feed covariate on null runs; see the truth suite for what it costs); noise beyond it is not removal (a
//!    noisy footprint convolved with the dwell would print the noise as a dwell-shaped
//!    pattern). The rate is kept at full weight to 1.1 times that radius plus one spot pixel,
//!    then rolls off (raised cosine) to 0 at 1.3 times it plus two pixels (the window of the
//!    centroid and the fit), and never reaches beyond the largest disc inside the map: a hard
//!    cut where a smooth tail still stands at 0.1 % of the peak is a step edge, and at a fine
//!    pitch that step was 1.2 % of the ripple sigma_1 (truth suite).
//! 6. Between the spot's pixels ([`Rim`]): by default the fitted bonnet shape, evaluated
//!    exactly (its square-root rim included, which no interpolation of pixels reproduces), plus
//!    the measured-minus-fit residual when it stands out of the noise; when the shape does not
//!    describe the spot (residual above [`FIT_ACCEPT`] of the footprint's RMS or [`FIT_NOISE_ACCEPT`] times the noise) the smooth
//!    radial shape ([`super::spotfit::SmoothShape`], a generalised Gaussian) on the same terms,
//!    kept out to where it falls below [`SMOOTH_TAIL`] of its peak; when neither describes it, the pixels
//!    themselves: band-limited upsampling to a quarter pixel, then Catmull-Rom bicubic over
//!    valid pixels (invalid ones filled from their neighbours). On the Hertz bonnet of the
//!    truth suite at the map pixel, interpolation alone misses the ripple sigma_1 by up to 16 %,
//!    the fit by 0.4 % (`tests/truth_removal.rs`, `rim_reconstructions_compared`).

use ndarray::{Array2, Zip};

use super::bonnet::BonnetShape;
use super::spotfit::{fit_shape, fit_smooth, FitStart, SmoothShape};
use super::{RateField, Tif};
use crate::error::ProcessError;
use crate::interp::{catmull_rom_across, catmull_rom_on_line};
use crate::pixel::PixelSampling;
use bonnetlab_surface::fill::fill_invalid;
use bonnetlab_surface::form::{evaluate_fit, fit_terms};
use bonnetlab_surface::{Surface, Term};

/// Options of [`tif_from_spot`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpotOptions {
    /// Width of the background ring as a fraction of the smaller map side.
    pub ring_fraction: f64,
    /// Target pixel (dx, dy) in mm; `None` keeps the spot map's pixel.
    pub pixel_mm: Option<(f64, f64)>,
    /// Largest TIF radius kept in mm (`None`: as large as the map allows).
    pub max_radius_mm: Option<f64>,
    /// How the footprint between the spot's pixels (its rim above all) is reconstructed.
    pub rim: Rim,
    /// How the spot map's pixels sample the removal: with [`PixelSampling::Area`] the fitted
    /// shape is compared with the spot as means over its pixels, so the field is the TIF
    /// itself, not the TIF blurred by one spot pixel. What is interpolated from the pixels (a
    /// significant measured-minus-model residual, or the pixels themselves when no shape
    /// describes the spot) stays as measured: pixel means, which a removal for area pixels
    /// then averages once more (a second blur of that part only).
    pub pixels: PixelSampling,
}

/// How a measured TIF is reconstructed between the spot's pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Rim {
    /// The precessing-bonnet shape fitted to the spot ([`super::spotfit`]) evaluated exactly,
    /// plus the measured-minus-fit residual interpolated when it stands out of the noise
    /// ([`residual_is_significant`]); the fit's centre is the tool centre.
    /// When the bonnet fit leaves more than [`FIT_ACCEPT`] of the footprint's RMS, or more than
    /// [`FIT_NOISE_ACCEPT`] times the noise, unexplained (a spot the bonnet model does not
    /// describe), the smooth radial shape on the same terms (a Gaussian spot sampled at one
    /// pixel per sigma: removal RMS 0.12 % of the exact deposition where interpolating its
    /// pixels missed by 1.05 %, truth suite); when that does not describe it either,
    /// [`Rim::Interpolate`].
    #[default]
    ModelPlusResidual,
    /// The fitted shape alone (the residual dropped); for comparisons.
    ModelOnly,
    /// The spot's pixels interpolated (band-limited upsampling, then Catmull-Rom), centred on
    /// the threshold-free removal centroid.
    Interpolate,
}

/// Largest residual RMS, as a fraction of the footprint's RMS, for which the fitted bonnet shape
/// is used (beyond it the model does not describe the spot).
pub const FIT_ACCEPT: f64 = 0.05;

/// Largest residual RMS, in units of the border ring's noise RMS, for which the fitted bonnet
/// shape is used. A shape that leaves a residual many times the noise is the wrong shape, however
/// small the residual is against the footprint: a truncated Gaussian spot fitted by the bonnet
/// shape leaves 2.8 % of its RMS, 12x the noise, and its model-based rim moved the calibration
/// of such runs (a 4 um misregistration accepted on a run with none).
pub const FIT_NOISE_ACCEPT: f64 = 3.0;

/// Whether the fitted bonnet shape describes the spot: its residual is within [`FIT_ACCEPT`] of
/// the footprint's RMS and within [`FIT_NOISE_ACCEPT`] times the noise.
fn model_describes_spot(residual_rms: f64, data_rms: f64, noise: f64) -> bool {
    residual_rms <= FIT_ACCEPT * data_rms
        && residual_rms <= FIT_NOISE_ACCEPT * noise.max(FIT_NOISE_FLOOR * data_rms)
}

/// Least noise RMS, as a fraction of the footprint's RMS, that the noise test of
/// [`model_describes_spot`] assumes. A spot map without noise (simulated, or smoothed before it
/// was written) has a border ring of RMS 0, and the test alone then refused even an exact fit:
/// the bonnet shape fitted a noise-free synthetic spot to 3e-15 of its 8.9 nm/s RMS and was
/// refused, and the pixel interpolant taken instead, whose rim the 0.25 mm pixels do not
/// resolve, made the TIF about 1 % narrow (issue 15's harness with a noise-free centred spot:
/// tif_scale 1.010-1.015 accepted on 6 of 12 null runs). Measured spots sit well above it (0.5
/// nm of noise on that spot is 2.7e-3 of its RMS), so it changes nothing for them; a shape
/// that leaves more than three times it is still the wrong shape.
pub const FIT_NOISE_FLOOR: f64 = 1e-3;

/// How many standard errors the fit residual's mean square must stand above the border ring's
/// noise variance before the residual is kept ([`residual_is_significant`]).
pub const RESIDUAL_SIGNIFICANCE: f64 = 4.0;

/// Whether a fit residual of RMS `residual` over `pixels` pixels holds more than noise of RMS
/// `noise`: a chi-square test on the mean square, significant when it exceeds the noise variance
/// by more than [`RESIDUAL_SIGNIFICANCE`] standard errors (sqrt(2 / pixels) relative). Pure noise
/// is dropped (interpolating it into the TIF would print it into every removal); a misfit spread
/// thinly over many pixels, each below the noise (a Gaussian spot fitted by the bonnet shape),
/// still adds up to significance and is kept.
pub fn residual_is_significant(residual: f64, noise: f64, pixels: usize) -> bool {
    let n = pixels.max(1) as f64;
    residual * residual > noise * noise * (1.0 + RESIDUAL_SIGNIFICANCE * (2.0 / n).sqrt())
}

impl Default for SpotOptions {
    fn default() -> Self {
        SpotOptions {
            ring_fraction: 0.1,
            pixel_mm: None,
            max_radius_mm: None,
            rim: Rim::default(),
            pixels: PixelSampling::Point,
        }
    }
}

impl Tif {
    /// The removal-rate TIF of a measured spot polished for `dwell_s` seconds (default options).
    pub fn from_spot(spot: &Surface, dwell_s: f64) -> Result<Tif, ProcessError> {
        tif_from_spot(spot, dwell_s, &SpotOptions::default())
    }
}

/// Upsampling factor of a measured spot's samples.
const UPSAMPLE: usize = 4;
/// Largest upsampled spot array (samples).
const MAX_UPSAMPLED: usize = 2048 * 2048;

/// The removal rate of a measured spot as a continuous field at the spot's own resolution,
/// centred on its removal centroid (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredTif {
    /// Rate (nm/s) on the spot map's pixels; invalid pixels already filled.
    rate: Array2<f64>,
    dx_mm: f64,
    dy_mm: f64,
    /// Fractional (row, column) of the tool centre in `rate`.
    centre: (f64, f64),
    /// Beyond this distance from the centre the rate is 0 (mm).
    radius_mm: f64,
    /// Up to this distance the interpolated samples count at full weight; from it to
    /// `taper_end_mm` they roll off ([`taper_weight`]), mm.
    taper_start_mm: f64,
    /// Beyond this distance the interpolated samples count for nothing (mm); `radius_mm` except
    /// with a smooth model, which reaches further.
    taper_end_mm: f64,
    /// The fitted shape, centred on the tool centre, when the rim is model-based (`rate` then
    /// holds the measured-minus-model residual).
    model: Option<SpotModel>,
    /// The smooth model tabulated over the radius, evaluated in its place (see [`Radial`]).
    radial: Option<Radial>,
}

/// Nodes of [`Radial`] over the footprint's radius.
const RADIAL_NODES: usize = 4096;

/// Nodes from the centre within which [`Radial`] evaluates its shape directly.
const RADIAL_DIRECT: f64 = 32.0;

/// A smooth radial model tabulated in r, values and slopes at [`RADIAL_NODES`] + 2 nodes, and
/// evaluated by cubic Hermite interpolation: the kernel builds evaluate the field 32 times per
/// kernel pixel and channel, and a power and an exponential per evaluation were a sixth of a
/// calibration's time. Interpolation error below 1e-10 of the peak for exponents 0.75 to 3
/// (test `radial_table_matches_the_smooth_shape`); exponents below 0.75 (a cusp at the centre)
/// are evaluated directly, and so is the innermost 1/128 of the radius.
#[derive(Debug, Clone, PartialEq)]
struct Radial {
    /// The shape, evaluated directly within [`RADIAL_DIRECT`] nodes of the centre, where
    /// `q^beta` is not smooth (beta < 1) and the table would be least accurate.
    g: SmoothShape,
    /// Node spacing (mm).
    h: f64,
    /// Value (nm/s) and slope times the spacing at each node.
    v: Vec<f64>,
    d: Vec<f64>,
}

impl Radial {
    fn of(g: &SmoothShape, radius_mm: f64) -> Option<Radial> {
        if g.beta < 0.75 || !(radius_mm > 0.0 && radius_mm.is_finite()) {
            return None;
        }
        let h = radius_mm / RADIAL_NODES as f64;
        let s2 = g.sigma_mm * g.sigma_mm;
        let (v, d) = (0..RADIAL_NODES + 2)
            .map(|k| {
                let r = k as f64 * h;
                let f = g.rate_at(r, 0.0);
                // d/dr of peak exp(-q^beta), q = r^2 / (2 sigma^2); 0 at the centre (beta > 1/2).
                let q = r * r / (2.0 * s2);
                let slope = if r > 0.0 {
                    -f * g.beta * q.powf(g.beta - 1.0) * r / s2
                } else {
                    0.0
                };
                (f, slope * h)
            })
            .unzip();
        Some(Radial { g: *g, h, v, d })
    }

    #[inline]
    fn at(&self, r: f64) -> f64 {
        let t = r / self.h;
        if t < RADIAL_DIRECT {
            return self.g.rate_at(r, 0.0);
        }
        let i = (t as usize).min(self.v.len() - 2);
        let s = t - i as f64;
        let (s2, m) = (s * s, 1.0 - s);
        let m2 = m * m;
        self.v[i] * (1.0 + 2.0 * s) * m2 + self.d[i] * s * m2 + self.v[i + 1] * s2 * (3.0 - 2.0 * s)
            - self.d[i + 1] * s2 * m
    }
}

/// The shape fitted to a measured spot ([`super::spotfit`]).
#[derive(Debug, Clone, PartialEq)]
pub enum SpotModel {
    /// The precessing bonnet's shape, with its precession azimuths.
    Bonnet {
        shape: BonnetShape,
        azimuths: Vec<(f64, f64)>,
    },
    /// The smooth radial shape, when the bonnet's does not describe the spot.
    Smooth(SmoothShape),
}

impl SpotModel {
    /// Rate (nm/s) at (x, y) mm from the tool centre.
    pub fn rate_at(&self, x: f64, y: f64) -> f64 {
        match self {
            SpotModel::Bonnet { shape, azimuths } => shape.rate_with(x, y, azimuths),
            SpotModel::Smooth(g) => g.rate_at(x, y),
        }
    }
}

/// Fraction of its peak to which a smooth model is kept (beyond it the TIF is 0).
const SMOOTH_TAIL: f64 = 1e-6;
/// Farthest a smooth model reaches, in units of the reach of the spot's pixels.
const SMOOTH_REACH: f64 = 2.0;

impl MeasuredTif {
    /// The field of a measured spot polished for `dwell_s` seconds.
    pub fn from_spot(
        spot: &Surface,
        dwell_s: f64,
        o: &SpotOptions,
    ) -> Result<MeasuredTif, ProcessError> {
        if !(dwell_s.is_finite() && dwell_s > 0.0) {
            return Err(ProcessError::invalid(format!(
                "spot dwell_s must be positive, got {dwell_s}"
            )));
        }
        let (dx, dy) = spot.pixel_mm("a measured TIF")?;
        let (rows, cols) = spot.dim();
        if rows < 5 || cols < 5 {
            return Err(ProcessError::invalid(format!(
                "spot map {rows} x {cols} is too small"
            )));
        }
        let valid = spot.valid();
        let background = plane_background(spot, &border_ring(valid, o.ring_fraction))?;
        let removal = background.residual.heights_nm().mapv(|h| -h);
        let peak = removal
            .indexed_iter()
            .filter(|(ij, _)| valid[*ij])
            .fold(0.0f64, |m, (_, &v)| m.max(v));
        if peak <= 0.0 {
            return Err(ProcessError::Processing(
                "spot map: no removal found (no dip below the border ring)".into(),
            ));
        }
        // First centre: centroid above 10 % of the peak.
        let (mut s, mut si, mut sj) = (0.0, 0.0, 0.0);
        for ((i, j), &v) in removal.indexed_iter() {
            if valid[(i, j)] && v > 0.1 * peak {
                s += v;
                si += v * i as f64;
                sj += v * j as f64;
            }
        }
        let (mut u0, mut v0) = (si / s, sj / s);
        let room = |u: f64, v: f64| {
            (v.min(cols as f64 - 1.0 - v) * dx).min(u.min(rows as f64 - 1.0 - u) * dy)
        };
        let rate = fill_invalid(&removal.mapv(|r| r / dwell_s), valid);
        let noise = background.rms_nm / dwell_s;
        let support = support_radius_mm(&rate, (u0, v0), dx, dy, noise);
        // Refine: threshold-free centroid inside a disc past the footprint.
        for _ in 0..3 {
            let r_win = (1.3 * support + 2.0 * dx.max(dy)).min(room(u0, v0));
            let (mut s, mut si, mut sj) = (0.0, 0.0, 0.0);
            for ((i, j), &v) in rate.indexed_iter() {
                let (ox, oy) = ((j as f64 - v0) * dx, (i as f64 - u0) * dy);
                if ox * ox + oy * oy <= r_win * r_win {
                    s += v;
                    si += v * i as f64;
                    sj += v * j as f64;
                }
            }
            if s <= 0.0 {
                break;
            }
            let (nu, nv) = (si / s, sj / s);
            let moved = (nu - u0).abs() + (nv - v0).abs();
            (u0, v0) = (nu, nv);
            if moved < 1e-6 {
                break;
            }
        }
        // The bonnet shape fitted over the same disc, when the rim is model-based; the smooth
        // shape when the bonnet's does not describe the spot.
        let mut model = None;
        let mut rate = rate;
        if o.rim != Rim::Interpolate {
            let window = (1.3 * support + 2.0 * dx.max(dy)).min(room(u0, v0));
            let (ci, cj) = (u0.round() as usize, v0.round() as usize);
            let start = FitStart {
                centre: (u0, v0),
                peak: rate[(ci.min(rows - 1), cj.min(cols - 1))].max(0.5 * peak / dwell_s),
                a_mm: support,
            };
            let describes = |residual: f64, data: f64| model_describes_spot(residual, data, noise);
            let response = o.pixels.response(dx, dy);
            let fitted = fit_shape(&rate, valid, (dx, dy), start, window, 4, response)
                .filter(|f| describes(f.residual_rms, f.data_rms))
                .map(|f| {
                    let azimuths = f.shape.azimuths();
                    let m = SpotModel::Bonnet {
                        shape: f.shape,
                        azimuths,
                    };
                    (m, f.centre, f.residual_rms, f.pixels)
                })
                .or_else(|| {
                    fit_smooth(&rate, valid, (dx, dy), start, window, response)
                        .filter(|f| describes(f.residual_rms, f.data_rms))
                        .map(|f| {
                            (
                                SpotModel::Smooth(f.shape),
                                f.centre,
                                f.residual_rms,
                                f.pixels,
                            )
                        })
                });
            if let Some((m, centre, residual, pixels)) = fitted {
                (u0, v0) = centre;
                // A residual within the measurement noise is noise: the model alone.
                let significant = residual_is_significant(residual, noise, pixels);
                if o.rim == Rim::ModelPlusResidual && significant {
                    rate = Array2::from_shape_fn((rows, cols), |(i, j)| {
                        let (x, y) = ((j as f64 - v0) * dx, (i as f64 - u0) * dy);
                        rate[(i, j)] - response.mean_of(x, y, |u, v| m.rate_at(u, v))
                    });
                } else {
                    rate.fill(0.0);
                }
                model = Some(m);
            }
        }
        // Full weight to 1.1 times the support plus a pixel, then a raised-cosine roll-off to
        // zero at the fitting window (1.3 times the support plus two pixels): a hard cut where
        // the tail is still 0.1 % of the peak is a step edge that puts spurious ripple into the
        // removal (see `taper_weight`).
        let mut outer = (1.3 * support + 2.0 * dx.max(dy)).min(room(u0, v0));
        if let Some(SpotModel::Bonnet { shape, .. }) = &model {
            outer = outer.max(shape.a_mm);
        }
        if let Some(m) = o.max_radius_mm {
            outer = outer.min(m);
        }
        let radius = (1.1 * support + dx.max(dy)).min(outer);
        if outer < dx.max(dy) {
            return Err(ProcessError::Processing(
                "spot map: the spot touches the map border".into(),
            ));
        }
        // A smooth shape has no edge: it is kept to where it falls below SMOOTH_TAIL of its peak
        // (a cut there is a step far below any ripple), at most SMOOTH_REACH times the pixels'
        // reach, and never past the largest radius asked for.
        let model_radius = match &model {
            Some(SpotModel::Smooth(g)) => {
                let r = g.radius_below(SMOOTH_TAIL).min(SMOOTH_REACH * outer);
                o.max_radius_mm.map_or(r, |m| r.min(m)).max(outer)
            }
            _ => outer,
        };
        // A box of odd size around the footprint, band-limited upsampling to a quarter of the
        // spot pixel (a coarse spot of a smooth footprint is then interpolated almost exactly;
        // see interp::fourier_upsample), then Catmull-Rom between the fine samples.
        let (ci, cj) = (u0.round() as isize, v0.round() as isize);
        let (h0, h1) = (
            (outer / dy).ceil() as isize + 4,
            (outer / dx).ceil() as isize + 4,
        );
        let cropped =
            Array2::from_shape_fn((2 * h0 as usize + 1, 2 * h1 as usize + 1), |(a, b)| {
                let (i, j) = (ci - h0 + a as isize, cj - h1 + b as isize);
                if i >= 0 && j >= 0 && (i as usize) < rows && (j as usize) < cols {
                    rate[(i as usize, j as usize)]
                } else {
                    0.0
                }
            });
        let (n0, n1) = cropped.dim();
        let factor = (1..=UPSAMPLE)
            .rev()
            .find(|f| n0 * n1 * f * f <= MAX_UPSAMPLED)
            .unwrap_or(1);
        let fine = crate::interp::fourier_upsample(&cropped, factor);
        let f = factor as f64;
        Ok(MeasuredTif {
            rate: fine,
            dx_mm: dx / f,
            dy_mm: dy / f,
            centre: ((u0 - (ci - h0) as f64) * f, (v0 - (cj - h1) as f64) * f),
            radius_mm: model_radius,
            taper_start_mm: radius,
            taper_end_mm: outer,
            radial: match &model {
                Some(SpotModel::Smooth(g)) => Radial::of(g, model_radius),
                _ => None,
            },
            model,
        })
    }

    /// The pixel (dx, dy) in mm of the field's samples (the spot's pixel over the upsampling).
    pub fn pixel_mm(&self) -> (f64, f64) {
        (self.dx_mm, self.dy_mm)
    }

    /// Radius beyond which the rate is 0, mm.
    pub fn radius_mm(&self) -> f64 {
        self.radius_mm
    }

    /// The fitted shape, when the rim is model-based.
    pub fn model(&self) -> Option<&SpotModel> {
        self.model.as_ref()
    }
}

impl RateField for MeasuredTif {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.rate_with(dx_mm, dy_mm, |u, v| {
            crate::interp::catmull_rom(&self.rate, u, v)
        })
    }

    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        // Across the line once, then four taps per point along it.
        let mut line = Vec::new();
        let live = if along_x {
            catmull_rom_across(&self.rate, true, self.centre.0 + c / self.dy_mm, &mut line)
        } else {
            catmull_rom_across(&self.rate, false, self.centre.1 + c / self.dx_mm, &mut line)
        };
        let along = |u: f64, v: f64| match (live, along_x) {
            (false, _) => 0.0,
            (true, true) => catmull_rom_on_line(&line, v),
            (true, false) => catmull_rom_on_line(&line, u),
        };
        for (o, &p) in out.iter_mut().zip(t) {
            *o = if along_x {
                self.rate_with(p, c, along)
            } else {
                self.rate_with(c, p, along)
            };
        }
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        (self.radius_mm, self.radius_mm)
    }
}

impl MeasuredTif {
    /// The rate at (dx, dy) mm from the tool centre, `samples(u, v)` the interpolant of the
    /// (residual) samples at fractional (row, column) of the spot map.
    #[inline]
    fn rate_with(&self, dx_mm: f64, dy_mm: f64, samples: impl Fn(f64, f64) -> f64) -> f64 {
        let r2 = dx_mm * dx_mm + dy_mm * dy_mm;
        if r2 > self.radius_mm * self.radius_mm {
            return 0.0;
        }
        let fitted = match (&self.radial, &self.model) {
            (Some(t), _) => t.at(r2.sqrt()),
            (None, Some(m)) => m.rate_at(dx_mm, dy_mm),
            (None, None) => 0.0,
        };
        let w = taper_weight(r2.sqrt(), self.taper_start_mm, self.taper_end_mm);
        if w == 0.0 {
            return fitted;
        }
        let u = self.centre.0 + dy_mm / self.dy_mm;
        let v = self.centre.1 + dx_mm / self.dx_mm;
        fitted + w * samples(u, v)
    }
}

/// Weight of the interpolated samples at `r` mm from the tool centre: 1 up to `start`, a
/// raised cosine from 1 at `start` to 0 at `end`, 0 beyond. Measured (truth suite, a Gaussian of
/// 0.6 mm sigma whose support is cut at 0.5 % of the peak, 3.3 sigma): a hard cut at 1.1 times
/// the support plus one spot pixel moved the ripple sigma_1 at a 1.3 mm pitch by +1.2 % with the
/// spot at 0.025 mm pixels and by +0.4 % at 0.06 mm (the cut radius moves with the pixel, and
/// a step at 0.1 % of the peak is most of a ripple that small). With the roll-off to the
/// fitting window the worst case of the suite with the spot at a quarter pixel or finer is
/// 0.31 % (before: 1.19 %); the bonnet spots (model-based rim) do not change.
fn taper_weight(r: f64, start: f64, end: f64) -> f64 {
    if r <= start {
        1.0
    } else if r >= end {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * (r - start) / (end - start)).cos())
    }
}

/// Mask of the border ring of a map: the valid pixels within `ring_fraction` of the smaller map
/// side (rounded, at least 2 pixels) from an edge, where the tool never touched. The process
/// front end's background ring (see the module docs, step 1).
pub fn border_ring(valid: &Array2<bool>, ring_fraction: f64) -> Array2<bool> {
    let (rows, cols) = valid.dim();
    let w = ((rows.min(cols) as f64 * ring_fraction).round() as usize).max(2);
    Array2::from_shape_fn((rows, cols), |(i, j)| {
        valid[(i, j)] && (i < w || j < w || i + w >= rows || j + w >= cols)
    })
}

/// A spot map's background: piston and tilt fitted by least squares on a mask of untouched
/// pixels (`bonnetlab_surface::form`), and what it leaves.
#[derive(Debug, Clone)]
pub struct PlaneBackground {
    /// The map minus the plane (nm), on the map's grid and mask; invalid pixels hold 0.
    pub residual: Surface,
    /// Valid pixels in the mask.
    pub pixels: usize,
    /// RMS of `residual` over the mask: the measurement noise estimate (nm).
    pub rms_nm: f64,
}

/// The one background convention of a spot map: piston + tilt fitted on `mask` (the border ring
/// of [`border_ring`] for the TIF front end; the spots analysis may give its own ring) and
/// subtracted everywhere. Removal is then `-residual` for a height map of a dip. Tilt is dropped
/// when the mask cannot determine it; fewer than 3 valid pixels is an error.
pub fn plane_background(s: &Surface, mask: &Array2<bool>) -> Result<PlaneBackground, ProcessError> {
    let pixels = mask.iter().zip(s.valid()).filter(|(&m, &v)| m && v).count();
    if pixels < 3 {
        return Err(ProcessError::Processing(
            "spot map: no valid pixels on the background ring".into(),
        ));
    }
    let on_mask = s.with_valid(Zip::from(mask).and(s.valid()).map_collect(|&m, &v| m && v))?;
    let fit = fit_terms(&on_mask, &[Term::Piston, Term::Tilt])?;
    let residual = s.with_heights(s.heights_nm() - &evaluate_fit(s, &fit))?;
    let sum2: f64 = residual
        .heights_nm()
        .iter()
        .zip(on_mask.valid())
        .filter(|(_, &m)| m)
        .map(|(v, _)| v * v)
        .sum();
    Ok(PlaneBackground {
        residual,
        pixels,
        rms_nm: (sum2 / pixels as f64).sqrt(),
    })
}

/// Fraction of the peak below which an annulus is no longer footprint, even without noise.
const SUPPORT_FLOOR: f64 = 5e-3;

/// Radius (mm) of the footprint: the outer edge of the last one-pixel annulus around `centre`
/// whose mean rate stands out of the noise (above three standard errors of an annulus mean of
/// pixels with noise `noise_rate`, nm/s) and above [`SUPPORT_FLOOR`] of the peak, searched
/// outwards until four annuli in a row fall below (noise far out does not count).
fn support_radius_mm(
    rate: &Array2<f64>,
    centre: (f64, f64),
    dx: f64,
    dy: f64,
    noise_rate: f64,
) -> f64 {
    let (r, c) = rate.dim();
    let d = dx.min(dy);
    let nb = ((r as f64 * dy).hypot(c as f64 * dx) / d) as usize + 2;
    let (mut sum, mut cnt) = (vec![0.0f64; nb], vec![0usize; nb]);
    let mut peak = 0.0f64;
    for ((i, j), &v) in rate.indexed_iter() {
        let b = (((j as f64 - centre.1) * dx).hypot((i as f64 - centre.0) * dy) / d) as usize;
        if b < nb {
            sum[b] += v;
            cnt[b] += 1;
        }
        peak = peak.max(v);
    }
    let mut last = 0;
    for b in 0..nb {
        let level = (SUPPORT_FLOOR * peak).max(3.0 * noise_rate / (cnt[b].max(1) as f64).sqrt());
        if cnt[b] > 0 && sum[b] / cnt[b] as f64 > level {
            last = b;
        } else if cnt[b] > 0 && b > last + 3 {
            break;
        }
    }
    (last as f64 + 1.0) * d
}

/// The removal-rate TIF of a measured spot, sampled at `o.pixel_mm` (default: the spot's own
/// pixel) from its [`MeasuredTif`] field; see the module docs for the steps.
pub fn tif_from_spot(spot: &Surface, dwell_s: f64, o: &SpotOptions) -> Result<Tif, ProcessError> {
    let field = MeasuredTif::from_spot(spot, dwell_s, o)?;
    let (dx, dy) = spot.pixel_mm("a measured TIF")?;
    let (tdx, tdy) = o.pixel_mm.unwrap_or((dx, dy));
    if !(tdx > 0.0 && tdy > 0.0 && tdx.is_finite() && tdy.is_finite()) {
        return Err(ProcessError::invalid(
            "target TIF pixel size must be positive",
        ));
    }
    let (rows, cols) = spot.dim();
    let (h0, h1) = (
        (field.radius_mm / tdy).floor() as usize,
        (field.radius_mm / tdx).floor() as usize,
    );
    if (2 * h0 + 1) * (2 * h1 + 1) > 4 * rows * cols + 64 * 64 {
        return Err(ProcessError::invalid(
            "target TIF pixel is far finer than the spot map",
        ));
    }
    Tif::sample(&field, tdx, tdy)
}

#[cfg(test)]
mod tests {

    #[test]
    fn radial_table_matches_the_smooth_shape() {
        for beta in [0.75, 0.9991, 1.0, 1.7, 3.0] {
            let g = SmoothShape {
                peak: 850.0,
                sigma_mm: 1.35,
                beta,
            };
            let radius = g.radius_below(1e-4).max(4.0);
            let t = Radial::of(&g, radius).unwrap();
            let mut worst: f64 = 0.0;
            for k in 0..=20_000 {
                let r = radius * k as f64 / 20_000.0 * (1.0 - 1e-12);
                worst = worst.max((t.at(r) - g.rate_at(r, 0.0)).abs());
            }
            assert!(
                worst < 1e-10 * g.peak,
                "beta {beta}: worst {worst:.3e} nm/s"
            );
        }
        let cusp = SmoothShape {
            peak: 1.0,
            sigma_mm: 1.0,
            beta: 0.5,
        };
        assert!(Radial::of(&cusp, 5.0).is_none());
    }

    use super::*;
    use crate::tif::{GaussianTif, RateField};
    use bonnetlab_surface::rng::Rng;

    #[test]
    fn recovers_an_offcentre_gaussian_spot_with_tilt_and_noise() {
        let g = GaussianTif::new(2.0, 16.0, 5.0).unwrap();
        let dwell = 20.0;
        let (xc, yc) = (13.3, 11.7);
        let mut rng = Rng::new(9);
        let h = Array2::from_shape_fn((120, 130), |(i, j)| {
            let (x, y) = (j as f64 * 0.2, i as f64 * 0.2);
            40.0 + 0.5 * x - 0.3 * y - g.rate_at_mm(x - xc, y - yc) * dwell + 0.2 * rng.normal()
        });
        let s = Surface::new(h, Some(0.2), Some(0.2)).unwrap();
        let t = tif_from_spot(
            &s,
            dwell,
            &SpotOptions {
                pixel_mm: Some((0.1, 0.1)),
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            (t.peak_rate_nm_per_s() - 5.0).abs() < 0.1,
            "{}",
            t.peak_rate_nm_per_s()
        );
        let vol = 2.0 * std::f64::consts::PI * 4.0 * 5.0;
        assert!((t.volume_rate_nm_mm2_per_s() / vol - 1.0).abs() < 0.02);
        let (cx, cy) = t.centroid_mm();
        assert!(cx.abs() < 0.05 && cy.abs() < 0.05, "{cx} {cy}");
        assert!((t.value_at_mm(2.0, 0.0) - g.rate_at_mm(2.0, 0.0)).abs() < 0.1);
    }

    /// A spot map without noise (a simulated one, flat around the spot) of the precessing
    /// bonnet: the fitted bonnet shape is its model, as for the same spot with measurement
    /// noise. Its border ring has no noise at all, and before `FIT_NOISE_FLOOR` the noise test refused the exact fit and took
    /// the pixel interpolant, whose rim 0.25 mm pixels do not resolve (about 1 % narrow).
    #[test]
    fn a_noise_free_bonnet_spot_takes_the_fitted_bonnet_shape() {
        use crate::tif::bonnet::{BonnetTif, BonnetTifParams};
        let truth = BonnetTif::new(&BonnetTifParams::paper(12.0)).unwrap();
        let (dwell, pix, (xc, yc)) = (20.0, 0.25, (15.1, 14.87));
        let mut rng = Rng::new(3);
        for noise_nm in [0.0, 0.5] {
            let h = Array2::from_shape_fn((120, 120), |(i, j)| {
                let (x, y) = (j as f64 * pix, i as f64 * pix);
                -truth.rate_at_mm(x - xc, y - yc) * dwell + noise_nm * rng.normal()
            });
            let s = Surface::new(h, Some(pix), Some(pix)).unwrap();
            let m = MeasuredTif::from_spot(&s, dwell, &SpotOptions::default()).unwrap();
            assert!(
                matches!(m.model(), Some(SpotModel::Bonnet { .. })),
                "noise {noise_nm} nm: {:?}",
                m.model().map(|_| "another model")
            );
            // Point values across the rim, against the truth, to the noise's share.
            let peak = truth.rate_at_mm(0.0, 0.0);
            let mut worst = 0.0f64;
            for k in 0..=400 {
                let r = 8.0 * k as f64 / 400.0;
                for (cx, cy) in [(1.0, 0.0), (0.6, 0.8), (0.0, 1.0)] {
                    let d = m.rate_at_mm(r * cx, r * cy) - truth.rate_at_mm(r * cx, r * cy);
                    worst = worst.max(d.abs());
                }
            }
            let tol = if noise_nm == 0.0 { 1e-6 } else { 2e-2 };
            assert!(
                worst < tol * peak,
                "noise {noise_nm} nm: worst {worst:.3e} of {peak}"
            );
        }
    }

    /// The line evaluation of a measured spot (and of its derived channels) gives the point
    /// values, on lines through the footprint, its taper and its cut, in both directions.
    #[test]
    fn rates_along_a_line_are_the_point_values() {
        use crate::tif::derived::{Channel, Derived};
        let g = GaussianTif::new(1.2, 8.0, 5.0).unwrap();
        let mut rng = Rng::new(4);
        let (xc, yc) = (6.1, 5.3);
        let h = Array2::from_shape_fn((60, 64), |(i, j)| {
            let (x, y) = (j as f64 * 0.2, i as f64 * 0.2);
            -g.rate_at_mm(x - xc, y - yc) * 10.0 + 0.05 * rng.normal()
        });
        let s = Surface::new(h, Some(0.2), Some(0.2)).unwrap();
        let m = MeasuredTif::from_spot(&s, 10.0, &SpotOptions::default()).unwrap();
        let (ex, _) = m.half_extent_mm();
        let t: Vec<f64> = (0..997)
            .map(|k| -1.1 * ex + 2.2 * ex * k as f64 / 996.0)
            .collect();
        let base: std::sync::Arc<dyn RateField + Send> = std::sync::Arc::new(m.clone());
        let fields: Vec<Box<dyn RateField>> = vec![
            Box::new(m),
            Box::new(Derived::new(base.clone(), 1.1, Channel::Value, 0.0)),
            Box::new(Derived::new(base.clone(), 0.9, Channel::Dx, 0.02)),
            Box::new(Derived::new(base.clone(), 1.0, Channel::Dy, 0.02)),
            Box::new(Derived::new(base, 1.2, Channel::Ds, 1e-3)),
        ];
        let mut out = vec![0.0; t.len()];
        for f in &fields {
            let peak = f
                .rate_at_mm(0.0, 0.0)
                .abs()
                .max(f.rate_at_mm(0.5, 0.5).abs());
            for c in [-1.05 * ex, -3.3, -0.07, 0.0, 1.9, 0.8 * ex] {
                for along_x in [true, false] {
                    f.rates_along(along_x, c, &t, &mut out);
                    let mut nonzero = 0;
                    for (&p, &o) in t.iter().zip(&out) {
                        let want = if along_x {
                            f.rate_at_mm(p, c)
                        } else {
                            f.rate_at_mm(c, p)
                        };
                        assert!((o - want).abs() <= 1e-12 * peak, "{c} {p}: {o} vs {want}");
                        nonzero += usize::from(want != 0.0);
                    }
                    if c.abs() < 2.0 {
                        assert!(nonzero > 100);
                    }
                }
            }
        }
    }

    #[test]
    fn rejects_flat_map_and_bad_dwell() {
        let s = Surface::new(Array2::zeros((20, 20)), Some(0.1), Some(0.1)).unwrap();
        assert!(Tif::from_spot(&s, 10.0).is_err());
        assert!(Tif::from_spot(&s, 0.0).is_err());
    }
}
