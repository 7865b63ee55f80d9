//! The precessing-bonnet shape ([`BonnetShape`]) fitted to a measured spot's rate map: centre,
//! centre rate, contact radius, pressure exponent, lever and precession azimuth, by
//! Levenberg-Marquardt on the pixel values (point samples), each step solved by the project's
//! least squares (`bonnetlab_surface::lsq`, QR of the Jacobian with Marquardt's damping rows,
//! never the normal equations). The bonnet's Jacobian is analytic
//! ([`BonnetShape::rate_partials`]): one pass over the pixels per iteration instead of one
//! evaluation per parameter.
//!
//! Why: a footprint with a square-root rim (Hertz contact) is not band-limited, so no
//! interpolation of its pixels reproduces the rim between them; the model does, and the
//! measured-minus-model residual, which is smooth when the model fits, is what the measured TIF
//! interpolates (see [`super::measured`]). The fit's centre is the tool centre: for a
//! point-symmetric footprint it carries no bias whatever the sub-pixel position (a centroid
//! over a window does, when the window clips the noisy surround unevenly).
//!
//! Parameters are fitted as (x0, y0, ln peak, ln a, ln gamma, ln b, psi), so the positive ones
//! stay positive; gamma is bounded to [0.05, 50] (50 makes the shape a Gaussian for all
//! purposes), b to [0.02 a, 200 a].
//!
//! A spot the bonnet shape does not describe (a Gaussian-like spot of an ion beam or of a
//! bonnet worn smooth: the shape's compact support leaves a residual many times the noise) is
//! fitted by the smooth radial shape [`SmoothShape`] instead ([`fit_smooth`]),
//! `peak exp(-(r^2 / (2 sigma^2))^beta)`: a Gaussian at beta = 1, flatter-topped above, more
//! peaked below. Fitted as (x0, y0, ln peak, ln sigma, ln beta), beta bounded to [0.3, 3], by
//! the same driver and schedule. Why: a spot sampled at about one pixel per sigma (a spot
//! measured on a coarser pixel than the map) is not band-limited at its pixel, so interpolating
//! its pixels misses the removal RMS by 1 % (truth suite); the fitted shape, where its residual
//! is within the noise, does not.

use ndarray::Array2;
use rayon::prelude::*;

use super::bonnet::BonnetShape;
use crate::pixel::PixelResponse;
use bonnetlab_surface::lm::{minimize, LmProblem, LmSettings};

/// A fitted shape (the bonnet's by default, or a [`SmoothShape`]) with its centre and how well
/// it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeFit<S = BonnetShape> {
    pub shape: S,
    /// Centre (row, column), fractional pixels of the fitted map.
    pub centre: (f64, f64),
    /// RMS of the residual over the fitted pixels, nm/s.
    pub residual_rms: f64,
    /// RMS of the data over the fitted pixels, nm/s.
    pub data_rms: f64,
    /// Pixels the fit used.
    pub pixels: usize,
    pub iterations: usize,
}

/// Starting point of a fit.
#[derive(Debug, Clone, Copy)]
pub struct FitStart {
    /// (row, column), fractional pixels.
    pub centre: (f64, f64),
    pub peak: f64,
    pub a_mm: f64,
}

/// A smooth radial spot: `peak exp(-(r^2 / (2 sigma^2))^beta)` (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmoothShape {
    /// Rate at the centre, nm/s.
    pub peak: f64,
    /// Width, mm (the Gaussian's sigma at beta = 1).
    pub sigma_mm: f64,
    /// Exponent of the radial profile (1: Gaussian).
    pub beta: f64,
}

impl SmoothShape {
    /// Rate (nm/s) at (x, y) mm from the centre.
    pub fn rate_at(&self, x: f64, y: f64) -> f64 {
        let q = (x * x + y * y) / (2.0 * self.sigma_mm * self.sigma_mm);
        self.peak * (-q.powf(self.beta)).exp()
    }

    /// Radius (mm) beyond which the rate is below `fraction` (in (0, 1)) of the peak.
    pub fn radius_below(&self, fraction: f64) -> f64 {
        self.sigma_mm * (2.0 * (-fraction.ln()).powf(1.0 / self.beta)).sqrt()
    }
}

/// Bounds of the smooth shape's exponent.
const BETA_RANGE: (f64, f64) = (0.3, 3.0);

