//! Maps on the run's grid ([`MapGrid`], the project's one grid type): bilinear sampling of maps
//! at path positions, masked Gaussian smoothing and a signed distance to the part edge.

use bonnetlab_process::interp::bilinear_clamped;
use ndarray::Array2;
use rayon::prelude::*;

/// The map grid: the project's one grid type (`bonnetlab_surface::Grid`).
pub use bonnetlab_surface::Grid as MapGrid;

/// Bilinear sample of a (hole-free) map at (x, y) mm, positions clamped to the grid
/// (`bonnetlab_process::interp::bilinear_clamped`).
pub fn sample(g: &MapGrid, a: &Array2<f64>, x: f64, y: f64) -> f64 {
    let (u, v) = g.frac_index(x, y);
    bilinear_clamped(a, u, v)
}

/// Masked (normalised) separable Gaussian smoothing with `sigma_px` pixels; invalid pixels get
/// the weighted mean of their valid neighbours (0 when there is none within 4 sigma).
pub fn smooth_masked(a: &Array2<f64>, valid: &Array2<bool>, sigma_px: f64) -> Array2<f64> {
    let (r, c) = a.dim();
    let h = (4.0 * sigma_px).ceil().max(1.0) as isize;
    let w: Vec<f64> = (-h..=h)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let mut num0 = Array2::<f64>::zeros((r, c));
    let mut den0 = Array2::<f64>::zeros((r, c));
    ndarray::Zip::from(&mut num0)
        .and(&mut den0)
        .and(a)
        .and(valid)
        .for_each(|n, d, &x, &v| {
            if v {
                *n = x;
                *d = 1.0;
            }
        });
    // Separable passes over contiguous rows; every output sums its taps in ascending order
    // (the same sums as a tap-by-tap loop), with the taps clipped to the map once per pixel.
    // Each output row is formed on its own (rows side by side: the same sums).
    let rows_pass = |m: &Array2<f64>| -> Array2<f64> {
        let mut out = Array2::zeros((r, c));
        let src_rows: Vec<_> = m.rows().into_iter().collect();
        let dst_rows: Vec<_> = out.rows_mut().into_iter().collect();
        src_rows
            .into_par_iter()
            .zip(dst_rows)
            .for_each(|(src, mut dst)| {
                let src = src.as_slice().expect("standard layout");
                let dst = dst.as_slice_mut().expect("standard layout");
                row_taps(src, &w, dst);
            });
        out
    };
    let cols_pass = |m: &Array2<f64>| -> Array2<f64> {
        let mut out = Array2::zeros((r, c));
        let src = m.as_slice().expect("standard layout");
        let dst_rows: Vec<_> = out.rows_mut().into_iter().collect();
        dst_rows
            .into_par_iter()
            .enumerate()
            .for_each(|(i, mut dst)| {
                let dst = dst.as_slice_mut().expect("standard layout");
                col_taps(src, c, i, &w, dst);
            });
        out
    };
    let pass = |m: &Array2<f64>, along_cols: bool| -> Array2<f64> {
        if along_cols {
            rows_pass(m)
        } else {
            cols_pass(m)
        }
    };
    let (num, den) = rayon::join(
        || pass(&pass(&num0, true), false),
        || pass(&pass(&den0, true), false),
    );
    ndarray::Zip::from(&num)
        .and(&den)
        .map_collect(|&n, &d| if d > 1e-9 { n / d } else { 0.0 })
}

/// Means of the valid pixels of `a` over `b` x `b` blocks (the last row and column of blocks
/// may be partial), and which blocks hold any (0 where none).
pub fn block_means(a: &Array2<f64>, valid: &Array2<bool>, b: usize) -> (Array2<f64>, Array2<bool>) {
    let (r, c) = a.dim();
    let b = b.max(1);
    let (rb, cb) = (r.div_ceil(b), c.div_ceil(b));
    let mut num = Array2::<f64>::zeros((rb, cb));
    let mut den = Array2::<f64>::zeros((rb, cb));
    for ((i, j), &v) in valid.indexed_iter() {
        if v {
            num[(i / b, j / b)] += a[(i, j)];
            den[(i / b, j / b)] += 1.0;
        }
    }
    let mean = Array2::from_shape_fn(
        (rb, cb),
        |q| if den[q] > 0.0 { num[q] / den[q] } else { 0.0 },
    );
    (mean, den.mapv(|w| w > 0.0))
}

