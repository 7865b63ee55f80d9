//! Interpolation of sampled maps at fractional (row, column) positions: the one place the
//! project interpolates a grid (bilinear for a sampled TIF, clamped for a hole-free map sampled
//! along a path, masked for a map with dropouts; Catmull-Rom bicubic and band-limited
//! upsampling for a measured spot). Positions are in pixels of the array (row u, column v);
//! outside the array the value is 0 (a footprint is zero beyond its samples) unless a
//! function says otherwise.

use ndarray::Array2;

use crate::fft::{Complex, Fft2};

/// Bilinear interpolation of `a` at fractional (row u, col v); 0 outside.
pub fn bilinear(a: &Array2<f64>, u: f64, v: f64) -> f64 {
    let (r, c) = a.dim();
    if !(u.is_finite() && v.is_finite()) || u < 0.0 || v < 0.0 {
        return 0.0;
    }
    let (i, j) = (u.floor() as usize, v.floor() as usize);
    if i >= r || j >= c {
        return 0.0;
    }
    let (fu, fv) = (u - i as f64, v - j as f64);
    let at = |ii: usize, jj: usize| if ii < r && jj < c { a[(ii, jj)] } else { 0.0 };
    (1.0 - fu) * ((1.0 - fv) * at(i, j) + fv * at(i, j + 1))
        + fu * ((1.0 - fv) * at(i + 1, j) + fv * at(i + 1, j + 1))
}

/// Bilinear interpolation of `a` at fractional (row u, col v) of a map that repeats with the
/// array's extent (a periodic field, such as one made by an inverse FFT); 0 for a non-finite
/// position or an empty array.
pub fn bilinear_periodic(a: &Array2<f64>, u: f64, v: f64) -> f64 {
    let (r, c) = a.dim();
    if r == 0 || c == 0 || !(u.is_finite() && v.is_finite()) {
        return 0.0;
    }
    let (i0, j0) = (u.floor(), v.floor());
    let (fu, fv) = (u - i0, v - j0);
    let wrap = |k: f64, n: usize| (k as i64).rem_euclid(n as i64) as usize;
    let (ia, ib) = (wrap(i0, r), wrap(i0 + 1.0, r));
    let (ja, jb) = (wrap(j0, c), wrap(j0 + 1.0, c));
    (1.0 - fu) * ((1.0 - fv) * a[(ia, ja)] + fv * a[(ia, jb)])
        + fu * ((1.0 - fv) * a[(ib, ja)] + fv * a[(ib, jb)])
}

/// Bilinear interpolation of `a` at fractional (row u, col v) with the position clamped to the
/// array (a hole-free map sampled at the part edge takes its border values, never 0).
pub fn bilinear_clamped(a: &Array2<f64>, u: f64, v: f64) -> f64 {
    let (r, c) = a.dim();
    if r == 0 || c == 0 {
        return 0.0;
    }
    bilinear(
        a,
        u.clamp(0.0, (r - 1) as f64),
        v.clamp(0.0, (c - 1) as f64),
    )
}

/// Bilinear interpolation of a masked map at fractional (row u, col v): `None` outside the
/// array or when a pixel the value depends on (a neighbour with a non-zero weight) is invalid.
pub fn bilinear_masked(a: &Array2<f64>, valid: &Array2<bool>, u: f64, v: f64) -> Option<f64> {
    let (r, c) = a.dim();
    if !(u >= 0.0 && v >= 0.0) {
        return None;
    }
    let (i0, j0) = (u.floor() as usize, v.floor() as usize);
    let i1 = if u > i0 as f64 { i0 + 1 } else { i0 };
    let j1 = if v > j0 as f64 { j0 + 1 } else { j0 };
    if i1 >= r || j1 >= c {
        return None;
    }
    let all_valid = [(i0, j0), (i0, j1), (i1, j0), (i1, j1)]
        .iter()
        .all(|&p| valid[p]);
    all_valid.then(|| bilinear(a, u, v))
}