/// Most pixels a fit evaluates (finer maps are strided evenly).
const MAX_FIT_PIXELS: usize = 12_000;
/// Parameters of the bonnet shape.
const NP: usize = 7;

fn shape_of(p: &[f64], steps: usize) -> BonnetShape {
    BonnetShape {
        peak: p[2].exp(),
        a_mm: p[3].exp(),
        gamma: p[4].exp().clamp(0.05, 50.0),
        lever_mm: p[5].exp(),
        psi_rad: p[6],
        steps,
    }
}

fn smooth_of(p: &[f64]) -> SmoothShape {
    SmoothShape {
        peak: p[2].exp(),
        sigma_mm: p[3].exp(),
        beta: p[4].exp().clamp(BETA_RANGE.0, BETA_RANGE.1),
    }
}

/// Fits the shape to `rate` (nm/s) at pixel (dx, dy) mm over the pixels where `use_px` is true
/// within `window_mm` of the start centre, each pixel's value the model as `response` sees it
/// (a point sample, or the mean over the pixel). `None` when the fit does not converge to a
/// footprint (non-finite, or a contact radius outside the window).
pub fn fit_shape(
    rate: &Array2<f64>,
    use_px: &Array2<bool>,
    (dx, dy): (f64, f64),
    start: FitStart,
    window_mm: f64,
    steps: usize,
    response: PixelResponse,
) -> Option<ShapeFit> {
    let pts = fit_points(rate, use_px, dx, dy, start.centre, window_mm, NP)?;
    let a0 = start.a_mm.max(2.0 * dx.max(dy));
    let values = |p: &[f64]| {
        let s = shape_of(p, steps);
        let az = s.azimuths();
        by_chunks(&pts, |&(x, y, _)| {
            response.mean_of(x - p[0], y - p[1], |u, v| s.rate_with(u, v, &az))
        })
    };
    // The analytic Jacobian in the fitted parameters (x0, y0 enter as x - x0, y - y0; gamma
    // is constant where `shape_of` clamps it).
    let gradient = |p: &[f64]| -> Vec<Vec<f64>> {
        let s = shape_of(p, steps);
        let az = s.azimuths();
        let g_free = (0.05..50.0).contains(&p[4].exp());
        let rows = by_chunks(&pts, |&(x, y, _)| {
            response.mean_of_n(x - p[0], y - p[1], |u, v| {
                let (r, d) = s.rate_partials(u, v, &az);
                let dg = if g_free { d[3] } else { 0.0 };
                [-d[0], -d[1], r, d[2], dg, d[4], d[5]]
            })
        });
        (0..NP)
            .map(|k| rows.iter().map(|row| row[k]).collect())
            .collect()
    };
    // Forward differences: lengths in mm scaled to the footprint, logs and angles absolute.
    let h = [1e-5 * a0, 1e-5 * a0, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6];
    // Keep the trial inside the plausible region.
    let clamp = |q: &mut [f64]| {
        q[4] = q[4].clamp(0.05f64.ln(), 50f64.ln());
        q[5] = q[5].clamp((0.02 * a0).ln(), (200.0 * a0).ln());
        q[3] = q[3].min((2.0 * window_mm).ln());
    };
    let mut best: Option<(Vec<f64>, f64, usize)> = None;
    // Three starting exponents (bell, parabolic, Hertz-like): the best converged fit wins.
    for gamma0 in [0.5, 1.0, 2.0] {
        let p0 = vec![
            0.0,
            0.0,
            start.peak.max(1e-12).ln(),
            a0.ln(),
            f64::ln(gamma0),
            (2.0 * a0).ln(),
            0.0,
        ];
        if let Some((p, cost, it)) =
            levenberg_marquardt(&pts, p0, &values, Some(&gradient), &h, &clamp, 10)
        {
            if best.as_ref().is_none_or(|b| cost < b.1) {
                best = Some((p, cost, it));
            }
        }
    }
    // The best start carried on to convergence.
    let (p, _, it0) = best?;
    let (p, cost, it1) = levenberg_marquardt(&pts, p, &values, Some(&gradient), &h, &clamp, 60)?;
    let shape = shape_of(&p, steps);
    if !(shape.a_mm > 0.5 * dx.max(dy) && shape.a_mm <= window_mm && shape.peak.is_finite()) {
        return None;
    }
    Some(fit_result(
        shape,
        &pts,
        start.centre,
        &p,
        cost,
        (dx, dy),
        it0 + it1,
    ))
}