/// [`smooth_masked`] with the pixels beyond the data's reach filled from afar: an invalid pixel
/// at distance `d` (pixels) from the nearest valid one takes the masked smoothing at the
/// length `max(sigma_px, alpha d)` (interpolated in log length between smoothings at `sigma_px`
/// times powers of two, each on block means a quarter of its length across, at least a
/// pixel), so the height beyond a rim continues the data nearby and relaxes to their wider mean
/// further out, instead of dropping to 0 at 4 sigma. Valid pixels, and invalid ones within
/// `sigma_px / alpha` of the data, are [`smooth_masked`]'s values bit for bit. `alpha` of 0.5
/// or more (below it, the first octave would blend with [`smooth_masked`]'s 0 past its reach);
/// 0 for [`smooth_masked`] itself.
pub fn smooth_masked_reaching(
    a: &Array2<f64>,
    valid: &Array2<bool>,
    sigma_px: f64,
    alpha: f64,
) -> Array2<f64> {
    let mut out = smooth_masked(a, valid, sigma_px);
    let (r, c) = a.dim();
    if alpha <= 0.0 || valid.iter().all(|v| *v) || !valid.iter().any(|v| *v) {
        return out;
    }
    let dist = edt_mm(valid, 1.0, 1.0);
    // Lengths past twice the map's size smooth no differently.
    let cap = (2.0 * r.max(c) as f64 / sigma_px).log2().ceil().max(1.0);
    // The pixels the wider smoothings decide, with their length's octave above sigma_px.
    let far: Vec<(usize, usize, f64)> = dist
        .indexed_iter()
        .filter_map(|((i, j), &d)| {
            let s = (alpha * d / sigma_px).log2().min(cap);
            (s > 0.0).then_some((i, j, s))
        })
        .collect();
    let Some(top) = far.iter().map(|f| f.2.ceil() as usize).max() else {
        return out;
    };
    // Level k: the masked smoothing at sigma_px 2^k, sampled at the far pixels.
    let levels: Vec<Vec<f64>> = (1..=top)
        .map(|k| {
            let sig = sigma_px * 2f64.powi(k as i32);
            let b = ((sig / 4.0).floor() as usize).max(1);
            let (mb, vb) = block_means(a, valid, b);
            let sm = smooth_masked(&mb, &vb, sig / b as f64);
            let half = 0.5 * (b as f64 - 1.0);
            far.iter()
                .map(|&(i, j, _)| {
                    bilinear_clamped(
                        &sm,
                        (i as f64 - half) / b as f64,
                        (j as f64 - half) / b as f64,
                    )
                })
                .collect()
        })
        .collect();
    for (n, &(i, j, s)) in far.iter().enumerate() {
        let k0 = s.floor() as usize;
        let t = s - k0 as f64;
        let at = |k: usize| {
            if k == 0 {
                out[(i, j)]
            } else {
                levels[k - 1][n]
            }
        };
        let v0 = at(k0);
        let v = if t > 0.0 {
            (1.0 - t) * v0 + t * at(k0 + 1)
        } else {
            v0
        };
        out[(i, j)] = v;
    }
    out
}

/// Output row `i` of the column pass: `dst` (zeros on entry) += `w[k] src row (i - h + k)` for
/// the taps inside the map (`c` columns a row), in ascending order.
fn col_taps(src: &[f64], c: usize, i: usize, w: &[f64], dst: &mut [f64]) {
    bonnetlab_spectrum::avx2_or_baseline!(col_taps_impl(src, c, i, w, dst))
}

