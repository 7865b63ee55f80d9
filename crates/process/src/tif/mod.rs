//! Tool influence functions (TIFs): the removal rate footprint of the tool at rest, in nm/s.
//!
//! A `Tif` is a sampled rate map on its own grid: odd dimensions, the tool centre at pixel
//! `(rows / 2, cols / 2)`, offsets in mm `(dx, dy) = ((j - cols/2) dx_mm, (i - rows/2) dy_mm)`
//! measured from the tool centre to the point of the surface. Models that can be evaluated
//! anywhere implement [`RateField`]; exact deposition evaluates them at the true offset, the
//! fast path samples them on the map grid.
//!
//! One file per source: [`gaussian`] (truncated disc), [`bonnet`] (precessing bonnet from
//! Preston's law) and [`measured`] (a polished spot on a height map).

pub mod bonnet;
pub mod derived;
pub mod gaussian;
pub mod measured;
pub mod motion;
pub mod spotfit;

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::ProcessError;

pub use bonnet::{BonnetTifParams, PressureProfile, RateScale};
pub use gaussian::GaussianTif;

/// Anything that gives the removal rate (nm/s) at an offset (mm) from the tool centre.
pub trait RateField: Sync {
    /// Rate in nm/s at offset (dx, dy) mm from the tool centre; 0 outside the footprint.
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64;
    /// Half-extent of the footprint (x, y) in mm: the rate is 0 beyond it.
    fn half_extent_mm(&self) -> (f64, f64);
    /// The exact integral of the rate over the plane (nm mm^2 / s), when the model knows it.
    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        None
    }
    /// Rates along one line: `out[k]` is the rate at `(t[k], c)` when `along_x`, else at
    /// `(c, t[k])` (mm). The same values as [`RateField::rate_at_mm`]; the kernel builds ask for
    /// thousands of points of one row or column at a time, and a field can share work between
    /// them (a measured spot interpolates across the line once).
    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        for (o, &v) in out.iter_mut().zip(t) {
            *o = if along_x {
                self.rate_at_mm(v, c)
            } else {
                self.rate_at_mm(c, v)
            };
        }
    }
}

/// A sampled removal-rate map (nm/s), tool centre at the middle pixel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tif {
    pub rate_nm_per_s: Array2<f64>,
    pub dx_mm: f64,
    pub dy_mm: f64,
}

impl Tif {
    /// A TIF from a rate array with odd dimensions and positive pixel size.
    pub fn new(rate_nm_per_s: Array2<f64>, dx_mm: f64, dy_mm: f64) -> Result<Tif, ProcessError> {
        let (r, c) = rate_nm_per_s.dim();
        if r % 2 == 0 || c % 2 == 0 {
            return Err(ProcessError::invalid(format!(
                "TIF dimensions must be odd, got {r} x {c}"
            )));
        }
        if !(dx_mm.is_finite() && dx_mm > 0.0 && dy_mm.is_finite() && dy_mm > 0.0) {
            return Err(ProcessError::invalid("TIF pixel size must be positive"));
        }
        if rate_nm_per_s.iter().any(|v| !v.is_finite()) {
            return Err(ProcessError::invalid("TIF rates must be finite"));
        }
        Ok(Tif {
            rate_nm_per_s,
            dx_mm,
            dy_mm,
        })
    }

    /// Half-widths (rows, columns) of [`Tif::sample`] of `field` at pixel (dx, dy), without
    /// sampling it.
    pub fn sample_half_widths(
        field: &dyn RateField,
        dx_mm: f64,
        dy_mm: f64,
    ) -> Result<(usize, usize), ProcessError> {
        if !(dx_mm.is_finite() && dx_mm > 0.0 && dy_mm.is_finite() && dy_mm > 0.0) {
            return Err(ProcessError::invalid("TIF pixel size must be positive"));
        }
        let (ex, ey) = field.half_extent_mm();
        let h1 = (ex / dx_mm + 1e-9).floor() as usize;
        let h0 = (ey / dy_mm + 1e-9).floor() as usize;
        if h0 > 100_000 || h1 > 100_000 || h0 * h1 > 25_000_000 {
            return Err(ProcessError::invalid(
                "TIF footprint is too large for its pixel size",
            ));
        }
        Ok((h0, h1))
    }

    /// Samples a rate field on a grid of pixel (dx, dy), covering its footprint.
    pub fn sample(field: &dyn RateField, dx_mm: f64, dy_mm: f64) -> Result<Tif, ProcessError> {
        let (h0, h1) = Tif::sample_half_widths(field, dx_mm, dy_mm)?;
        let rate = Array2::from_shape_fn((2 * h0 + 1, 2 * h1 + 1), |(i, j)| {
            field.rate_at_mm(
                (j as f64 - h1 as f64) * dx_mm,
                (i as f64 - h0 as f64) * dy_mm,
            )
        });
        Tif::new(rate, dx_mm, dy_mm)
    }

