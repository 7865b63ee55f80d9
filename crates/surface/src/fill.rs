//! Filling the invalid pixels of a map from its valid ones: the one hole fill of the project
//! for maps that must be complete before an interpolation or a convolution (a measured spot's
//! rate, a real map used as a synthetic run's initial surface, a dwell case's target).
//!
//! The fill grows inwards front by front (breadth first over 8-neighbours): every invalid pixel
//! next to a known one takes the mean of its known 8-neighbours, those values become known, and
//! the next front is filled from them. A dropout inside a footprint becomes a smooth patch, not a
//! hole of zero; valid pixels are never changed.

use ndarray::Array2;

/// The 8-neighbours of (i, j) inside an `r` x `c` array, in row-major order.
fn neighbours(i: usize, j: usize, r: usize, c: usize) -> impl Iterator<Item = (usize, usize)> {
    (-1isize..=1)
        .flat_map(|di| (-1isize..=1).map(move |dj| (di, dj)))
        .filter(|&d| d != (0, 0))
        .filter_map(move |(di, dj)| {
            let (a, b) = (i as isize + di, j as isize + dj);
            (a >= 0 && b >= 0 && (a as usize) < r && (b as usize) < c)
                .then_some((a as usize, b as usize))
        })
}

/// `a` with its invalid pixels (where `valid` is false) filled from the valid ones, front by
/// front (see the module docs). Valid pixels keep their values. When no pixel is valid there is
/// nothing to fill from and `a` is returned unchanged (callers that need data check first).
///
/// Panics if `a` and `valid` differ in shape.
pub fn fill_invalid(a: &Array2<f64>, valid: &Array2<bool>) -> Array2<f64> {
    assert_eq!(
        a.dim(),
        valid.dim(),
        "fill_invalid: map and mask differ in shape"
    );
    let (r, c) = a.dim();
    let mut out = a.clone();
    let mut known = valid.clone();
    let mut queued = valid.clone();
    let mut front: Vec<(usize, usize)> = Vec::new();
    for ((i, j), &k) in valid.indexed_iter() {
        if !k && neighbours(i, j, r, c).any(|p| valid[p]) {
            front.push((i, j));
            queued[(i, j)] = true;
        }
    }
    while !front.is_empty() {
        let values: Vec<f64> = front
            .iter()
            .map(|&(i, j)| {
                let (mut s, mut n) = (0.0, 0usize);
                for p in neighbours(i, j, r, c) {
                    if known[p] {
                        s += out[p];
                        n += 1;
                    }
                }
                s / n as f64
            })
            .collect();
        for (&p, v) in front.iter().zip(values) {
            out[p] = v;
            known[p] = true;
        }
        let mut next = Vec::new();
        for &(i, j) in &front {
            for p in neighbours(i, j, r, c) {
                if !queued[p] {
                    queued[p] = true;
                    next.push(p);
                }
            }
        }
        front = next;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_valid_pixels_and_fills_a_plane_hole_exactly() {
        let plane = |i: usize, j: usize| 3.0 + 0.5 * i as f64 - 0.25 * j as f64;
        let a = Array2::from_shape_fn((9, 11), |(i, j)| plane(i, j));
        let mut valid = Array2::from_elem((9, 11), true);
        valid[(4, 5)] = false;
        let mut holed = a.clone();
        holed[(4, 5)] = 0.0;
        let f = fill_invalid(&holed, &valid);
        // The symmetric mean of a plane's eight neighbours is the plane's value.
        assert!((f[(4, 5)] - plane(4, 5)).abs() < 1e-12, "{}", f[(4, 5)]);
        for (p, &ok) in valid.indexed_iter() {
            if ok {
                assert_eq!(f[p], holed[p]);
            }
        }
    }

    #[test]
    fn fills_front_by_front_from_the_nearest_data() {
        // Only the left column is valid: every later column takes the mean of the column before
        // it (its known 8-neighbours), so a column-constant map stays column-constant.
        let mut a = Array2::zeros((5, 6));
        let mut valid = Array2::from_elem((5, 6), false);
        for i in 0..5 {
            a[(i, 0)] = 7.0;
            valid[(i, 0)] = true;
        }
        let f = fill_invalid(&a, &valid);
        assert!(f.iter().all(|&v| (v - 7.0).abs() < 1e-12), "{f:?}");
        // A corner value spreads, and the next front averages two sources.
        let mut b = Array2::zeros((3, 3));
        let mut vb = Array2::from_elem((3, 3), false);
        b[(0, 0)] = 1.0;
        b[(2, 2)] = 3.0;
        vb[(0, 0)] = true;
        vb[(2, 2)] = true;
        let g = fill_invalid(&b, &vb);
        assert_eq!(g[(1, 1)], 2.0);
        assert_eq!(g[(0, 1)], 1.0); // first front: only (0, 0) is known among its neighbours
        assert_eq!(g[(0, 2)], 2.0); // second front: mean of (0, 1), (1, 1), (1, 2)
    }

    #[test]
    fn reaches_every_pixel_within_the_range_of_the_data() {
        let h = Array2::from_shape_fn((9, 9), |(i, j)| (i + j) as f64);
        let valid = Array2::from_shape_fn((9, 9), |(i, j)| {
            (i as i64 - 4).pow(2) + (j as i64 - 4).pow(2) <= 4
        });
        let f = fill_invalid(&h, &valid);
        for (p, &ok) in valid.indexed_iter() {
            if ok {
                assert_eq!(f[p], h[p]);
            }
            // Means of means never leave the range of the valid data (4 ..= 12).
            assert!(
                f[p].is_finite() && (4.0..=12.0).contains(&f[p]),
                "{p:?} {}",
                f[p]
            );
        }
    }

    #[test]
    fn nothing_valid_leaves_the_map_unchanged() {
        let a = Array2::from_elem((3, 4), 2.5);
        let f = fill_invalid(&a, &Array2::from_elem((3, 4), false));
        assert_eq!(f, a);
    }
}
