//! A TIF measured from a fixed-point spot: a height map of a dip polished for `dwell_s` seconds.
//!
//! Steps and conventions:
//! 1. Background: a plane (piston + tilt) fitted by least squares on the border ring (valid
//!    pixels within `ring_fraction` of the smaller map side from the edge, at least 2 pixels),
//!    where the tool never touched; subtracting it removes set-up piston and tilt.
//! 2. Sign: removal = -(height - background), positive where material was removed.
//! 3. Centring: the centroid of the removal above 10 % of its maximum (the threshold keeps the
//!    measurement noise of the flat surround from pulling the centroid).
//! 4. Rate: removal / dwell_s (nm/s).
//! 5. Window: the largest disc around the centroid that stays inside the map, resampled
//!    (bilinear over valid neighbours) onto an odd grid of the target pixel size; the rate is set
//!    to 0 outside that disc.

use ndarray::Array2;

use super::Tif;
use crate::error::ProcessError;
use bonnetlab_surface::Surface;

/// Options of [`tif_from_spot`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpotOptions {
    /// Width of the background ring as a fraction of the smaller map side.
    pub ring_fraction: f64,
    /// Target pixel (dx, dy) in mm; `None` keeps the spot map's pixel.
    pub pixel_mm: Option<(f64, f64)>,
    /// Largest TIF radius kept in mm (`None`: as large as the map allows).
    pub max_radius_mm: Option<f64>,
}

impl Default for SpotOptions {
    fn default() -> Self {
        SpotOptions {
            ring_fraction: 0.1,
            pixel_mm: None,
            max_radius_mm: None,
        }
    }
}

impl Tif {
    /// The removal-rate TIF of a measured spot polished for `dwell_s` seconds (default options).
    pub fn from_spot(spot: &Surface, dwell_s: f64) -> Result<Tif, ProcessError> {
        tif_from_spot(spot, dwell_s, &SpotOptions::default())
    }
}

/// The removal-rate TIF of a measured spot; see the module docs for the steps.
pub fn tif_from_spot(spot: &Surface, dwell_s: f64, o: &SpotOptions) -> Result<Tif, ProcessError> {
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
    let h = spot.heights_nm();
    let valid = spot.valid();
    let ring = ((rows.min(cols) as f64 * o.ring_fraction).round() as usize).max(2);
    let in_ring = |i: usize, j: usize| i < ring || j < ring || i + ring >= rows || j + ring >= cols;
    // Plane fit on the ring: normal equations of [1, x, y] in pixel units (centred).
    let (ci, cj) = (rows as f64 / 2.0, cols as f64 / 2.0);
    let mut ata = [[0.0f64; 3]; 3];
    let mut atb = [0.0f64; 3];
    let mut n_ring = 0usize;
    for ((i, j), &z) in h.indexed_iter() {
        if valid[(i, j)] && in_ring(i, j) {
            let b = [1.0, j as f64 - cj, i as f64 - ci];
            for p in 0..3 {
                for q in 0..3 {
                    ata[p][q] += b[p] * b[q];
                }
                atb[p] += b[p] * z;
            }
            n_ring += 1;
        }
    }
    if n_ring < 3 {
        return Err(ProcessError::Processing(
            "spot map: no valid pixels on the border ring".into(),
        ));
    }
    let coef = solve3(ata, atb).unwrap_or([atb[0] / n_ring as f64, 0.0, 0.0]);
    let removal = Array2::from_shape_fn((rows, cols), |(i, j)| {
        if valid[(i, j)] {
            -(h[(i, j)] - coef[0] - coef[1] * (j as f64 - cj) - coef[2] * (i as f64 - ci))
        } else {
            0.0
        }
    });
    let peak = removal
        .indexed_iter()
        .filter(|(ij, _)| valid[*ij])
        .fold(0.0f64, |m, (_, &v)| m.max(v));
    if peak <= 0.0 {
        return Err(ProcessError::Processing(
            "spot map: no removal found (no dip below the border ring)".into(),
        ));
    }
    let (mut s, mut si, mut sj) = (0.0, 0.0, 0.0);
    for ((i, j), &v) in removal.indexed_iter() {
        if valid[(i, j)] && v > 0.1 * peak {
            s += v;
            si += v * i as f64;
            sj += v * j as f64;
        }
    }
    let (u0, v0) = (si / s, sj / s);
    let x_room = (v0.min(cols as f64 - 1.0 - v0)) * dx;
    let y_room = (u0.min(rows as f64 - 1.0 - u0)) * dy;
    let mut radius = x_room.min(y_room);
    if let Some(m) = o.max_radius_mm {
        radius = radius.min(m);
    }
    let (tdx, tdy) = o.pixel_mm.unwrap_or((dx, dy));
    if !(tdx > 0.0 && tdy > 0.0 && tdx.is_finite() && tdy.is_finite()) {
        return Err(ProcessError::invalid(
            "target TIF pixel size must be positive",
        ));
    }
    let h1 = (radius / tdx).floor() as usize;
    let h0 = (radius / tdy).floor() as usize;
    if h0 == 0 || h1 == 0 {
        return Err(ProcessError::Processing(
            "spot map: the spot touches the map border".into(),
        ));
    }
    if (2 * h0 + 1) * (2 * h1 + 1) > 4 * rows * cols + 64 * 64 {
        return Err(ProcessError::invalid(
            "target TIF pixel is far finer than the spot map",
        ));
    }
    let rate = Array2::from_shape_fn((2 * h0 + 1, 2 * h1 + 1), |(a, b)| {
        let ox = (b as f64 - h1 as f64) * tdx;
        let oy = (a as f64 - h0 as f64) * tdy;
        if ox * ox + oy * oy > radius * radius {
            return 0.0;
        }
        bilinear_valid(&removal, valid, u0 + oy / dy, v0 + ox / dx) / dwell_s
    });
    Tif::new(rate, tdx, tdy)
}

/// Bilinear interpolation using only valid neighbours (weights renormalised); 0 if none.
fn bilinear_valid(a: &Array2<f64>, valid: &Array2<bool>, u: f64, v: f64) -> f64 {
    let (r, c) = a.dim();
    if u < 0.0 || v < 0.0 {
        return 0.0;
    }
    let (i, j) = (u.floor() as usize, v.floor() as usize);
    let (fu, fv) = (u - i as f64, v - j as f64);
    let mut s = 0.0;
    let mut w = 0.0;
    for (ii, jj, ww) in [
        (i, j, (1.0 - fu) * (1.0 - fv)),
        (i, j + 1, (1.0 - fu) * fv),
        (i + 1, j, fu * (1.0 - fv)),
        (i + 1, j + 1, fu * fv),
    ] {
        if ii < r && jj < c && valid[(ii, jj)] && ww > 0.0 {
            s += ww * a[(ii, jj)];
            w += ww;
        }
    }
    if w > 1e-12 {
        s / w
    } else {
        0.0
    }
}

/// Solves a 3x3 system by Cramer's rule; `None` when singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.abs() < 1e-12 * (a[0][0] * a[1][1] * a[2][2]).abs().max(1e-300) {
        return None;
    }
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        *o = det(m) / d;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
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

    #[test]
    fn rejects_flat_map_and_bad_dwell() {
        let s = Surface::new(Array2::zeros((20, 20)), Some(0.1), Some(0.1)).unwrap();
        assert!(Tif::from_spot(&s, 10.0).is_err());
        assert!(Tif::from_spot(&s, 0.0).is_err());
    }
}
