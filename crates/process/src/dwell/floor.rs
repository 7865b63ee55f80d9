//! The dwell floor: a lower bound on the total dwell of any non-negative dwell map that
//! reproduces the desired removal on the clear aperture (CA), up to piston and tilt.
//!
//! Why it holds: with a TIF B >= 0 and a dwell T >= 0 the removal B T is >= 0 everywhere; an
//! exact fit makes it `Z + a + b . (x - x_c)` on the CA (some piston a and tilt b, x_c the CA's
//! centroid), and a unit dwell on one pixel removes at most the TIF volume `vol` (the sum of its
//! samples) summed over the CA's pixels, so, with N the CA's pixel count,
//!
//!   vol sum(T) >= sum_CA (Z + a + b . (x - x_c)) = sum_CA Z + N a,
//!   where Z + a + b . (x - x_c) >= 0 on the CA.
//!
//! The least right-hand side takes the plane `-(a + b . (x - x_c))` as high as it goes under the
//! CA's heights: a = -E, E the lower convex envelope of the points (x, Z) at x_c, and
//!
//!   sum(T) >= (sum_CA Z - N E) / vol.
//!
//! The bound is reached by a TIF narrower than a pixel (a delta: T = (Z - plane) / vol on the CA
//! and 0 elsewhere); a wider TIF spends part of every edge pixel's removal outside the CA and
//! needs more. A dwell solver that holds its total below the floor cannot reach a small residual,
//! whatever its iterations ([`super::min_dwell`] holds the total it starts from).

use super::DwellProblem;

/// The dwell floor of `p` (s, summed over the dwell grid's pixels): see the module docs. 0 when
/// the TIF has a negative sample (B T >= 0 then fails and so does the argument) or removes
/// nothing.
pub fn dwell_floor_s(p: &DwellProblem) -> f64 {
    let rate = &p.tif.rate_nm_per_s;
    if rate.iter().any(|&v| v < 0.0) {
        return 0.0;
    }
    let vol = rate.sum();
    if vol <= 0.0 {
        return 0.0;
    }
    let Some(plane) = EnvelopePlane::of(p) else {
        return 0.0;
    };
    let (n, sum_z) = p
        .desired_nm
        .iter()
        .zip(&p.aperture)
        .filter(|(_, &a)| a)
        .fold((0.0, 0.0), |(n, s), (z, _)| (n + 1.0, s + z));
    ((sum_z - n * plane.at_centroid_nm) / vol).max(0.0)
}

/// The highest plane under the desired removal on the CA (the lower convex envelope's
/// supporting plane at the CA's centroid): `Z - plane >= 0` on the CA with the least sum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopePlane {
    /// CA centroid (row, col), pixels.
    pub centroid: (f64, f64),
    /// The plane's height there (nm).
    pub at_centroid_nm: f64,
    /// Slopes (nm per pixel) along rows and columns.
    pub slope_row: f64,
    pub slope_col: f64,
}

impl EnvelopePlane {
    /// The envelope plane of `p`'s desired removal on its CA (None: an empty CA).
    pub fn of(p: &DwellProblem) -> Option<EnvelopePlane> {
        let pts: Vec<(f64, f64, f64)> = p
            .desired_nm
            .indexed_iter()
            .zip(p.aperture.iter())
            .filter(|(_, &a)| a)
            .map(|(((i, j), &z), _)| (i as f64, j as f64, z))
            .collect();
        if pts.is_empty() {
            return None;
        }
        Some(lower_envelope_at_centroid(&pts))
    }

    /// The plane's height (nm) at pixel (row, col).
    pub fn at(&self, row: f64, col: f64) -> f64 {
        self.at_centroid_nm
            + self.slope_row * (row - self.centroid.0)
            + self.slope_col * (col - self.centroid.1)
    }
}