/// Fits the [`SmoothShape`] to `rate` (nm/s) like [`fit_shape`] fits the bonnet's: same pixels,
/// window, start and driver. `None` when the fit does not converge to a footprint (non-finite,
/// or a width outside the window).
pub fn fit_smooth(
    rate: &Array2<f64>,
    use_px: &Array2<bool>,
    (dx, dy): (f64, f64),
    start: FitStart,
    window_mm: f64,
    response: PixelResponse,
) -> Option<ShapeFit<SmoothShape>> {
    let pts = fit_points(rate, use_px, dx, dy, start.centre, window_mm, NP)?;
    let a0 = start.a_mm.max(2.0 * dx.max(dy));
    let values = |p: &[f64]| {
        let s = smooth_of(p);
        by_chunks(&pts, |&(x, y, _)| {
            response.mean_of(x - p[0], y - p[1], |u, v| s.rate_at(u, v))
        })
    };
    let h = [1e-5 * a0, 1e-5 * a0, 1e-6, 1e-6, 1e-6];
    let clamp = |q: &mut [f64]| {
        q[4] = q[4].clamp(BETA_RANGE.0.ln(), BETA_RANGE.1.ln());
        q[3] = q[3].min((2.0 * window_mm).ln());
    };
    // The support is where the spot falls to about 0.5 % of its peak: 3.3 sigma of a Gaussian.
    let p0 = vec![0.0, 0.0, start.peak.max(1e-12).ln(), (a0 / 3.3).ln(), 0.0];
    let (p, cost, it) = levenberg_marquardt(&pts, p0, &values, None, &h, &clamp, 80)?;
    let shape = smooth_of(&p);
    if !(shape.sigma_mm > 0.1 * dx.max(dy) && shape.sigma_mm <= window_mm && shape.peak.is_finite())
    {
        return None;
    }
    Some(fit_result(
        shape,
        &pts,
        start.centre,
        &p,
        cost,
        (dx, dy),
        it,
    ))
}

/// The pixels of a fit as (x, y) mm relative to `centre` (fractional row, column) and their
/// values: those where `use_px` is true within `window_mm` of it, strided evenly on fine maps.
/// `None` when there are fewer than four per parameter (`np` parameters).
fn fit_points(
    rate: &Array2<f64>,
    use_px: &Array2<bool>,
    dx: f64,
    dy: f64,
    centre: (f64, f64),
    window_mm: f64,
    np: usize,
) -> Option<Vec<(f64, f64, f64)>> {
    let (rows, cols) = rate.dim();
    let (u0, v0) = centre;
    let n_in = {
        let (h0, h1) = (window_mm / dy, window_mm / dx);
        (std::f64::consts::PI * h0 * h1) as usize + 1
    };
    let stride = ((n_in as f64 / MAX_FIT_PIXELS as f64).sqrt().ceil() as usize).max(1);
    let mut pts: Vec<(f64, f64, f64)> = Vec::new();
    for i in (0..rows).step_by(stride) {
        for j in (0..cols).step_by(stride) {
            let (x, y) = ((j as f64 - v0) * dx, (i as f64 - u0) * dy);
            if use_px[(i, j)] && x * x + y * y <= window_mm * window_mm {
                pts.push((x, y, rate[(i, j)]));
            }
        }
    }
    (pts.len() >= 4 * np).then_some(pts)
}

/// The [`ShapeFit`] of converged parameters `p` (whose first two are the centre's x, y offset
/// in mm from `centre`) with least-squares `cost` over `pts`, at pixel `px` (dx, dy) mm.
fn fit_result<S>(
    shape: S,
    pts: &[(f64, f64, f64)],
    centre: (f64, f64),
    p: &[f64],
    cost: f64,
    px: (f64, f64),
    iterations: usize,
) -> ShapeFit<S> {
    let n = pts.len() as f64;
    let data_rms = (pts.iter().map(|q| q.2 * q.2).sum::<f64>() / n).sqrt();
    ShapeFit {
        shape,
        centre: (centre.0 + p[1] / px.1, centre.1 + p[0] / px.0),
        residual_rms: (cost / n).sqrt(),
        data_rms,
        pixels: pts.len(),
        iterations,
    }
}

