//! The tool influence function as the calibration uses it: a removal-rate map (nm/s) on its own
//! grid, tool centre at pixel (rows / 2, cols / 2), resampled onto the map's pixel pitch as a
//! convolution kernel, optionally widened by a scale factor (`T_s(r) = T(r / s)`), and its
//! derivatives.
//!
//! `from_spot` is a private version of the measured-spot conversion (removal = -(height) after
//! removing the piston of the spot map's border ring, divided by the spot's dwell).

use bonnetlab_surface::Surface;
use ndarray::Array2;

use crate::error::CalibrateError;

#[derive(Debug, Clone, PartialEq)]
pub struct TifMap {
    /// Removal rate, nm/s, tool centre at (rows / 2, cols / 2).
    pub rate_nm_per_s: Array2<f64>,
    pub dx_mm: f64,
    pub dy_mm: f64,
}

impl TifMap {
    pub fn new(rate_nm_per_s: Array2<f64>, dx_mm: f64, dy_mm: f64) -> Result<Self, CalibrateError> {
        if !(dx_mm > 0.0 && dy_mm > 0.0 && dx_mm.is_finite() && dy_mm.is_finite()) {
            return Err(CalibrateError::InvalidInput(
                "TIF pixel size must be positive".into(),
            ));
        }
        if rate_nm_per_s.is_empty() || rate_nm_per_s.iter().any(|v| !v.is_finite()) {
            return Err(CalibrateError::InvalidInput(
                "TIF map is empty or not finite".into(),
            ));
        }
        Ok(TifMap {
            rate_nm_per_s,
            dx_mm,
            dy_mm,
        })
    }

    /// Removal rate from a measured spot: a height map (a dip) polished for `dwell_s` at its
    /// centre pixel. Piston = mean of the valid pixels on the border ring (outermost 10 % of
    /// the shorter side); invalid pixels become 0 rate. Rates below zero are kept (noise).
    pub fn from_spot(spot: &Surface, dwell_s: f64) -> Result<Self, CalibrateError> {
        if !(dwell_s > 0.0 && dwell_s.is_finite()) {
            return Err(CalibrateError::InvalidInput(format!(
                "spot dwell_s must be positive, got {dwell_s}"
            )));
        }
        let (dx, dy) = spot.pixel_mm("a TIF from a measured spot")?;
        let (r, c) = spot.dim();
        let ring = (r.min(c) / 10).max(1);
        let (mut s, mut n) = (0.0, 0usize);
        for i in 0..r {
            for j in 0..c {
                let border = i < ring || j < ring || i + ring >= r || j + ring >= c;
                if let (true, Some(h)) = (border, spot.get(i, j)) {
                    s += h;
                    n += 1;
                }
            }
        }
        if n == 0 {
            return Err(CalibrateError::InvalidInput(
                "the spot map has no valid pixel on its border ring (piston reference)".into(),
            ));
        }
        let piston = s / n as f64;
        let rate = Array2::from_shape_fn((r, c), |(i, j)| match spot.get(i, j) {
            Some(h) => -(h - piston) / dwell_s,
            None => 0.0,
        });
        Self::new(rate, dx, dy)
    }

    /// Peak rate (nm/s).
    pub fn peak(&self) -> f64 {
        self.rate_nm_per_s.iter().cloned().fold(0.0, f64::max)
    }

    /// Value at an offset (mm) from the tool centre by Catmull-Rom bicubic interpolation (exact
    /// at the nodes; O(h^4) error, so a widened spot is not blurred by interpolation); the rate is
    /// 0 outside the map.
    pub fn value_at_mm(&self, x_mm: f64, y_mm: f64) -> f64 {
        let (r, c) = self.rate_nm_per_s.dim();
        let fi = y_mm / self.dy_mm + (r / 2) as f64;
        let fj = x_mm / self.dx_mm + (c / 2) as f64;
        if fi <= -1.0 || fj <= -1.0 || fi >= r as f64 || fj >= c as f64 {
            return 0.0;
        }
        let (i0, j0) = (fi.floor() as isize, fj.floor() as isize);
        let (ti, tj) = (fi - i0 as f64, fj - j0 as f64);
        let w = |t: f64| {
            [
                0.5 * (-t * t * t + 2.0 * t * t - t),
                0.5 * (3.0 * t * t * t - 5.0 * t * t + 2.0),
                0.5 * (-3.0 * t * t * t + 4.0 * t * t + t),
                0.5 * (t * t * t - t * t),
            ]
        };
        let (wi, wj) = (w(ti), w(tj));
        let mut s = 0.0;
        for (a, wa) in wi.iter().enumerate() {
            let ii = i0 - 1 + a as isize;
            if ii < 0 || ii >= r as isize {
                continue;
            }
            for (b, wb) in wj.iter().enumerate() {
                let jj = j0 - 1 + b as isize;
                if jj < 0 || jj >= c as isize {
                    continue;
                }
                s += wa * wb * self.rate_nm_per_s[(ii as usize, jj as usize)];
            }
        }
        s
    }