/// The lower convex envelope of points (row, col, z) at their centroid: the greatest value there
/// of a plane lying under every point. Searched as max over the row slope `b0` of the exact
/// best plane for that slope (a 1-D lower hull over the columns); the best plane's value is
/// concave in `b0`, so a golden-section search finds it.
fn lower_envelope_at_centroid(pts: &[(f64, f64, f64)]) -> EnvelopePlane {
    let n = pts.len() as f64;
    let rc = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let cc = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let (c_lo, c_hi) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.1), hi.max(p.1))
        });
    let c0 = c_lo as usize;
    let ncols = (c_hi - c_lo) as usize + 1;
    let mut col_min = vec![f64::INFINITY; ncols];
    let mut hull: Vec<(f64, f64)> = Vec::with_capacity(ncols);
    // The best plane with row slope b0: the columns' lowest points of z - b0 (row - rc), their
    // lower hull, and its value at cc (and the hull's slope there: the plane's column slope).
    let mut best_for = |b0: f64| -> (f64, f64) {
        col_min.iter_mut().for_each(|m| *m = f64::INFINITY);
        for &(r, c, z) in pts {
            let m = &mut col_min[c as usize - c0];
            *m = m.min(z - b0 * (r - rc));
        }
        hull.clear();
        for (k, &m) in col_min.iter().enumerate() {
            if !m.is_finite() {
                continue;
            }
            let q = ((k + c0) as f64, m);
            while hull.len() >= 2 {
                let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
                // Drop b when it lies on or above the chord a-q.
                if (b.0 - a.0) * (q.1 - a.1) - (b.1 - a.1) * (q.0 - a.0) <= 0.0 {
                    hull.pop();
                } else {
                    break;
                }
            }
            hull.push(q);
        }
        match hull.windows(2).find(|w| w[0].0 <= cc && cc <= w[1].0) {
            Some(w) => {
                let slope = (w[1].1 - w[0].1) / (w[1].0 - w[0].0);
                (w[0].1 + slope * (cc - w[0].0), slope)
            }
            // One column: the centroid is on it.
            None => (hull[0].1, 0.0),
        }
    };
    // Bracket the best slope: widen until the envelope falls off on both sides.
    let range = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.2), hi.max(p.2))
        });
    let mut s = (range.1 - range.0).max(f64::MIN_POSITIVE);
    let at0 = best_for(0.0).0;
    for _ in 0..64 {
        if best_for(s).0 <= at0 && best_for(-s).0 <= at0 {
            break;
        }
        s *= 2.0;
    }
    let (mut lo, mut hi) = (-s, s);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (best_for(x1).0, best_for(x2).0);
    // The best slope seen (the search's points are all planes under the points).
    let mut best = (at0, 0.0);
    for _ in 0..100 {
        for (x, f) in [(x1, f1), (x2, f2)] {
            if f > best.0 {
                best = (f, x);
            }
        }
        if hi - lo <= 1e-12 * s {
            break;
        }
        if f1 < f2 {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = best_for(x2).0;
        } else {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = best_for(x1).0;
        }
    }
    let (value, slope_col) = best_for(best.1);
    EnvelopePlane {
        centroid: (rc, cc),
        at_centroid_nm: value,
        slope_row: best.1,
        slope_col,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::Tif;
    use ndarray::Array2;

    /// Brute force: every plane through three points that lies under all points, its value at
    /// the centroid, the greatest (an LP's optimum is at a vertex).
    fn brute(pts: &[(f64, f64, f64)]) -> f64 {
        let n = pts.len() as f64;
        let rc = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let cc = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let mut best = f64::NEG_INFINITY;
        for a in 0..pts.len() {
            for b in a + 1..pts.len() {
                for c in b + 1..pts.len() {
                    let (p, q, r) = (pts[a], pts[b], pts[c]);
                    // Plane z = u + v row + w col through p, q, r (Cramer).
                    let det = (q.0 - p.0) * (r.1 - p.1) - (r.0 - p.0) * (q.1 - p.1);
                    if det.abs() < 1e-9 {
                        continue;
                    }
                    let v = ((q.2 - p.2) * (r.1 - p.1) - (r.2 - p.2) * (q.1 - p.1)) / det;
                    let w = ((q.0 - p.0) * (r.2 - p.2) - (r.0 - p.0) * (q.2 - p.2)) / det;
                    let u = p.2 - v * p.0 - w * p.1;
                    if pts.iter().all(|s| u + v * s.0 + w * s.1 <= s.2 + 1e-9) {
                        best = best.max(u + v * rc + w * cc);
                    }
                }
            }
        }
        best
    }

    /// Against brute force on a random irregular point set (a clear aperture with holes), and
    /// exact on a plane (envelope = the plane: floor 0).
    #[test]
    fn envelope_matches_brute_force() {
        let mut rng = bonnetlab_surface::rng::Rng::new(3);
        for _ in 0..5 {
            let mut pts = Vec::new();
            for i in 0..6 {
                for j in 0..7 {
                    if rng.uniform() > 0.3 {
                        let z = 3.0 * rng.normal() + 0.4 * i as f64;
                        pts.push((i as f64, j as f64, z));
                    }
                }
            }
            let (e, b) = (lower_envelope_at_centroid(&pts), brute(&pts));
            assert!(
                (e.at_centroid_nm - b).abs() < 1e-9 * (1.0 + b.abs()),
                "{e:?} vs {b}"
            );
            // The plane lies under every point.
            assert!(pts.iter().all(|p| e.at(p.0, p.1) <= p.2 + 1e-9), "{e:?}");
        }
        let plane: Vec<(f64, f64, f64)> = (0..5)
            .flat_map(|i| {
                (0..9).map(move |j| (i as f64, j as f64, 2.0 + 0.7 * i as f64 - 1.3 * j as f64))
            })
            .collect();
        let e = lower_envelope_at_centroid(&plane);
        assert!(
            (e.at_centroid_nm - (2.0 + 0.7 * 2.0 - 1.3 * 4.0)).abs() < 1e-9
                && (e.slope_row - 0.7).abs() < 1e-9
                && (e.slope_col + 1.3).abs() < 1e-9,
            "{e:?}"
        );
    }

    /// A delta TIF reaches the floor: dwell (Z - the envelope's plane) / volume on the CA fits
    /// exactly; on a plane the floor is 0.
    #[test]
    fn floor_of_a_delta_tif_is_the_sum_over_the_envelope() {
        let tif = Tif::new(Array2::from_elem((1, 1), 4.0), 1.0, 1.0).unwrap();
        let z = Array2::from_shape_fn((6, 8), |(i, j)| 10.0 + 2.0 * i as f64 + j as f64);
        let ca = Array2::from_elem((6, 8), true);
        let p = DwellProblem::new(z.clone(), ca.clone(), tif.clone()).unwrap();
        assert!(dwell_floor_s(&p) < 1e-9);
        // A single pit: the envelope is the plane z = 10 (all other points are higher), so the
        // floor is the heights above 10 over the volume.
        let mut z = Array2::from_elem((6, 8), 10.0);
        z[(2, 3)] = 4.0;
        z[(4, 6)] = 13.0;
        let p = DwellProblem::new(z.clone(), ca, tif).unwrap();
        let pts: Vec<_> = z
            .indexed_iter()
            .map(|((i, j), &v)| (i as f64, j as f64, v))
            .collect();
        let e = brute(&pts);
        let want = (z.sum() - 48.0 * e) / 4.0;
        assert!(
            (dwell_floor_s(&p) - want).abs() < 1e-9,
            "{} vs {want}",
            dwell_floor_s(&p)
        );
    }
}