#[inline(always)]
fn col_taps_impl(src: &[f64], c: usize, i: usize, w: &[f64], dst: &mut [f64]) {
    let r = src.len() / c;
    let h = w.len() / 2;
    let lo = i.saturating_sub(h);
    let hi = (i + h).min(r - 1);
    for ii in lo..=hi {
        let wk = w[ii + h - i];
        for (d, x) in dst.iter_mut().zip(&src[ii * c..(ii + 1) * c]) {
            *d += wk * x;
        }
    }
}

/// One row of the separable smoothing: `dst[j]` = the sum over the taps `w` (odd length
/// `2h + 1`, centred) of `w[k] src[j - h + k]`, the taps clipped to the row, summed in
/// ascending order from +0.0. Where the taps are not clipped, [`ROW_BLOCK`] outputs are formed
/// together (independent sums, each in the same order: the same bits as one at a time, without
/// waiting on one sum's additions).
fn row_taps(src: &[f64], w: &[f64], dst: &mut [f64]) {
    bonnetlab_spectrum::avx2_or_baseline!(row_taps_impl(src, w, dst))
}

#[inline(always)]
fn row_taps_impl(src: &[f64], w: &[f64], dst: &mut [f64]) {
    let c = src.len();
    let h = w.len() / 2;
    let one = |j: usize| -> f64 {
        let lo = j.saturating_sub(h);
        let hi = (j + h).min(c - 1);
        let mut s = 0.0;
        for (x, wk) in src[lo..=hi].iter().zip(&w[lo + h - j..]) {
            s += wk * x;
        }
        s
    };
    // Outputs whose taps all lie in the row: h ..= c - 1 - h.
    let (a, b) = if c > 2 * h { (h, c - h) } else { (c, c) };
    for (j, d) in dst.iter_mut().enumerate().take(a) {
        *d = one(j);
    }
    let mut j = a;
    while j + ROW_BLOCK <= b {
        let mut s = [0.0; ROW_BLOCK];
        for (k, wk) in w.iter().enumerate() {
            let x = &src[j - h + k..j - h + k + ROW_BLOCK];
            for (sq, xq) in s.iter_mut().zip(x) {
                *sq += wk * xq;
            }
        }
        dst[j..j + ROW_BLOCK].copy_from_slice(&s);
        j += ROW_BLOCK;
    }
    for (jj, d) in dst.iter_mut().enumerate().skip(j) {
        *d = one(jj);
    }
}

/// Outputs of [`row_taps`] formed together.
const ROW_BLOCK: usize = 8;

/// Squared 1-D distance transform (Felzenszwalb & Huttenlocher) of `f` (0 at sites, inf elsewhere).
fn dt1(f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let mut d = vec![f64::INFINITY; n];
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    let first = match f.iter().position(|x| x.is_finite()) {
        Some(p) => p,
        None => return d,
    };
    v[0] = first;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in first + 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            let s =
                ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            if s <= z[k] && k > 0 {
                k -= 1;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f64::INFINITY;
                break;
            }
        }
    }
    let mut k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        *dq = (q as f64 - p as f64).powi(2) + f[p];
    }
    d
}

/// Euclidean distance (mm) from each pixel centre to the nearest pixel where `site` is true.
fn edt_mm(site: &Array2<bool>, dx: f64, dy: f64) -> Array2<f64> {
    let (r, c) = site.dim();
    // Rows in pixel units of x, then columns with the y scale folded in.
    let mut g = Array2::<f64>::zeros((r, c));
    for i in 0..r {
        let f: Vec<f64> = (0..c)
            .map(|j| if site[(i, j)] { 0.0 } else { f64::INFINITY })
            .collect();
        let d = dt1(&f);
        for j in 0..c {
            g[(i, j)] = d[j] * dx * dx;
        }
    }
    let mut out = Array2::<f64>::zeros((r, c));
    let sy = dy * dy;
    for j in 0..c {
        // Generalised: minimise g(i') + (i - i')^2 dy^2  ==  sy * (g/sy + (i - i')^2)
        let f: Vec<f64> = (0..r).map(|i| g[(i, j)] / sy).collect();
        let d = dt1(&f);
        for i in 0..r {
            out[(i, j)] = (d[i] * sy).sqrt();
        }
    }
    out
}