/// Catmull-Rom weights of the taps at -1, 0, 1, 2 around fraction t.
fn catmull_rom_weights(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Catmull-Rom bicubic interpolation of `a` at fractional (row u, col v): exact at the nodes,
/// third-order accurate between them; taps outside the array count as 0, and beyond one pixel
/// past the array the value is 0.
pub fn catmull_rom(a: &Array2<f64>, u: f64, v: f64) -> f64 {
    let (r, c) = a.dim();
    if !(u.is_finite() && v.is_finite()) || u <= -1.0 || v <= -1.0 || u >= r as f64 || v >= c as f64
    {
        return 0.0;
    }
    let (i0, j0) = (u.floor() as isize, v.floor() as isize);
    let (wi, wj) = (
        catmull_rom_weights(u - i0 as f64),
        catmull_rom_weights(v - j0 as f64),
    );
    // All 16 taps inside a contiguous array: the same sums in the same order, without the
    // per-tap bounds tests (a measured spot's interpolant is evaluated millions of times per
    // kernel build).
    if i0 >= 1 && j0 >= 1 && i0 + 2 < r as isize && j0 + 2 < c as isize {
        if let Some(all) = a.as_slice() {
            let (i0, j0) = (i0 as usize, j0 as usize);
            let mut s = 0.0;
            for (p, wp) in wi.iter().enumerate() {
                let start = (i0 - 1 + p) * c + j0 - 1;
                let row = &all[start..start + 4];
                let mut t = 0.0;
                for (wq, x) in wj.iter().zip(row) {
                    t += wq * x;
                }
                s += wp * t;
            }
            return s;
        }
    }
    let mut s = 0.0;
    for (p, wp) in wi.iter().enumerate() {
        let ii = i0 - 1 + p as isize;
        if ii < 0 || ii >= r as isize {
            continue;
        }
        let row = a.row(ii as usize);
        let mut t = 0.0;
        for (q, wq) in wj.iter().enumerate() {
            let jj = j0 - 1 + q as isize;
            if jj >= 0 && jj < c as isize {
                t += wq * row[jj as usize];
            }
        }
        s += wp * t;
    }
    s
}

/// [`catmull_rom`] of `a` along one line, in two steps: [`catmull_rom_across`] interpolates
/// across the line once (row `u`, or column `v` when not `along_rows`), and
/// [`catmull_rom_on_line`] then interpolates along it at any number of points, four taps each.
/// Returns false (and leaves `line` empty) when the line lies off the array, where the
/// interpolant is 0.
pub fn catmull_rom_across(a: &Array2<f64>, along_rows: bool, u: f64, line: &mut Vec<f64>) -> bool {
    line.clear();
    let (r, c) = a.dim();
    let (n_across, n_along) = if along_rows { (r, c) } else { (c, r) };
    if !u.is_finite() || u <= -1.0 || u >= n_across as f64 {
        return false;
    }
    let i0 = u.floor() as isize;
    let wi = catmull_rom_weights(u - i0 as f64);
    line.resize(n_along, 0.0);
    for (p, wp) in wi.iter().enumerate() {
        let ii = i0 - 1 + p as isize;
        if ii < 0 || ii >= n_across as isize {
            continue;
        }
        let lane = if along_rows {
            a.row(ii as usize)
        } else {
            a.column(ii as usize)
        };
        for (l, x) in line.iter_mut().zip(lane.iter()) {
            *l += wp * x;
        }
    }
    true
}

/// The cubic interpolant of a line from [`catmull_rom_across`] at fractional position `v`
/// (0 beyond one sample past either end; taps off the line count as 0).
#[inline]
pub fn catmull_rom_on_line(line: &[f64], v: f64) -> f64 {
    let n = line.len();
    if !v.is_finite() || v <= -1.0 || v >= n as f64 {
        return 0.0;
    }
    let j0 = v.floor() as isize;
    let wj = catmull_rom_weights(v - j0 as f64);
    if j0 >= 1 && j0 + 2 < n as isize {
        let j0 = j0 as usize;
        return wj[0] * line[j0 - 1]
            + wj[1] * line[j0]
            + wj[2] * line[j0 + 1]
            + wj[3] * line[j0 + 2];
    }
    let mut s = 0.0;
    for (q, wq) in wj.iter().enumerate() {
        let jj = j0 - 1 + q as isize;
        if jj >= 0 && jj < n as isize {
            s += wq * line[jj as usize];
        }
    }
    s
}

/// Band-limited (Fourier) upsampling of `a` by an integer factor: sample (m, n) of the result is
/// the trigonometric interpolant of `a` at (m / factor, n / factor). The array is taken as one
/// period, so it should fall to (nearly) the same level on all borders (a spot's surround).
/// Odd dimensions keep the interpolant real without a split Nyquist term.
pub fn fourier_upsample(a: &Array2<f64>, factor: usize) -> Array2<f64> {
    let (n0, n1) = a.dim();
    if factor <= 1 || n0 == 0 || n1 == 0 || n0 % 2 == 0 || n1 % 2 == 0 {
        return a.clone();
    }
    let (m0, m1) = (n0 * factor, n1 * factor);
    let small = Fft2::new(n0, n1);
    let big = Fft2::new(m0, m1);
    let mut real: Vec<f64> = a.iter().copied().collect();
    let zero = Complex::new(0.0, 0.0);
    let mut tmp = vec![zero; small.spectrum_len()];
    let mut spec = vec![zero; small.spectrum_len()];
    small.forward(&mut real, &mut tmp, &mut spec);
    // Transposed half spectra: element (k1, k0) at k1 * rows + k0.
    let scale = (factor * factor) as f64;
    let mut bspec = vec![zero; big.spectrum_len()];
    for k1 in 0..=n1 / 2 {
        for k0 in 0..n0 {
            let b0 = if k0 <= n0 / 2 { k0 } else { k0 + m0 - n0 };
            bspec[k1 * m0 + b0] = spec[k1 * n0 + k0] * scale;
        }
    }
    let mut btmp = vec![zero; big.spectrum_len()];
    let mut out = vec![0.0; m0 * m1];
    big.inverse(&mut bspec, &mut btmp, &mut out);
    Array2::from_shape_vec((m0, m1), out).unwrap_or_else(|_| a.clone())
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_periodic_sample_wraps_and_interpolates() {
        let a = ndarray::Array2::from_shape_fn((4, 5), |(i, j)| (10 * i + j) as f64);
        // Inside: bilinear in both directions (row 1, column 1.5).
        assert!((super::bilinear_periodic(&a, 1.0, 1.5) - 11.5).abs() < 1e-12);
        // One period up and to the left is the same point.
        assert!((super::bilinear_periodic(&a, 1.0 - 4.0, 1.5 - 5.0) - 11.5).abs() < 1e-12);
        // Past the last column it wraps to the first: half way between 4 and 0 on row 0.
        assert!((super::bilinear_periodic(&a, 0.0, 4.5) - 2.0).abs() < 1e-12);
        // And past the last row, to the first: half way between 30 and 0 in column 0.
        assert!((super::bilinear_periodic(&a, 3.5, 0.0) - 15.0).abs() < 1e-12);
    }

    use super::*;

    #[test]
    fn catmull_rom_is_exact_at_nodes_and_on_cubics_inside() {
        // A cubic in each direction is not reproduced by Catmull-Rom, but a quadratic is.
        let f =
            |u: f64, v: f64| 1.0 + 0.3 * u - 0.2 * v + 0.05 * u * u - 0.04 * v * v + 0.01 * u * v;
        let a = Array2::from_shape_fn((12, 12), |(i, j)| f(i as f64, j as f64));
        assert!((catmull_rom(&a, 4.0, 7.0) - f(4.0, 7.0)).abs() < 1e-12);
        for (u, v) in [(3.3, 5.7), (6.5, 2.25), (8.9, 8.1)] {
            assert!((catmull_rom(&a, u, v) - f(u, v)).abs() < 1e-10, "{u} {v}");
        }
        assert_eq!(catmull_rom(&a, -1.5, 3.0), 0.0);
    }

    #[test]
    fn fourier_upsampling_reproduces_a_band_limited_gaussian() {
        // sigma 1.2 px: the spectrum at Nyquist is below 1e-3 of its peak.
        let g = |u: f64, v: f64| (-((u - 10.3).powi(2) + (v - 9.6).powi(2)) / (2.0 * 1.44)).exp();
        let a = Array2::from_shape_fn((21, 21), |(i, j)| g(i as f64, j as f64));
        let up = fourier_upsample(&a, 4);
        assert_eq!(up.dim(), (84, 84));
        let mut worst = 0.0f64;
        for ((m, n), &v) in up.indexed_iter() {
            worst = worst.max((v - g(m as f64 / 4.0, n as f64 / 4.0)).abs());
        }
        assert!(worst < 2e-3, "{worst}");
        // Catmull-Rom on the raw samples is an order of magnitude worse at this sampling.
        let cr = (catmull_rom(&a, 10.5, 9.5) - g(10.5, 9.5)).abs();
        assert!(cr > 5.0 * worst, "{cr} vs {worst}");
    }

    #[test]
    fn bilinear_reproduces_planes() {
        let a = Array2::from_shape_fn((5, 6), |(i, j)| 2.0 * i as f64 - j as f64);
        assert!((bilinear(&a, 1.25, 3.5) - (2.5 - 3.5)).abs() < 1e-12);
        assert_eq!(bilinear(&a, 5.5, 1.0), 0.0);
        // Clamped: the border value beyond the array, the interpolant inside.
        assert_eq!(bilinear_clamped(&a, 7.0, -2.0), a[(4, 0)]);
        assert_eq!(bilinear_clamped(&a, 4.0, 5.0), a[(4, 5)]);
        assert_eq!(bilinear_clamped(&a, 1.25, 3.5), bilinear(&a, 1.25, 3.5));
    }

    #[test]
    fn masked_bilinear_needs_the_pixels_it_weights() {
        let a = Array2::from_shape_fn((5, 6), |(i, j)| 2.0 * i as f64 - j as f64);
        let mut valid = Array2::from_elem((5, 6), true);
        valid[(2, 3)] = false;
        assert_eq!(bilinear_masked(&a, &valid, 1.25, 3.5), None);
        assert_eq!(bilinear_masked(&a, &valid, 1.0, 4.0), Some(a[(1, 4)]));
        // On a node next to the hole only the node itself counts.
        assert_eq!(bilinear_masked(&a, &valid, 2.0, 4.0), Some(a[(2, 4)]));
        assert_eq!(bilinear_masked(&a, &valid, 2.0, 2.5), None);
        assert_eq!(
            bilinear_masked(&a, &valid, 3.5, 0.5),
            bilinear(&a, 3.5, 0.5).into()
        );
        // The last row and column are reachable on their nodes, not beyond.
        assert_eq!(bilinear_masked(&a, &valid, 4.0, 5.0), Some(a[(4, 5)]));
        assert_eq!(bilinear_masked(&a, &valid, 4.0, 5.5), None);
        assert_eq!(bilinear_masked(&a, &valid, -0.1, 1.0), None);
    }
}
