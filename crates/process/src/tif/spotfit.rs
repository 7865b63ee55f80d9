//! The precessing-bonnet shape ([`BonnetShape`]) fitted to a measured spot's rate map: centre,
//! centre rate, contact radius, pressure exponent, lever and precession azimuth, by
//! Levenberg-Marquardt on the pixel values (point samples), each step solved by the project's
//! least squares (`bonnetlab_surface::lsq`, QR of the Jacobian with Marquardt's damping rows,
//! never the normal equations).
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

use ndarray::Array2;
use rayon::prelude::*;

use super::bonnet::BonnetShape;
use bonnetlab_surface::lm::{minimize, LmProblem, LmSettings};

/// A fitted shape with its centre and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeFit {
    pub shape: BonnetShape,
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

/// Most pixels a fit evaluates (finer maps are strided evenly).
const MAX_FIT_PIXELS: usize = 12_000;
const NP: usize = 7;

fn shape_of(p: &[f64; NP], steps: usize) -> BonnetShape {
    BonnetShape {
        peak: p[2].exp(),
        a_mm: p[3].exp(),
        gamma: p[4].exp().clamp(0.05, 50.0),
        lever_mm: p[5].exp(),
        psi_rad: p[6],
        steps,
    }
}

/// Fits the shape to `rate` (nm/s) at pixel (dx, dy) mm over the pixels where `use_px` is true
/// within `window_mm` of the start centre. `None` when the fit does not converge to a
/// footprint (non-finite, or a contact radius outside the window).
pub fn fit_shape(
    rate: &Array2<f64>,
    use_px: &Array2<bool>,
    dx: f64,
    dy: f64,
    start: FitStart,
    window_mm: f64,
    steps: usize,
) -> Option<ShapeFit> {
    let (rows, cols) = rate.dim();
    let (u0, v0) = start.centre;
    let n_in = {
        let (h0, h1) = (window_mm / dy, window_mm / dx);
        (std::f64::consts::PI * h0 * h1) as usize + 1
    };
    let stride = ((n_in as f64 / MAX_FIT_PIXELS as f64).sqrt().ceil() as usize).max(1);
    // Pixels of the fit as (x, y) mm relative to the start centre, and their values.
    let mut pts: Vec<(f64, f64, f64)> = Vec::new();
    for i in (0..rows).step_by(stride) {
        for j in (0..cols).step_by(stride) {
            let (x, y) = ((j as f64 - v0) * dx, (i as f64 - u0) * dy);
            if use_px[(i, j)] && x * x + y * y <= window_mm * window_mm {
                pts.push((x, y, rate[(i, j)]));
            }
        }
    }
    if pts.len() < 4 * NP {
        return None;
    }
    let a0 = start.a_mm.max(2.0 * dx.max(dy));
    let mut best: Option<([f64; NP], f64, usize)> = None;
    // Three starting exponents (bell, parabolic, Hertz-like): the best converged fit wins.
    for gamma0 in [0.5, 1.0, 2.0] {
        let p0 = [
            0.0,
            0.0,
            start.peak.max(1e-12).ln(),
            a0.ln(),
            f64::ln(gamma0),
            (2.0 * a0).ln(),
            0.0,
        ];
        if let Some((p, cost, it)) = levenberg_marquardt(&pts, p0, steps, a0, window_mm, 10) {
            if best.as_ref().is_none_or(|b| cost < b.1) {
                best = Some((p, cost, it));
            }
        }
    }
    // The best start carried on to convergence.
    let (p, _, it0) = best?;
    let (p, cost, it1) = levenberg_marquardt(&pts, p, steps, a0, window_mm, 60)?;
    let iterations = it0 + it1;
    let shape = shape_of(&p, steps);
    if !(shape.a_mm > 0.5 * dx.max(dy) && shape.a_mm <= window_mm && shape.peak.is_finite()) {
        return None;
    }
    let n = pts.len() as f64;
    let data_rms = (pts.iter().map(|q| q.2 * q.2).sum::<f64>() / n).sqrt();
    Some(ShapeFit {
        shape,
        centre: (u0 + p[1] / dy, v0 + p[0] / dx),
        residual_rms: (cost / n).sqrt(),
        data_rms,
        pixels: pts.len(),
        iterations,
    })
}

/// Model values at the points for parameters `p`.
fn model(pts: &[(f64, f64, f64)], p: &[f64; NP], steps: usize) -> Vec<f64> {
    let s = shape_of(p, steps);
    let az = s.azimuths();
    pts.par_iter()
        .map(|&(x, y, _)| s.rate_with(x - p[0], y - p[1], &az))
        .collect()
}