    /// Support radius (mm): the largest distance from the centre of a pixel whose rate exceeds
    /// `frac` of the peak, taken only over the connected core around the centre's ring so that
    /// isolated noise spikes far out do not inflate it.
    pub fn support_radius_mm(&self, frac: f64) -> f64 {
        let peak = self.peak();
        let (r, c) = self.rate_nm_per_s.dim();
        // Azimuthal profile: max rate per 1-pixel-wide annulus.
        let dmin = self.dx_mm.min(self.dy_mm);
        let nb = ((r.max(c) as f64) * self.dx_mm.max(self.dy_mm) / dmin) as usize + 2;
        let mut prof = vec![0.0f64; nb];
        let mut cnt = vec![0usize; nb];
        for i in 0..r {
            for j in 0..c {
                let x = (j as f64 - (c / 2) as f64) * self.dx_mm;
                let y = (i as f64 - (r / 2) as f64) * self.dy_mm;
                let b = (x.hypot(y) / dmin) as usize;
                if b < nb {
                    prof[b] += self.rate_nm_per_s[(i, j)];
                    cnt[b] += 1;
                }
            }
        }
        let mut last = 0;
        for b in 0..nb {
            if cnt[b] > 0 && prof[b] / cnt[b] as f64 > frac * peak {
                last = b;
            } else if cnt[b] > 0 && b > last + 3 {
                break;
            }
        }
        (last as f64 + 1.0) * dmin
    }

    /// Zeroes the rate outside `radius_mm` (measurement noise beyond the spot is not removal).
    pub fn cropped_to_radius(&self, radius_mm: f64) -> TifMap {
        let (r, c) = self.rate_nm_per_s.dim();
        let rate = Array2::from_shape_fn((r, c), |(i, j)| {
            let x = (j as f64 - (c / 2) as f64) * self.dx_mm;
            let y = (i as f64 - (r / 2) as f64) * self.dy_mm;
            if x.hypot(y) <= radius_mm {
                self.rate_nm_per_s[(i, j)]
            } else {
                0.0
            }
        });
        TifMap {
            rate_nm_per_s: rate,
            dx_mm: self.dx_mm,
            dy_mm: self.dy_mm,
        }
    }

    /// Kernel `(2 hr + 1) x (2 hc + 1)` on pitch (dx, dy), of the spot widened by `scale`:
    /// `K(x) = T(x / scale)`.
    pub fn kernel(&self, dx_mm: f64, dy_mm: f64, hr: usize, hc: usize, scale: f64) -> Array2<f64> {
        Array2::from_shape_fn((2 * hr + 1, 2 * hc + 1), |(a, b)| {
            let y = (a as f64 - hr as f64) * dy_mm / scale;
            let x = (b as f64 - hc as f64) * dx_mm / scale;
            self.value_at_mm(x, y)
        })
    }
}

/// Central-difference derivatives (per mm) of a kernel along x (columns) and y (rows).
pub fn kernel_gradient(k: &Array2<f64>, dx_mm: f64, dy_mm: f64) -> (Array2<f64>, Array2<f64>) {
    let (r, c) = k.dim();
    let at = |i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i as usize >= r || j as usize >= c {
            0.0
        } else {
            k[(i as usize, j as usize)]
        }
    };
    let gx = Array2::from_shape_fn((r, c), |(i, j)| {
        (at(i as isize, j as isize + 1) - at(i as isize, j as isize - 1)) / (2.0 * dx_mm)
    });
    let gy = Array2::from_shape_fn((r, c), |(i, j)| {
        (at(i as isize + 1, j as isize) - at(i as isize - 1, j as isize)) / (2.0 * dy_mm)
    });
    (gx, gy)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gauss(n: usize, d: f64, sigma: f64) -> TifMap {
        let h = (n / 2) as f64;
        let a = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = ((j as f64 - h) * d, (i as f64 - h) * d);
            10.0 * (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
        });
        TifMap::new(a, d, d).unwrap()
    }

    #[test]
    fn spot_conversion_and_scaling() {
        let t = gauss(81, 0.25, 1.5);
        // A spot = piston 7 nm minus 30 s of removal.
        let h = t.rate_nm_per_s.mapv(|v| 7.0 - 30.0 * v);
        let spot = Surface::new(h, Some(0.25), Some(0.25)).unwrap();
        let back = TifMap::from_spot(&spot, 30.0).unwrap();
        assert!((back.peak() - 10.0).abs() < 1e-3, "{}", back.peak());
        // scale 2: value at 2 mm equals the original's value at 1 mm
        let k = t.kernel(0.25, 0.25, 12, 12, 2.0);
        assert!((k[(12, 20)] - t.value_at_mm(1.0, 0.0)).abs() < 1e-12);
        let r = t.support_radius_mm(0.01);
        assert!((r - 1.5 * (2.0f64 * 100f64.ln()).sqrt()).abs() < 0.5, "{r}");
    }

    #[test]
    fn gradient_of_a_linear_ramp_is_its_slope() {
        let k = Array2::from_shape_fn((5, 5), |(i, j)| 2.0 * j as f64 - 3.0 * i as f64);
        let (gx, gy) = kernel_gradient(&k, 0.5, 0.25);
        assert!((gx[(2, 2)] - 4.0).abs() < 1e-12);
        assert!((gy[(2, 2)] + 12.0).abs() < 1e-12);
    }
}