    /// Samples a rate field like [`Tif::sample`], but pixels cut by the edge of the footprint
    /// (its corners, edge midpoints and centre disagree on being inside) take the mean of
    /// 16 x 16 sub-samples, and the whole is scaled to the model's exact volume when it has one instead of the centre value. A hard edge (truncated
    /// Gaussian, uniform-pressure bonnet) then carries the right area into the sampled TIF, so
    /// the FFT removal matches the exact deposition of the continuous model; pixels fully inside
    /// keep their point value (averaging them would blur the TIF by a box of one pixel).
    pub fn sample_antialiased(
        field: &dyn RateField,
        dx_mm: f64,
        dy_mm: f64,
    ) -> Result<Tif, ProcessError> {
        let mut t = Tif::sample(field, dx_mm, dy_mm)?;
        let (h0, h1) = t.half_widths();
        const N: usize = 16;
        // Grow by one pixel so cells whose centre is just outside the support are included.
        let (g0, g1) = (h0 + 1, h1 + 1);
        let mut rate = Array2::zeros((2 * g0 + 1, 2 * g1 + 1));
        for ((i, j), r) in rate.indexed_iter_mut() {
            let (cx, cy) = (
                (j as f64 - g1 as f64) * dx_mm,
                (i as f64 - g0 as f64) * dy_mm,
            );
            let centre = field.rate_at_mm(cx, cy);
            let probes = [
                (-0.5, -0.5),
                (0.5, -0.5),
                (-0.5, 0.5),
                (0.5, 0.5),
                (0.0, -0.5),
                (0.0, 0.5),
                (-0.5, 0.0),
                (0.5, 0.0),
            ];
            let nonzero = probes
                .iter()
                .filter(|(a, b)| field.rate_at_mm(cx + a * dx_mm, cy + b * dy_mm) != 0.0)
                .count()
                + usize::from(centre != 0.0);
            if nonzero == 0 || nonzero == probes.len() + 1 {
                *r = centre;
                continue;
            }
            let mut sum = 0.0;
            for a in 0..N {
                for b in 0..N {
                    sum += field.rate_at_mm(
                        cx + ((b as f64 + 0.5) / N as f64 - 0.5) * dx_mm,
                        cy + ((a as f64 + 0.5) / N as f64 - 0.5) * dy_mm,
                    );
                }
            }
            *r = sum / (N * N) as f64;
        }
        // Pixel sums of a footprint with a steep edge (a Hertz sqrt profile) miss a few 0.1 % of
        // its volume, which would show as a uniform removal error: match the model's volume.
        if let Some(v) = field.volume_rate_nm_mm2_per_s() {
            let sum = rate.sum() * dx_mm * dy_mm;
            if sum > 0.0 && v > 0.0 {
                rate.mapv_inplace(|r| r * v / sum);
            }
        }
        t.rate_nm_per_s = rate;
        Ok(t)
    }

    /// A Gaussian TIF truncated to a disc of diameter `diameter_mm` (see [`GaussianTif`]).
    pub fn gaussian(
        sigma_mm: f64,
        diameter_mm: f64,
        peak_rate_nm_per_s: f64,
        dx_mm: f64,
        dy_mm: f64,
    ) -> Result<Tif, ProcessError> {
        let g = GaussianTif::new(sigma_mm, diameter_mm, peak_rate_nm_per_s)?;
        Tif::sample(&g, dx_mm, dy_mm)
    }

    /// The precessing-bonnet TIF (see [`bonnet`]).
    pub fn bonnet(p: &BonnetTifParams, dx_mm: f64, dy_mm: f64) -> Result<Tif, ProcessError> {
        let model = bonnet::BonnetTif::new(p)?;
        Tif::sample(&model, dx_mm, dy_mm)
    }

    /// (rows / 2, cols / 2): the half-widths in pixels.
    pub fn half_widths(&self) -> (usize, usize) {
        let (r, c) = self.rate_nm_per_s.dim();
        (r / 2, c / 2)
    }

    /// Peak rate in nm/s.
    pub fn peak_rate_nm_per_s(&self) -> f64 {
        self.rate_nm_per_s.iter().fold(0.0f64, |m, &v| m.max(v))
    }

    /// Volumetric removal rate: integral of the rate over the plane, nm mm^2 / s.
    pub fn volume_rate_nm_mm2_per_s(&self) -> f64 {
        self.rate_nm_per_s.sum() * self.dx_mm * self.dy_mm
    }

