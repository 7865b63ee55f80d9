//! Fields derived from a rate field: the footprint widened by a factor, at a changed offset,
//! and its derivatives.
//!
//! The calibration and the vibration coupling linearise the removal about a state: a tool
//! displaced by `e` removes `T(r - e) ~ T(r) - e . grad T(r) + (e . grad)^2 T(r) / 2`, a spot
//! widened by `s` removes `T(r / s)`, a bonnet pressed deeper by `δ` removes `T(r; δ)`. Each
//! derivative is itself a rate field (nm/s per mm, per mm², or per unit of scale), so the fast
//! removal takes it like any TIF: the same motion kernels, line phases and dwell splatting, and
//! the linearised columns (the calibration's) and weighted dwell channels (the vibration
//! coupling's: dwell times `-u`, `u²/2`, `δ`, `δ²/2`, `-u δ`) share the forward model's
//! discretisation exactly.
//!
//! Offset law ([`OffsetLaw`]): a bonnet of radius R at nominal offset h0 has the contact radius
//! a(h) = sqrt(2 R h - h²); at an offset changed by δ the footprint keeps its shape scaled by
//! a(h0 + δ) / a0 and its peak rate scales as ((h0 + δ) / h0)^γ:
//! `T(q; δ) = ((h0 + δ) / h0)^γ · T_s(q · a0 / a(h0 + δ))`. A field without an offset law does not
//! depend on the offset, so its offset derivatives are zero.
//!
//! Derivatives are central differences of the continuous field with a step `h` (mm, or a
//! relative step of the scale; the offset step is the law's), small against the pixel so the
//! kernel samples the derivative rather than a difference over a pixel; at a footprint's steep
//! edge (a Hertz bonnet's square root) the point values are large but their one-pixel averages
//! along the motion, which the moving kernels use, stay the integral of the derivative.

use std::sync::Arc;

use super::RateField;

/// What a [`Derived`] field gives of its base `T`, widened by `s` and at offset change `δ`:
/// `T_s(x, y; δ)` (see the module docs; `δ` = 0 unless the field has an [`OffsetLaw`]).
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
    /// `d²T_s / dx²` (nm/s per mm²).
    Dxx,
    /// `d²T_s / dy²` (nm/s per mm²).
    Dyy,
    /// `dT_s / dδ` (nm/s per mm of offset).
    Dh,
    /// `d²T_s / dδ²` (nm/s per mm² of offset).
    Dhh,
    /// `d²T_s / dx dδ` (nm/s per mm²).
    Dxh,
    /// `d²T_s / dy dδ` (nm/s per mm²).
    Dyh,
}

impl Channel {
    /// Every channel, in the order of [`Channel::index`].
    pub const ALL: [Channel; 10] = [
        Channel::Value,
        Channel::Dx,
        Channel::Dy,
        Channel::Ds,
        Channel::Dxx,
        Channel::Dyy,
        Channel::Dh,
        Channel::Dhh,
        Channel::Dxh,
        Channel::Dyh,
    ];

    /// Position in [`Channel::ALL`] (a slot index for workspaces kept per channel).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The first lateral derivative along x (`true`) or y, and the second, and the mixed one
    /// with the offset.
    pub fn lateral(along_x: bool) -> (Channel, Channel, Channel) {
        if along_x {
            (Channel::Dx, Channel::Dxx, Channel::Dxh)
        } else {
            (Channel::Dy, Channel::Dyy, Channel::Dyh)
        }
    }
}

/// How a bonnet's footprint changes with its offset (see the module docs). Units: mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetLaw {
    h0_mm: f64,
    radius_mm: f64,
    gamma: f64,
    a0_mm: f64,
    /// Difference step of the offset derivatives, mm.
    step_mm: f64,
}

/// Default offset difference step, as a fraction of h0: the second difference's relative error
/// is O(step²) (4e-4 at 2 %), its rounding error stays below 1e-10.
const OFFSET_STEP: f64 = 0.02;

impl OffsetLaw {
    /// The law of a bonnet of radius `radius_mm` at nominal offset `h0_mm` (0 < h0 < 2 R) with
    /// pressure exponent `gamma`; `None` when the geometry is not valid.
    pub fn new(h0_mm: f64, radius_mm: f64, gamma: f64) -> Option<OffsetLaw> {
        let ok = h0_mm.is_finite()
            && radius_mm.is_finite()
            && gamma.is_finite()
            && h0_mm > 0.0
            && h0_mm < 2.0 * radius_mm;
        ok.then(|| OffsetLaw {
            h0_mm,
            radius_mm,
            gamma,
            a0_mm: (2.0 * radius_mm * h0_mm - h0_mm * h0_mm).sqrt(),
            step_mm: OFFSET_STEP * h0_mm,
        })
    }

    /// Nominal offset h0, mm.
    pub fn h0_mm(&self) -> f64 {
        self.h0_mm
    }

