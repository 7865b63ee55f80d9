//! Locating a spot on its removal map: the smoothed maximum, the removal-weighted centroid and
//! the sub-pixel peak from a local paraboloid fit.
//!
//! The paraboloid `z = c0 + c1 u + c2 v + c3 u^2 + c4 u v + c5 v^2` is fitted by least squares
//! to the valid pixels removed by at least `TOP_FRACTION` of the smoothed peak within
//! `radius_mm` of the starting point, then again on the pixels above `REFINE_FRACTION` of the
//! first peak about the first vertex; its vertex is the spot centre and its value there the peak
//! removal, when the fit is concave and the vertex lies inside the fitted region. Otherwise
//! (flat-topped or ring-shaped spots) the caller falls back to the centroid and the smoothed
//! maximum.

use serde::{Deserialize, Serialize};

use bonnetlab_surface::Surface;

use bonnetlab_surface::lsq::{solve_from_r, StreamingQr};

/// Pixels at or above this fraction of the smoothed peak enter the first paraboloid fit.
pub const TOP_FRACTION: f64 = 0.85;
/// The second fit, about the first vertex, keeps the pixels above this fraction of the first
/// peak: a smaller cap moves the vertex less towards the wide side of a lopsided spot.
pub const REFINE_FRACTION: f64 = 0.92;

/// How the centre and peak were found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CentreMethod {
    /// Vertex of the local paraboloid fit.
    #[default]
    Paraboloid,
    /// Removal-weighted centroid; peak = smoothed maximum (the paraboloid was not concave).
    Centroid,
}

/// The maximum of the 3 x 3 mean of the valid removal (noise-robust start point):
/// (row, col, value).
pub fn smoothed_max(removal: &Surface) -> Option<(usize, usize, f64)> {
    let (rows, cols) = removal.dim();
    let mut best: Option<(usize, usize, f64)> = None;
    for i in 0..rows {
        for j in 0..cols {
            if removal.get(i, j).is_none() {
                continue;
            }
            let (mut s, mut n) = (0.0, 0usize);
            for ii in i.saturating_sub(1)..(i + 2).min(rows) {
                for jj in j.saturating_sub(1)..(j + 2).min(cols) {
                    if let Some(v) = removal.get(ii, jj) {
                        s += v;
                        n += 1;
                    }
                }
            }
            let m = s / n as f64;
            if best.is_none_or(|b| m > b.2) {
                best = Some((i, j, m));
            }
        }
    }
    best
}

/// Removal-weighted centroid (mm) of the valid pixels with removal >= `threshold_nm` inside the
/// disc of `radius_mm` about `(cx, cy)`, and the number of pixels used.
pub fn centroid(
    removal: &Surface,
    threshold_nm: f64,
    (cx, cy): (f64, f64),
    radius_mm: f64,
) -> Option<(f64, f64, usize)> {
    let (mut sw, mut sx, mut sy, mut n) = (0.0, 0.0, 0.0, 0usize);
    for ((i, j), &v) in removal.heights_nm().indexed_iter() {
        if !removal.valid()[(i, j)] || v < threshold_nm {
            continue;
        }
        let (x, y) = (removal.x_mm(j), removal.y_mm(i));
        if (x - cx).hypot(y - cy) > radius_mm {
            continue;
        }
        sw += v;
        sx += v * x;
        sy += v * y;
        n += 1;
    }
    (sw > 0.0).then(|| (sx / sw, sy / sw, n))
}

/// Sub-pixel peak from the paraboloid fit: (x_mm, y_mm, peak_nm, pixels used), or `None` when
/// the fit is not a concave cap whose vertex lies in the fitted region.
pub fn paraboloid_peak(
    removal: &Surface,
    (cx, cy): (f64, f64),
    radius_mm: f64,
    threshold_nm: f64,
) -> Option<(f64, f64, f64, usize)> {
    let mut rows: Vec<([f64; 6], f64)> = Vec::new();
    let mut reach = 0.0f64;
    for ((i, j), &v) in removal.heights_nm().indexed_iter() {
        if !removal.valid()[(i, j)] || v < threshold_nm {
            continue;
        }
        let (u, w) = (removal.x_mm(j) - cx, removal.y_mm(i) - cy);
        let r = u.hypot(w);
        if r > radius_mm {
            continue;
        }
        reach = reach.max(r);
        rows.push(([1.0, u, w, u * u, u * w, w * w], v));
    }
    if rows.len() < 12 {
        return None;
    }
    // Least squares by the project's QR (`bonnetlab_surface::lsq`, no normal equations); a
    // degenerate set of pixels (a basis column dependent on the others) gives no vertex.
    let mut qr = StreamingQr::new(7);
    for (r, y) in &rows {
        let mut row = [0.0; 7];
        row[..6].copy_from_slice(r);
        row[6] = *y;
        qr.push_row(&row);
    }
    let sol = solve_from_r(&qr.finish(), 7);
    if !sol.dropped.is_empty() || sol.coefficients.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let c = sol.coefficients;
    // Concave: the Hessian [[2c3, c4], [c4, 2c5]] is negative definite.
    let (a, b, d) = (2.0 * c[3], c[4], 2.0 * c[5]);
    if !(a < 0.0 && a * d - b * b > 0.0) {
        return None;
    }
    let det = a * d - b * b;
    let u0 = (-c[1] * d + c[2] * b) / det;
    let w0 = (-c[2] * a + c[1] * b) / det;
    if u0.hypot(w0) > reach {
        return None;
    }
    let peak = c[0] + c[1] * u0 + c[2] * w0 + c[3] * u0 * u0 + c[4] * u0 * w0 + c[5] * w0 * w0;
    Some((cx + u0, cy + w0, peak, rows.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    fn cap(x0: f64, y0: f64) -> Surface {
        let dx = 0.1;
        let z = Array2::from_shape_fn((101, 121), |(i, j)| {
            let (x, y) = (j as f64 * dx - x0, i as f64 * dx - y0);
            (100.0 - 20.0 * x * x - 10.0 * y * y - 4.0 * x * y).max(0.0)
        });
        Surface::new(z, Some(dx), Some(dx)).unwrap()
    }

    #[test]
    fn paraboloid_vertex_is_exact_on_a_paraboloid() {
        let s = cap(6.037, 4.981);
        let (i, j, _) = smoothed_max(&s).unwrap();
        let (x, y, p, n) = paraboloid_peak(&s, (s.x_mm(j), s.y_mm(i)), 1.5, 0.85 * 100.0).unwrap();
        assert!(n > 12);
        assert!(
            (x - 6.037).abs() < 1e-9 && (y - 4.981).abs() < 1e-9,
            "{x} {y}"
        );
        assert!((p - 100.0).abs() < 1e-9);
    }

    #[test]
    fn centroid_of_a_symmetric_cap_is_its_centre_and_convex_data_is_rejected() {
        // The cap is centro-symmetric about its vertex, so the centroid is the vertex.
        let s = cap(6.0, 5.0);
        let (x, y, _) = centroid(&s, 1.0, (6.0, 5.0), 4.0).unwrap();
        assert!((x - 6.0).abs() < 1e-9 && (y - 5.0).abs() < 1e-9, "{x} {y}");
        let bowl = s.with_heights(s.heights_nm().mapv(|v| 200.0 - v)).unwrap();
        assert!(paraboloid_peak(&bowl, (6.0, 5.0), 1.5, 0.0).is_none());
    }
}
