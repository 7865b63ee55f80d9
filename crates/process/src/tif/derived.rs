//! Fields derived from a rate field: the footprint widened by a factor and its derivatives.
//!
//! The calibration and the vibration coupling linearise the removal about a state: a tool
//! displaced by `e` removes `T(r - e) ~ T(r) - e . grad T(r)`, a spot widened by `s` removes
//! `T(r / s)`. Each derivative is itself a rate field (nm/s per mm, or per unit of scale), so
//! the fast removal takes it like any TIF: the same motion kernels, line phases and dwell
//! splatting, and the linearised columns share the forward model's discretisation exactly.
//!
//! Derivatives are central differences of the continuous field with a step `h` (mm, or a
//! relative step of the scale), small against the pixel so the kernel samples the derivative
//! rather than a difference over a pixel; at a footprint's steep edge (a Hertz bonnet's
//! square root) the point values are large but their one-pixel averages along the motion, which
//! the moving kernels use, stay the integral of the derivative.

use std::sync::Arc;

use super::RateField;

/// What a [`Derived`] field gives of its base `T`, widened by `s`: `T_s(x, y) = T(x / s, y / s)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// `T_s` itself.
    Value,
    /// `dT_s / dx` (nm/s per mm).
    Dx,
    /// `dT_s / dy` (nm/s per mm).
    Dy,
    /// `dT_s / ds` (nm/s per unit scale).
    Ds,
}

/// A rate field derived from a shared base field (see the module docs).
#[derive(Clone)]
pub struct Derived {
    base: Arc<dyn RateField + Send>,
    scale: f64,
    channel: Channel,
    step: f64,
}

impl std::fmt::Debug for Derived {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Derived({:?}, scale {}, step {})",
            self.channel, self.scale, self.step
        )
    }
}

impl Derived {
    /// `channel` of `base` widened by `scale` (> 0); `step` is the difference step in mm for
    /// `Dx` / `Dy` and relative to the scale for `Ds` (ignored for `Value`).
    pub fn new(base: Arc<dyn RateField + Send>, scale: f64, channel: Channel, step: f64) -> Self {
        Derived {
            base,
            scale,
            channel,
            step: step.abs().max(1e-9),
        }
    }

    fn value(&self, x: f64, y: f64, s: f64) -> f64 {
        self.base.rate_at_mm(x / s, y / s)
    }
}

impl RateField for Derived {
    fn rate_at_mm(&self, x: f64, y: f64) -> f64 {
        let (s, h) = (self.scale, self.step);
        match self.channel {
            Channel::Value => self.value(x, y, s),
            Channel::Dx => (self.value(x + h, y, s) - self.value(x - h, y, s)) / (2.0 * h),
            Channel::Dy => (self.value(x, y + h, s) - self.value(x, y - h, s)) / (2.0 * h),
            Channel::Ds => {
                let ds = h * s;
                (self.value(x, y, s + ds) - self.value(x, y, s - ds)) / (2.0 * ds)
            }
        }
    }

    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        let (s, h) = (self.scale, self.step);
        // The base along the line at scale `s2`, the line moved by `dc` across and `dt` along.
        let mut buf = Vec::with_capacity(t.len());
        let mut lo = vec![0.0; t.len()];
        let mut base_along = |s2: f64, dc: f64, dt: f64, o: &mut [f64]| {
            buf.clear();
            buf.extend(t.iter().map(|&p| (p + dt) / s2));
            self.base.rates_along(along_x, (c + dc) / s2, &buf, o);
        };
        // (across, along) offsets of the two samples of a difference along x or y.
        let pair = |on_line: bool| {
            if on_line {
                ((0.0, h), (0.0, -h))
            } else {
                ((h, 0.0), (-h, 0.0))
            }
        };
        match self.channel {
            Channel::Value => base_along(s, 0.0, 0.0, out),
            Channel::Dx | Channel::Dy => {
                let ((c1, t1), (c2, t2)) = pair((self.channel == Channel::Dx) == along_x);
                base_along(s, c1, t1, out);
                base_along(s, c2, t2, &mut lo);
                for (o, l) in out.iter_mut().zip(&lo) {
                    *o = (*o - l) / (2.0 * h);
                }
            }
            Channel::Ds => {
                let ds = h * s;
                base_along(s + ds, 0.0, 0.0, out);
                base_along(s - ds, 0.0, 0.0, &mut lo);
                for (o, l) in out.iter_mut().zip(&lo) {
                    *o = (*o - l) / (2.0 * ds);
                }
            }
        }
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        let (ex, ey) = self.base.half_extent_mm();
        let (s, h) = (self.scale, self.step);
        match self.channel {
            Channel::Value => (ex * s, ey * s),
            Channel::Dx => (ex * s + h, ey * s),
            Channel::Dy => (ex * s, ey * s + h),
            Channel::Ds => (ex * s * (1.0 + h), ey * s * (1.0 + h)),
        }
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        match self.channel {
            // The integral of T(r / s) is s^2 times T's; of its derivatives, 0 and 2 s V.
            Channel::Value => self
                .base
                .volume_rate_nm_mm2_per_s()
                .map(|v| v * self.scale * self.scale),
            Channel::Dx | Channel::Dy => Some(0.0),
            Channel::Ds => self
                .base
                .volume_rate_nm_mm2_per_s()
                .map(|v| 2.0 * self.scale * v),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::GaussianTif;

    fn gauss() -> Arc<dyn RateField + Send> {
        Arc::new(GaussianTif::new(1.0, 8.0, 10.0).unwrap())
    }

    #[test]
    fn widened_value_and_derivatives_match_the_closed_form() {
        // T(r) = 10 exp(-r^2 / 2): T_s(x, y) = 10 exp(-(x^2 + y^2) / (2 s^2)).
        let s = 1.3;
        let t = |x: f64, y: f64| 10.0 * (-(x * x + y * y) / (2.0 * s * s)).exp();
        let (x, y) = (0.7, -0.4);
        let v = Derived::new(gauss(), s, Channel::Value, 0.0);
        assert!((v.rate_at_mm(x, y) - t(x, y)).abs() < 1e-12);
        let dx = Derived::new(gauss(), s, Channel::Dx, 1e-4);
        assert!((dx.rate_at_mm(x, y) - (-x / (s * s)) * t(x, y)).abs() < 1e-6);
        let dy = Derived::new(gauss(), s, Channel::Dy, 1e-4);
        assert!((dy.rate_at_mm(x, y) - (-y / (s * s)) * t(x, y)).abs() < 1e-6);
        // dT_s/ds = (r^2 / s^3) T_s
        let ds = Derived::new(gauss(), s, Channel::Ds, 1e-4);
        let r2 = x * x + y * y;
        assert!((ds.rate_at_mm(x, y) - r2 / (s * s * s) * t(x, y)).abs() < 1e-6);
        assert_eq!(v.half_extent_mm(), (4.0 * s, 4.0 * s));
    }
}