/// Points per parallel task of a fit's evaluations: each point costs tens of nanoseconds, so
/// finer tasks spend more on scheduling (and idle workers spinning) than they save.
const CHUNK: usize = 2048;

/// `f` at every point, in order, in parallel over chunks of [`CHUNK`] points.
fn by_chunks<T: Send>(pts: &[(f64, f64, f64)], f: impl Fn(&(f64, f64, f64)) -> T + Sync) -> Vec<T> {
    if pts.len() <= CHUNK {
        return pts.iter().map(f).collect();
    }
    pts.par_chunks(CHUNK)
        .flat_map_iter(|c| c.iter().map(&f))
        .collect()
}

fn cost_of(pts: &[(f64, f64, f64)], m: &[f64]) -> f64 {
    pts.iter().zip(m).map(|(q, v)| (q.2 - v).powi(2)).sum()
}

/// A shape fit as the project's one Levenberg-Marquardt driver sees it: residual
/// `model - data` at the fit's pixels, the Jacobian analytic (`gradient`) or else by forward
/// differences with step `h[k]` for parameter k, trials clamped to the plausible region by
/// `clamp`.
struct ShapeProblem<'a> {
    pts: &'a [(f64, f64, f64)],
    /// The model at the points for parameters `p`.
    values: &'a dyn Fn(&[f64]) -> Vec<f64>,
    /// The model's partial derivatives at the points, one column per parameter.
    gradient: Option<Gradient<'a>>,
    h: &'a [f64],
    clamp: &'a dyn Fn(&mut [f64]),
}

/// A fit's analytic Jacobian: the partial derivatives at the points, one column per parameter.
type Gradient<'a> = &'a dyn Fn(&[f64]) -> Vec<Vec<f64>>;

/// An evaluation: the model at the points and the residual `model - data`.
struct Trial {
    m: Vec<f64>,
    r: Vec<f64>,
}

impl ShapeProblem<'_> {
    fn trial(&self, p: &[f64]) -> Trial {
        let m = (self.values)(p);
        let r = m.iter().zip(self.pts).map(|(v, q)| v - q.2).collect();
        Trial { m, r }
    }
}

impl LmProblem for ShapeProblem<'_> {
    type State = Trial;
    type Error = std::convert::Infallible;

    fn residual<'s>(&self, state: &'s Trial) -> &'s [f64] {
        &state.r
    }

    fn cost(&self, state: &Trial) -> f64 {
        cost_of(self.pts, &state.m)
    }

    fn jacobian(&mut self, x: &[f64], state: &Trial) -> Result<Vec<Vec<f64>>, Self::Error> {
        if let Some(g) = self.gradient {
            return Ok(g(x));
        }
        Ok((0..x.len())
            .map(|k| {
                let mut q = x.to_vec();
                q[k] += self.h[k];
                let mk = (self.values)(&q);
                mk.iter()
                    .zip(&state.m)
                    .map(|(a, b)| (a - b) / self.h[k])
                    .collect()
            })
            .collect())
    }

    fn propose(&self, x: &[f64], step: &[f64]) -> Vec<f64> {
        let mut q: Vec<f64> = x.iter().zip(step).map(|(a, d)| a + d).collect();
        (self.clamp)(&mut q);
        q
    }

    fn evaluate(&mut self, x: &[f64], _current: &Trial) -> Result<Option<Trial>, Self::Error> {
        Ok(Some(self.trial(x)))
    }
}