    /// Offset difference step of the derivative channels, mm.
    pub fn step_mm(&self) -> f64 {
        self.step_mm
    }

    /// (rate factor, footprint scale) at offset change `delta_mm`: `((h0 + δ) / h0)^γ` and
    /// `a(h0 + δ) / a0` (the offset clamped to (0, R]: a bonnet lifted off removes nothing).
    pub fn factors(&self, delta_mm: f64) -> (f64, f64) {
        let h = self.h0_mm + delta_mm;
        if h <= 0.0 {
            return (0.0, 1e-9);
        }
        let h = h.min(self.radius_mm);
        let a = (2.0 * self.radius_mm * h - h * h).sqrt();
        (
            (h / self.h0_mm).powf(self.gamma),
            (a / self.a0_mm).max(1e-9),
        )
    }
}

/// A rate field derived from a shared base field (see the module docs).
#[derive(Clone)]
pub struct Derived {
    base: Arc<dyn RateField + Send>,
    scale: f64,
    channel: Channel,
    step: f64,
    offset: Option<OffsetLaw>,
}

impl std::fmt::Debug for Derived {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Derived({:?}, scale {}, step {}, offset law {:?})",
            self.channel, self.scale, self.step, self.offset
        )
    }
}

impl Derived {
    /// `channel` of `base` widened by `scale` (> 0); `step` is the difference step in mm for
    /// the lateral derivatives and relative to the scale for `Ds` (ignored for `Value`).
    pub fn new(base: Arc<dyn RateField + Send>, scale: f64, channel: Channel, step: f64) -> Self {
        Derived {
            base,
            scale,
            channel,
            step: step.abs().max(1e-9),
            offset: None,
        }
    }

    /// The same channel of a bonnet whose footprint follows `law` with the offset.
    pub fn with_offset(mut self, law: OffsetLaw) -> Self {
        self.offset = Some(law);
        self
    }

    /// `T_s(x, y; δ)`.
    fn value(&self, x: f64, y: f64, s: f64, delta: f64) -> f64 {
        match &self.offset {
            None => self.base.rate_at_mm(x / s, y / s),
            Some(law) if delta != 0.0 => {
                let (f, sc) = law.factors(delta);
                let w = s * sc;
                f * self.base.rate_at_mm(x / w, y / w)
            }
            Some(_) => self.base.rate_at_mm(x / s, y / s),
        }
    }

    /// Offset difference step (mm; 1 without a law, where the field does not depend on it).
    fn offset_step(&self) -> f64 {
        self.offset.map_or(1.0, |l| l.step_mm)
    }

    /// `dT_s / dδ` at (x, y).
    fn d_offset(&self, x: f64, y: f64, s: f64) -> f64 {
        let e = self.offset_step();
        (self.value(x, y, s, e) - self.value(x, y, s, -e)) / (2.0 * e)
    }

    /// Footprint scale at the largest offset change the channel evaluates.
    fn offset_widening(&self) -> f64 {
        match (&self.offset, self.channel) {
            (Some(law), Channel::Dh | Channel::Dhh | Channel::Dxh | Channel::Dyh) => {
                law.factors(law.step_mm).1.max(1.0)
            }
            _ => 1.0,
        }
    }
}