    /// Bilinear value at an offset in mm from the centre; 0 outside the sampled window.
    pub fn value_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        let (h0, h1) = self.half_widths();
        let u = dy_mm / self.dy_mm + h0 as f64;
        let v = dx_mm / self.dx_mm + h1 as f64;
        bilinear(&self.rate_nm_per_s, u, v)
    }

    /// Resampled (bilinear) to a new pixel size over the same footprint. Rates are point
    /// values (nm/s), so resampling keeps them; the volume rate is kept up to sampling error.
    pub fn resampled(&self, dx_mm: f64, dy_mm: f64) -> Result<Tif, ProcessError> {
        Tif::sample(self, dx_mm, dy_mm)
    }

    /// The same TIF multiplied by `factor`.
    pub fn scaled(&self, factor: f64) -> Tif {
        Tif {
            rate_nm_per_s: &self.rate_nm_per_s * factor,
            dx_mm: self.dx_mm,
            dy_mm: self.dy_mm,
        }
    }

    /// Centroid (x, y) of the rate in mm relative to the centre pixel.
    pub fn centroid_mm(&self) -> (f64, f64) {
        let (h0, h1) = self.half_widths();
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for ((i, j), &v) in self.rate_nm_per_s.indexed_iter() {
            s += v;
            sx += v * (j as f64 - h1 as f64) * self.dx_mm;
            sy += v * (i as f64 - h0 as f64) * self.dy_mm;
        }
        if s == 0.0 {
            (0.0, 0.0)
        } else {
            (sx / s, sy / s)
        }
    }

    /// Full width at half maximum along X through the centre row, mm (linear interpolation).
    pub fn fwhm_x_mm(&self) -> f64 {
        let (h0, h1) = self.half_widths();
        let row = self.rate_nm_per_s.row(h0);
        let peak = row.iter().fold(0.0f64, |m, &v| m.max(v));
        if peak <= 0.0 {
            return 0.0;
        }
        let half = peak / 2.0;
        let crossing = |dir: isize| -> f64 {
            // Walk outwards from the last pixel at or above half maximum.
            let n = row.len() as isize;
            let mut j = h1 as isize;
            let mut best = j;
            while j >= 0 && j < n {
                if row[j as usize] >= half {
                    best = j;
                }
                j += dir;
            }
            let next = best + dir;
            if next < 0 || next >= n {
                return (best - h1 as isize).abs() as f64;
            }
            let (a, b) = (row[best as usize], row[next as usize]);
            let t = if a != b { (a - half) / (a - b) } else { 0.0 };
            (best - h1 as isize).abs() as f64 + t
        };
        (crossing(1) + crossing(-1)) * self.dx_mm
    }
}

impl RateField for Tif {
    /// Bilinear inside the sampled window, 0 beyond its outer samples (the half-extent), on
    /// every side alike.
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        let (ex, ey) = self.half_extent_mm();
        if dx_mm.abs() > ex * (1.0 + 1e-12) || dy_mm.abs() > ey * (1.0 + 1e-12) {
            return 0.0;
        }
        self.value_at_mm(dx_mm, dy_mm)
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        let (h0, h1) = self.half_widths();
        (h1 as f64 * self.dx_mm, h0 as f64 * self.dy_mm)
    }
}

pub(crate) use crate::interp::bilinear;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_volume_matches_analytic() {
        // 2 pi sigma^2 peak for an untruncated Gaussian (disc radius 6 sigma).
        let t = Tif::gaussian(1.5, 18.0, 4.0, 0.05, 0.05).unwrap();
        let expect = 2.0 * std::f64::consts::PI * 1.5 * 1.5 * 4.0;
        assert!((t.volume_rate_nm_mm2_per_s() / expect - 1.0).abs() < 1e-6);
        assert!((t.peak_rate_nm_per_s() - 4.0).abs() < 1e-12);
        // FWHM = 2 sqrt(2 ln 2) sigma
        let fwhm = 2.0 * (2.0 * 2f64.ln()).sqrt() * 1.5;
        assert!((t.fwhm_x_mm() - fwhm).abs() < 0.01, "{}", t.fwhm_x_mm());
    }

    #[test]
    fn resampling_keeps_volume_and_centre() {
        let t = Tif::gaussian(2.0, 16.0, 1.0, 0.1, 0.1).unwrap();
        let r = t.resampled(0.25, 0.2).unwrap();
        let rel = r.volume_rate_nm_mm2_per_s() / t.volume_rate_nm_mm2_per_s() - 1.0;
        assert!(rel.abs() < 1e-3, "{rel}");
        let (cx, cy) = r.centroid_mm();
        assert!(cx.abs() < 1e-9 && cy.abs() < 1e-9);
        assert!((t.value_at_mm(0.05, 0.0) - (-0.05f64 * 0.05 / 8.0).exp()).abs() < 1e-3);
    }

    #[test]
    fn antialiased_edge_carries_the_disc_area() {
        // A uniform disc of radius 1.3 px: its area is pi 1.69 px^2 whatever the sampling.
        struct Disc;
        impl RateField for Disc {
            fn rate_at_mm(&self, x: f64, y: f64) -> f64 {
                f64::from(u8::from(x * x + y * y <= 1.69))
            }
            fn half_extent_mm(&self) -> (f64, f64) {
                (1.3, 1.3)
            }
        }
        let a = Tif::sample_antialiased(&Disc, 1.0, 1.0)
            .unwrap()
            .volume_rate_nm_mm2_per_s();
        let p = Tif::sample(&Disc, 1.0, 1.0)
            .unwrap()
            .volume_rate_nm_mm2_per_s();
        let exact = std::f64::consts::PI * 1.69;
        assert!((a - exact).abs() < 0.01 * exact, "{a} vs {exact}");
        assert!(
            (p - exact).abs() > 0.05 * exact,
            "point sampling gives 5 pixels: {p}"
        );
    }

    #[test]
    fn rejects_even_dims() {
        assert!(Tif::new(Array2::zeros((2, 3)), 1.0, 1.0).is_err());
    }
}