/// A shape fit from `p` by `surface::lm` (see [`ShapeProblem`]; `gradient` the analytic
/// Jacobian, forward differences with steps `h` without): (parameters, cost,
/// iterations), `None` when the parameters are not finite.
fn levenberg_marquardt(
    pts: &[(f64, f64, f64)],
    p: Vec<f64>,
    values: &dyn Fn(&[f64]) -> Vec<f64>,
    gradient: Option<Gradient>,
    h: &[f64],
    clamp: &dyn Fn(&mut [f64]),
    max_iter: usize,
) -> Option<(Vec<f64>, f64, usize)> {
    let mut prob = ShapeProblem {
        pts,
        values,
        gradient,
        h,
        clamp,
    };
    let start = prob.trial(&p);
    let settings = LmSettings {
        max_iter,
        max_tries: 12,
        lambda0: 1e-3,
        increase: 4.0,
        decrease: 3.0,
        lambda_min: 1e-12,
        rel_tol: 1e-9,
        step_tol: 0.0,
        pred_tol: 0.0,
        diag_floor: 1e-300,
    };
    let out = match minimize(&mut prob, p, start, &settings) {
        Ok(o) => o,
        Err(e) => match e {},
    };
    out.x
        .iter()
        .all(|v| v.is_finite())
        .then_some((out.x, out.cost, out.iterations))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::bonnet::BonnetTif;
    use crate::tif::{BonnetTifParams, RateField};

    /// `f(x, y)` (mm from the centre) on an `n` x `n` map of `px` pixels centred at (row, col)
    /// `c`.
    fn sampled(n: usize, px: f64, c: (f64, f64), f: impl Fn(f64, f64) -> f64) -> Array2<f64> {
        Array2::from_shape_fn((n, n), |(i, j)| {
            f((j as f64 - c.1) * px, (i as f64 - c.0) * px)
        })
    }

    /// The paper's bonnet at a 0.2 mm offset, and a fit's start near `centre` (row, column).
    fn offset_bonnet(centre: f64) -> (BonnetTifParams, BonnetTif, FitStart) {
        let mut p = BonnetTifParams::paper(10.0);
        p.offset_mm = 0.2;
        let m = BonnetTif::new(&p).unwrap();
        let start = FitStart {
            centre: (centre, centre),
            peak: 9.0,
            a_mm: 3.0,
        };
        (p, m, start)
    }

    /// The bonnet's shape fitted over every pixel of `rate` (pixel `px`, 5 mm window).
    fn fit_all(rate: &Array2<f64>, px: f64, start: FitStart, response: PixelResponse) -> ShapeFit {
        let use_px = Array2::from_elem(rate.dim(), true);
        fit_shape(rate, &use_px, (px, px), start, 5.0, 4, response).unwrap()
    }

    #[test]
    fn recovers_a_hertz_bonnet_from_coarse_pixels() {
        let (p, m, start) = offset_bonnet(12.0);
        let (px, n) = (0.5, 25usize);
        let (uc, vc) = (12.3, 11.6);
        let rate = sampled(n, px, (uc, vc), |x, y| m.rate_at_mm(x, y));
        let f = fit_all(&rate, px, start, PixelResponse::Point);
        let a = p.contact_radius_mm();
        assert!((f.shape.a_mm / a - 1.0).abs() < 1e-4, "{f:?}");
        assert!((f.shape.gamma - 0.5).abs() < 1e-3, "{f:?}");
        assert!((f.centre.0 - uc).abs() < 1e-4 && (f.centre.1 - vc).abs() < 1e-4);
        assert!(f.residual_rms < 1e-4 * f.data_rms, "{f:?}");
    }

    /// The mean of `f` over each pixel of `sampled`'s map, by M x M midpoints (not the fit's
    /// Gauss-Legendre nodes).
    fn pixel_means<const M: usize>(
        n: usize,
        px: f64,
        c: (f64, f64),
        f: impl Fn(f64, f64) -> f64,
    ) -> Array2<f64> {
        sampled(n, px, c, |x, y| {
            let mut s = 0.0;
            for a in 0..M {
                for b in 0..M {
                    let (u, v) = (
                        (b as f64 + 0.5) / M as f64 - 0.5,
                        (a as f64 + 0.5) / M as f64 - 0.5,
                    );
                    s += f(x + u * px, y + v * px);
                }
            }
            s / (M * M) as f64
        })
    }

    #[test]
    fn recovers_a_bonnet_from_pixel_means_when_told_the_pixels_average() {
        // A camera's spot: each pixel the mean over its square. Fitted as point samples the
        // shape comes out wider (the box adds px^2 / 12 to the second moment); fitted as area
        // means it is the bonnet itself.
        let (p, m, start) = offset_bonnet(24.0);
        let (px, n) = (0.25, 49usize);
        let (uc, vc) = (24.3, 23.6);
        let rate = pixel_means::<16>(n, px, (uc, vc), |x, y| m.rate_at_mm(x, y));
        let a = p.contact_radius_mm();
        let area = fit_all(&rate, px, start, PixelResponse::area(px, px));
        let point = fit_all(&rate, px, start, PixelResponse::Point);
        let err_area = (area.shape.a_mm / a - 1.0).abs();
        let err_point = (point.shape.a_mm / a - 1.0).abs();
        assert!(err_area < 2e-4, "area fit a {} vs {a}", area.shape.a_mm);
        assert!(
            err_point > 10.0 * err_area,
            "point {err_point} vs area {err_area}"
        );
        assert!((area.centre.0 - uc).abs() < 1e-3 && (area.centre.1 - vc).abs() < 1e-3);
        assert!(
            area.residual_rms < 0.2 * point.residual_rms,
            "area {} point {}",
            area.residual_rms,
            point.residual_rms
        );
    }

    #[test]
    fn a_camera_spot_off_the_pixels_is_centred_to_1e_4_mm() {
        // Noise-free 0.25 mm pixel means (32 x 32 midpoints each) of the bonnet centred at
        // four places off the pixel grid: the area fit's centre within 1e-4 mm and contact
        // radius within 5e-5. Five Gauss-Legendre nodes per axis on every box put the centre
        // 2-8e-4 mm off (the square-root rim; a path offset of that size in a calibration).
        // Measured with the rim's boxes in 4 x 4 cells: centre errors at most 6.4e-5 mm,
        // radius errors at most 2.8e-5 (with five nodes: 2.4e-4).
        let (p, m, start) = offset_bonnet(24.0);
        let (px, n) = (0.25, 49usize);
        let a = p.contact_radius_mm();
        for c in [(24.3, 23.6), (24.0, 24.0), (24.1, 23.9), (24.05, 24.2)] {
            let rate = pixel_means::<32>(n, px, c, |x, y| m.rate_at_mm(x, y));
            let f = fit_all(&rate, px, start, PixelResponse::area(px, px));
            let (ex, ey) = (f.centre.0 - c.0, f.centre.1 - c.1);
            assert!(
                ex.abs() < 1e-4 && ey.abs() < 1e-4,
                "{c:?}: off by ({ex}, {ey}) mm"
            );
            assert!((f.shape.a_mm / a - 1.0).abs() < 5e-5, "{c:?}: {f:?}");
        }
    }

    #[test]
    fn recovers_a_gaussian_sampled_at_one_pixel_per_sigma() {
        // sigma 0.6 mm at 0.65 mm pixels, centre off the pixels: the smooth shape with beta 1.
        let (px, n) = (0.65, 21usize);
        let (uc, vc) = (10.4, 9.7);
        let g = SmoothShape {
            peak: 10.0,
            sigma_mm: 0.6,
            beta: 1.0,
        };
        let rate = sampled(n, px, (uc, vc), |x, y| g.rate_at(x, y));
        let use_px = Array2::from_elem((n, n), true);
        let start = FitStart {
            centre: (10.0, 10.0),
            peak: 8.0,
            a_mm: 2.6,
        };
        let f = fit_smooth(&rate, &use_px, (px, px), start, 5.0, PixelResponse::Point).unwrap();
        assert!((f.shape.sigma_mm / 0.6 - 1.0).abs() < 1e-5, "{f:?}");
        assert!((f.shape.beta - 1.0).abs() < 1e-5, "{f:?}");
        assert!((f.shape.peak / 10.0 - 1.0).abs() < 1e-5, "{f:?}");
        assert!((f.centre.0 - uc).abs() < 1e-5 && (f.centre.1 - vc).abs() < 1e-5);
        assert!(f.residual_rms < 1e-5 * f.data_rms, "{f:?}");
        // A Gaussian's 1e-6 radius: sigma sqrt(2 ln 1e6).
        let r = f.shape.radius_below(1e-6);
        assert!((r / (0.6 * (2.0 * 1e6f64.ln()).sqrt()) - 1.0).abs() < 1e-4);
        // A flat-topped one (beta 2) from the same start.
        let g2 = SmoothShape { beta: 2.0, ..g };
        let rate2 = sampled(n, px, (uc, vc), |x, y| g2.rate_at(x, y));
        let f2 = fit_smooth(&rate2, &use_px, (px, px), start, 5.0, PixelResponse::Point).unwrap();
        assert!((f2.shape.beta - 2.0).abs() < 1e-4, "{f2:?}");
        assert!((f2.shape.sigma_mm / 0.6 - 1.0).abs() < 1e-4, "{f2:?}");
    }
}