/// Signed distance (mm) to the part edge: positive inside. The part is the valid aperture with
/// its holes (dropouts not connected to the map border) filled; the map border is an edge.
pub fn signed_edge_distance(valid: &Array2<bool>, dx: f64, dy: f64) -> Array2<f64> {
    let (r, c) = valid.dim();
    // Pad by one outside pixel so the map border counts as edge.
    let (pr, pc) = (r + 2, c + 2);
    let mut outside = Array2::<bool>::from_elem((pr, pc), false);
    // Flood fill from the padding through invalid pixels.
    let mut stack = vec![(0usize, 0usize)];
    let is_invalid = |i: usize, j: usize| -> bool {
        i == 0 || j == 0 || i == pr - 1 || j == pc - 1 || !valid[(i - 1, j - 1)]
    };
    outside[(0, 0)] = true;
    while let Some((i, j)) = stack.pop() {
        let nb = [
            (i.wrapping_sub(1), j),
            (i + 1, j),
            (i, j.wrapping_sub(1)),
            (i, j + 1),
        ];
        for (a, b) in nb {
            if a < pr && b < pc && !outside[(a, b)] && is_invalid(a, b) {
                outside[(a, b)] = true;
                stack.push((a, b));
            }
        }
    }
    let inside = outside.mapv(|o| !o);
    let d_out = edt_mm(&outside, dx, dy);
    let d_in = edt_mm(&inside, dx, dy);
    let half = 0.5 * dx.min(dy);
    Array2::from_shape_fn((r, c), |(i, j)| {
        if inside[(i + 1, j + 1)] {
            d_out[(i + 1, j + 1)] - half
        } else {
            -(d_in[(i + 1, j + 1)] - half)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edge_distance_of_a_rectangle_with_a_hole() {
        let mut v = Array2::from_elem((20, 30), true);
        v[(10, 15)] = false; // a dropout, not an edge
        let d = signed_edge_distance(&v, 0.5, 0.5);
        // pixel (10, 5): nearest edge is the left border at x = -0.25 mm -> 5*0.5 + 0.25
        assert!((d[(10, 5)] - 2.75).abs() < 1e-9, "{}", d[(10, 5)]);
        assert!((d[(10, 14)] - 4.75).abs() < 1e-9, "{}", d[(10, 14)]);
        assert!((d[(0, 0)] - 0.25).abs() < 1e-9);
    }

    #[test]
    fn blocked_row_taps_are_the_plain_sums_bit_for_bit() {
        // Rows shorter than, equal to and longer than the taps, with a block remainder.
        let mut rng = bonnetlab_surface::rng::Rng::new(7);
        for (c, h) in [
            (3usize, 4usize),
            (9, 4),
            (10, 4),
            (37, 4),
            (64, 12),
            (401, 48),
        ] {
            let src: Vec<f64> = (0..c).map(|_| rng.uniform() - 0.5).collect();
            let w: Vec<f64> = (0..=2 * h).map(|_| rng.uniform()).collect();
            let mut got = vec![f64::NAN; c];
            row_taps(&src, &w, &mut got);
            for (j, g) in got.iter().enumerate() {
                let mut s = 0.0;
                for (k, wk) in w.iter().enumerate() {
                    let q = j as isize - h as isize + k as isize;
                    if q >= 0 && (q as usize) < c {
                        s += wk * src[q as usize];
                    }
                }
                assert_eq!(g.to_bits(), s.to_bits(), "c {c} h {h} j {j}");
            }
        }
    }

    #[test]
    fn the_reaching_fill_keeps_the_data_and_continues_them_past_the_smoothings_reach() {
        // A disc of data in a larger map: a level of 7 with a ripple on it.
        let (r, c) = (96, 128);
        let a = Array2::from_shape_fn((r, c), |(i, j)| {
            7.0 + (0.3 * i as f64).sin() * (0.2 * j as f64).cos()
        });
        let v = Array2::from_shape_fn((r, c), |(i, j)| {
            (i as f64 - 40.0).hypot(j as f64 - 50.0) < 25.0
        });
        let sigma = 2.0;
        let old = smooth_masked(&a, &v, sigma);
        let new = smooth_masked_reaching(&a, &v, sigma, 0.5);
        let dist = edt_mm(&v, 1.0, 1.0);
        let mut far = 0;
        for ((i, j), &d) in dist.indexed_iter() {
            if d <= sigma / 0.5 {
                // The data and the pixels the smoothing itself reaches: the same bits.
                assert_eq!(old[(i, j)].to_bits(), new[(i, j)].to_bits(), "({i}, {j})");
            } else if d > 4.0 * sigma * std::f64::consts::SQRT_2 + 1.0 {
                // Past the smoothing's (square) reach the old fill is 0; the new one
                // continues the data (their ripple averages out at the longer lengths).
                far += 1;
                assert_eq!(old[(i, j)], 0.0);
                // Within the data's range (7 +- 1), and their level where it is far.
                let tol = if d > 30.0 { 0.3 } else { 1.0 };
                assert!(
                    (new[(i, j)] - 7.0).abs() < tol,
                    "({i}, {j}): {}",
                    new[(i, j)]
                );
            }
        }
        assert!(far > 5000, "{far}");
        // Continuous: no step between neighbours larger than the data's own.
        let step = |m: &Array2<f64>| {
            let mut s = 0.0f64;
            for i in 0..r {
                for j in 1..c {
                    s = s.max((m[(i, j)] - m[(i, j - 1)]).abs());
                }
            }
            s
        };
        assert!(step(&new) < 0.5, "{}", step(&new));
        assert!(step(&old) > 1.0);
        // Nothing to fill: the smoothing itself.
        let all = Array2::from_elem((r, c), true);
        assert_eq!(
            smooth_masked_reaching(&a, &all, sigma, 0.5),
            smooth_masked(&a, &all, sigma)
        );
    }

    #[test]
    fn smoothing_keeps_a_plane_and_fills_holes() {
        let a = Array2::from_shape_fn((15, 15), |(i, j)| 2.0 * i as f64 + j as f64);
        let mut v = Array2::from_elem((15, 15), true);
        v[(7, 7)] = false;
        let s = smooth_masked(&a, &v, 1.5);
        assert!((s[(7, 7)] - 21.0).abs() < 1e-9);
    }

    #[test]
    fn smoothing_sums_the_taps_of_a_direct_masked_convolution() {
        // Against the normalised convolution written tap by tap, on a rough map with holes,
        // a kernel wider than the map and a narrow one.
        let (r, c) = (23, 31);
        let a = Array2::from_shape_fn((r, c), |(i, j)| ((i * 37 + j * 101) % 17) as f64 - 8.0);
        let v = Array2::from_shape_fn((r, c), |(i, j)| (i * 7 + j * 3) % 5 != 0);
        for sigma in [0.7f64, 3.0, 9.0] {
            let h = (4.0 * sigma).ceil() as isize;
            let g = |t: isize| (-(t * t) as f64 / (2.0 * sigma * sigma)).exp();
            let got = smooth_masked(&a, &v, sigma);
            for i in 0..r as isize {
                for j in 0..c as isize {
                    let (mut num, mut den) = (0.0, 0.0);
                    for ti in -h..=h {
                        for tj in -h..=h {
                            let (ii, jj) = (i + ti, j + tj);
                            if ii >= 0 && jj >= 0 && ii < r as isize && jj < c as isize {
                                let q = (ii as usize, jj as usize);
                                if v[q] {
                                    num += g(ti) * g(tj) * a[q];
                                    den += g(ti) * g(tj);
                                }
                            }
                        }
                    }
                    let want = num / den;
                    let d = got[(i as usize, j as usize)] - want;
                    assert!(
                        d.abs() < 1e-12 * (1.0 + want.abs()),
                        "{sigma} ({i}, {j}): {d}"
                    );
                }
            }
        }
    }
}