impl RateField for Derived {
    fn rate_at_mm(&self, x: f64, y: f64) -> f64 {
        let (s, h) = (self.scale, self.step);
        let v = |x: f64, y: f64| self.value(x, y, s, 0.0);
        match self.channel {
            Channel::Value => v(x, y),
            Channel::Dx => (v(x + h, y) - v(x - h, y)) / (2.0 * h),
            Channel::Dy => (v(x, y + h) - v(x, y - h)) / (2.0 * h),
            Channel::Ds => {
                let ds = h * s;
                (self.value(x, y, s + ds, 0.0) - self.value(x, y, s - ds, 0.0)) / (2.0 * ds)
            }
            Channel::Dxx => (v(x + h, y) - 2.0 * v(x, y) + v(x - h, y)) / (h * h),
            Channel::Dyy => (v(x, y + h) - 2.0 * v(x, y) + v(x, y - h)) / (h * h),
            Channel::Dh => self.d_offset(x, y, s),
            Channel::Dhh => {
                let e = self.offset_step();
                (self.value(x, y, s, e) - 2.0 * v(x, y) + self.value(x, y, s, -e)) / (e * e)
            }
            Channel::Dxh => (self.d_offset(x + h, y, s) - self.d_offset(x - h, y, s)) / (2.0 * h),
            Channel::Dyh => (self.d_offset(x, y + h, s) - self.d_offset(x, y - h, s)) / (2.0 * h),
        }
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        let (ex, ey) = self.base.half_extent_mm();
        let (s, h) = (self.scale, self.step);
        let w = s * self.offset_widening();
        match self.channel {
            Channel::Value => (ex * s, ey * s),
            Channel::Dx | Channel::Dxx => (ex * s + h, ey * s),
            Channel::Dy | Channel::Dyy => (ex * s, ey * s + h),
            Channel::Ds => (ex * s * (1.0 + h), ey * s * (1.0 + h)),
            Channel::Dh | Channel::Dhh => (ex * w, ey * w),
            Channel::Dxh => (ex * w + h, ey * w),
            Channel::Dyh => (ex * w, ey * w + h),
        }
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        // The integral of T(r / s; δ) is f(δ) (s sc(δ))² times T's; of its lateral derivatives
        // 0; of the others the same differences of that scalar.
        let v0 = self.base.volume_rate_nm_mm2_per_s()?;
        let s = self.scale;
        let vol = |s: f64, d: f64| match &self.offset {
            Some(law) => {
                let (f, sc) = law.factors(d);
                f * (s * sc).powi(2) * v0
            }
            None => s * s * v0,
        };
        let e = self.offset_step();
        Some(match self.channel {
            Channel::Value => vol(s, 0.0),
            Channel::Dx | Channel::Dy | Channel::Dxx | Channel::Dyy => 0.0,
            Channel::Dxh | Channel::Dyh => 0.0,
            Channel::Ds => 2.0 * s * v0,
            Channel::Dh => (vol(s, e) - vol(s, -e)) / (2.0 * e),
            Channel::Dhh => (vol(s, e) - 2.0 * vol(s, 0.0) + vol(s, -e)) / (e * e),
        })
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

    #[test]
    fn second_order_and_offset_channels_match_the_closed_form() {
        // T(r; δ) = f(δ) 10 exp(-r² / (2 (s sc(δ))²)), f = ((h0 + δ) / h0)^γ,
        // sc = a(h0 + δ) / a0: dT/dδ = T (γ / h0 + r² sc' / s²) at δ = 0, sc' = (R - h0) / a0².
        let (s, h0, r, gamma) = (1.3, 0.6, 20.0, 0.7);
        let law = OffsetLaw::new(h0, r, gamma).unwrap();
        let a0sq = 2.0 * r * h0 - h0 * h0;
        let t = |x: f64, y: f64| 10.0 * (-(x * x + y * y) / (2.0 * s * s)).exp();
        let (x, y) = (0.7, -0.4);
        let ch = |c: Channel| Derived::new(gauss(), s, c, 1e-3).with_offset(law);
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
        let dxx = (x * x / s.powi(4) - 1.0 / (s * s)) * t(x, y);
        assert!(rel(ch(Channel::Dxx).rate_at_mm(x, y), dxx) < 1e-5);
        let dyy = (y * y / s.powi(4) - 1.0 / (s * s)) * t(x, y);
        assert!(rel(ch(Channel::Dyy).rate_at_mm(x, y), dyy) < 1e-5);
        let r2 = x * x + y * y;
        let dh = t(x, y) * (gamma / h0 + r2 * (r - h0) / a0sq / (s * s));
        assert!(rel(ch(Channel::Dh).rate_at_mm(x, y), dh) < 1e-3);
        // The mixed and second offset derivatives against differences of the closed form at a
        // ten times smaller offset step.
        let closed = |x: f64, y: f64, d: f64| {
            let (f, sc) = law.factors(d);
            f * 10.0 * (-(x * x + y * y) / (2.0 * (s * sc).powi(2))).exp()
        };
        let e = 0.002 * h0;
        let dhh = (closed(x, y, e) - 2.0 * closed(x, y, 0.0) + closed(x, y, -e)) / (e * e);
        assert!(rel(ch(Channel::Dhh).rate_at_mm(x, y), dhh) < 2e-3);
        let dxh = -x / (s * s) * dh + t(x, y) * 2.0 * x * (r - h0) / a0sq / (s * s);
        assert!(rel(ch(Channel::Dxh).rate_at_mm(x, y), dxh) < 1e-3);
        // Volumes: the offset channels' are the derivatives of f(δ) (s sc(δ))² V.
        let v = |d: f64| {
            let (f, sc) = law.factors(d);
            f * (s * sc).powi(2) * 10.0 * 2.0 * std::f64::consts::PI
        };
        let ee = 1e-5;
        let dv = (v(ee) - v(-ee)) / (2.0 * ee);
        let got = ch(Channel::Dh).volume_rate_nm_mm2_per_s().unwrap();
        assert!(rel(got, dv) < 1e-3, "{got} vs {dv}");
        // Without an offset law the field does not depend on the offset.
        let plain = Derived::new(gauss(), s, Channel::Dh, 1e-3);
        assert_eq!(plain.rate_at_mm(x, y), 0.0);
        assert_eq!(
            Channel::ALL.map(Channel::index),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
        );
    }
}