fn cost_of(pts: &[(f64, f64, f64)], m: &[f64]) -> f64 {
    pts.iter().zip(m).map(|(q, v)| (q.2 - v).powi(2)).sum()
}

/// The shape fit as the project's one Levenberg-Marquardt driver sees it: residual
/// `model - data` at the fit's pixels, forward-difference Jacobian, trials clamped to the
/// plausible region.
struct ShapeProblem<'a> {
    pts: &'a [(f64, f64, f64)],
    steps: usize,
    a0: f64,
    window: f64,
}

/// An evaluation: the model at the points and the residual `model - data`.
struct Trial {
    m: Vec<f64>,
    r: Vec<f64>,
}

impl ShapeProblem<'_> {
    fn trial(&self, p: &[f64; NP]) -> Trial {
        let m = model(self.pts, p, self.steps);
        let r = m.iter().zip(self.pts).map(|(v, q)| v - q.2).collect();
        Trial { m, r }
    }
}

fn params(x: &[f64]) -> [f64; NP] {
    let mut p = [0.0; NP];
    p.copy_from_slice(x);
    p
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
        // Forward differences: lengths in mm scaled to the footprint, logs and angles absolute.
        let h = [1e-5 * self.a0, 1e-5 * self.a0, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6];
        let p = params(x);
        Ok((0..NP)
            .map(|k| {
                let mut q = p;
                q[k] += h[k];
                let mk = model(self.pts, &q, self.steps);
                mk.iter()
                    .zip(&state.m)
                    .map(|(a, b)| (a - b) / h[k])
                    .collect()
            })
            .collect())
    }

    fn propose(&self, x: &[f64], step: &[f64]) -> Vec<f64> {
        let mut q: Vec<f64> = x.iter().zip(step).map(|(a, d)| a + d).collect();
        // Keep the trial inside the plausible region.
        q[4] = q[4].clamp(0.05f64.ln(), 50f64.ln());
        q[5] = q[5].clamp((0.02 * self.a0).ln(), (200.0 * self.a0).ln());
        q[3] = q[3].min((2.0 * self.window).ln());
        q
    }

    fn evaluate(&mut self, x: &[f64], _current: &Trial) -> Result<Option<Trial>, Self::Error> {
        Ok(Some(self.trial(&params(x))))
    }
}

/// The shape fit from `p` by `surface::lm`: (parameters, cost, iterations).
fn levenberg_marquardt(
    pts: &[(f64, f64, f64)],
    p: [f64; NP],
    steps: usize,
    a0: f64,
    window: f64,
    max_iter: usize,
) -> Option<([f64; NP], f64, usize)> {
    let mut prob = ShapeProblem {
        pts,
        steps,
        a0,
        window,
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
        diag_floor: 1e-300,
    };
    let out = match minimize(&mut prob, p.to_vec(), start, &settings) {
        Ok(o) => o,
        Err(e) => match e {},
    };
    let p = params(&out.x);
    p.iter()
        .all(|v| v.is_finite())
        .then_some((p, out.cost, out.iterations))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::bonnet::BonnetTif;
    use crate::tif::{BonnetTifParams, RateField};

    #[test]
    fn recovers_a_hertz_bonnet_from_coarse_pixels() {
        let mut p = BonnetTifParams::paper(10.0);
        p.offset_mm = 0.2;
        let m = BonnetTif::new(&p).unwrap();
        let (px, n) = (0.5, 25usize);
        let (uc, vc) = (12.3, 11.6);
        let rate = Array2::from_shape_fn((n, n), |(i, j)| {
            m.rate_at_mm((j as f64 - vc) * px, (i as f64 - uc) * px)
        });
        let use_px = Array2::from_elem((n, n), true);
        let start = FitStart {
            centre: (12.0, 12.0),
            peak: 9.0,
            a_mm: 3.0,
        };
        let f = fit_shape(&rate, &use_px, px, px, start, 5.0, 4).unwrap();
        let a = p.contact_radius_mm();
        assert!((f.shape.a_mm / a - 1.0).abs() < 1e-4, "{f:?}");
        assert!((f.shape.gamma - 0.5).abs() < 1e-3, "{f:?}");
        assert!((f.centre.0 - uc).abs() < 1e-4 && (f.centre.1 - vc).abs() < 1e-4);
        assert!(f.residual_rms < 1e-4 * f.data_rms, "{f:?}");
    }
}
