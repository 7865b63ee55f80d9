//! Small dense least squares on compressed pixel vectors: weighted Gram matrices (the normal
//! equations; the fits have a handful of columns over 10^4..10^6 pixels, so forming `C^T W C`
//! once is far cheaper than a QR of the tall matrix) solved with `nalgebra`'s SVD, and the
//! pseudo-inverse for covariances.
//!
//! Conditioning guard: the Gram matrix is first equilibrated (`D G D`, `D = diag(G)^-1/2`, so
//! columns of any unit have unit norm), then singular values below [`RCOND`] times the largest
//! are treated as zero. Columns whose equilibrated Gram matrix has a condition number above
//! 1 / `RCOND` (the columns themselves above ~10^5) are so nearly dependent that the data cannot
//! split their share: the minimum-norm solution splits it evenly and the fitted values are
//! unaffected, instead of a fit that aborts or returns huge opposite coefficients.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Relative singular-value cut-off of the equilibrated Gram matrix (see the module docs).
pub const RCOND: f64 = 1e-10;

/// Pixels per block of [`products`]: the block's columns stay in the L1/L2 cache while every
/// pair of columns is accumulated over it.
const BLOCK: usize = 256;

/// Weighted products `out[r][t] = init + sum_i (w_i x_r[i]) y_t[i]` for every row `r` and
/// every target `t >= r` (entries `t < r` stay `init`), over the pixels `picked` (ascending;
/// all when `None`). `rows[r]` is usually `targets[r]` (a Gram matrix's upper triangle).
///
/// Every entry is one sequential sum over the pixels in ascending order, exactly as a plain
/// loop `for i { s += w[i] * x[i] * y[i] }` forms it; the pixels are taken in blocks (each
/// entry's running sum carried from block to block, eight or four entries at a time for
/// instruction-level parallelism) so the columns are read from memory once per block rather
/// than once per pair. The sums are the plain loop's to the bit.
pub fn products(
    rows: &[&[f64]],
    targets: &[&[f64]],
    w: &[f64],
    picked: Option<&[usize]>,
    init: f64,
) -> Vec<Vec<f64>> {
    products_from(rows, targets, w, picked, init, |r| r)
}

/// [`products`] for the targets `t >= first(r)` of each row `r` (entries `t < first(r)` stay
/// `init`): `first = |_| 0` gives every product of every row with every target (a rectangular
/// block, e.g. the cross terms of new columns with unchanged ones). Each entry is the same
/// sequential sum as in [`products`].
///
/// Rows go to the rayon pool in groups of about equal work (each group a pass over the pixels
/// of its own): every entry is still formed by one thread as the one sequential sum above, so
/// the result does not depend on the grouping, bit for bit. A fit's Gram matrix is often formed
/// while the other thread has nothing to do (a refinement's trial evaluation, the last
/// contender of a round).
pub fn products_from(
    rows: &[&[f64]],
    targets: &[&[f64]],
    w: &[f64],
    picked: Option<&[usize]>,
    init: f64,
    first: impl Fn(usize) -> usize + Sync,
) -> Vec<Vec<f64>> {
    let nt = targets.len();
    let work: Vec<usize> = (0..rows.len())
        .map(|r| nt.saturating_sub(first(r)))
        .collect();
    let total: usize = work.iter().sum();
    let npix = picked.map_or(w.len(), |p| p.len());
    let threads = rayon::current_num_threads().min(rows.len());
    if threads < 2 || total.saturating_mul(npix) < PARALLEL_MIN_PRODUCTS {
        let all: Vec<usize> = (0..rows.len()).collect();
        return products_of_rows(rows, targets, w, picked, init, &first, &all);
    }
    // Consecutive rows in `threads` groups of about total / threads products each.
    let mut groups: Vec<Vec<usize>> = vec![Vec::new()];
    let mut done = 0;
    for (r, &wk) in work.iter().enumerate() {
        let g = groups.len();
        if done * threads >= g * total && g < threads && !groups[g - 1].is_empty() {
            groups.push(Vec::new());
        }
        if let Some(v) = groups.last_mut() {
            v.push(r);
        }
        done += wk;
    }
    let parts: Vec<Vec<Vec<f64>>> = groups
        .par_iter()
        .map(|g| products_of_rows(rows, targets, w, picked, init, &first, g))
        .collect();
    parts.into_iter().flatten().collect()
}

/// Products (pixels times rows times targets) below which [`products_from`] stays on the
/// calling thread.
const PARALLEL_MIN_PRODUCTS: usize = 1 << 21;

/// Rows from which [`products_of_rows`] lays each block of targets out pixel by pixel
/// ([`products_transposed`]); fewer rows read the targets as they are.
const TRANSPOSED_MIN_ROWS: usize = 4;

/// [`products_from`] for the rows `which` (ascending), one serial pass over the pixels.
fn products_of_rows(
    rows: &[&[f64]],
    targets: &[&[f64]],
    w: &[f64],
    picked: Option<&[usize]>,
    init: f64,
    first: &(impl Fn(usize) -> usize + Sync),
    which: &[usize],
) -> Vec<Vec<f64>> {
    if which.len() >= TRANSPOSED_MIN_ROWS {
        return products_transposed(rows, targets, w, picked, init, first, which);
    }
    let nt = targets.len();
    let mut acc = vec![vec![init; nt]; which.len()];
    let total = picked.map_or(w.len(), |p| p.len());
    // Gather buffers (used with `picked` only): the targets, the weights and the row.
    let mut buf = vec![0.0; if picked.is_some() { nt * BLOCK } else { 0 }];
    let mut wbuf = vec![0.0; BLOCK];
    let mut xbuf = vec![0.0; BLOCK];
    let mut wx = vec![0.0; BLOCK];
    let mut lo = 0;
    while lo < total {
        let hi = (lo + BLOCK).min(total);
        let nb = hi - lo;
        let gather = |dst: &mut [f64], src: &[f64], p: &[usize]| {
            for (d, &i) in dst.iter_mut().zip(&p[lo..hi]) {
                *d = src[i];
            }
        };
        let (cols, wblk): (Vec<&[f64]>, &[f64]) = match picked {
            Some(p) => {
                for (k, t) in targets.iter().enumerate() {
                    gather(&mut buf[k * BLOCK..k * BLOCK + nb], t, p);
                }
                gather(&mut wbuf[..nb], w, p);
                (
                    (0..nt).map(|k| &buf[k * BLOCK..k * BLOCK + nb]).collect(),
                    &wbuf[..nb],
                )
            }
            None => (targets.iter().map(|t| &t[lo..hi]).collect(), &w[lo..hi]),
        };
        for (&r, row) in which.iter().zip(acc.iter_mut()) {
            if first(r) >= nt {
                continue;
            }
            let x: &[f64] = match picked {
                Some(p) => {
                    gather(&mut xbuf[..nb], rows[r], p);
                    &xbuf[..nb]
                }
                None => &rows[r][lo..hi],
            };
            for ((d, &wi), &xi) in wx[..nb].iter_mut().zip(wblk).zip(x) {
                *d = wi * xi;
            }
            let wx = &wx[..nb];
            let mut t = first(r);
            while t + 8 <= nt {
                add_products::<8>(row, t, &cols, wx);
                t += 8;
            }
            while t + 4 <= nt {
                add_products::<4>(row, t, &cols, wx);
                t += 4;
            }
            while t < nt {
                add_products::<1>(row, t, &cols, wx);
                t += 1;
            }
        }
        lo = hi;
    }
    acc
}

/// `row[t..t + N] += sum_i wx[i] cols[t + k][i]`, each of the N sums sequential over `i` (N
/// independent chains side by side).
fn add_products<const N: usize>(row: &mut [f64], t: usize, cols: &[&[f64]], wx: &[f64]) {
    let nb = wx.len();
    let c: [&[f64]; N] = std::array::from_fn(|k| &cols[t + k][..nb]);
    let mut s: [f64; N] = std::array::from_fn(|k| row[t + k]);
    for (i, &x) in wx.iter().enumerate() {
        for k in 0..N {
            s[k] += x * c[k][i];
        }
    }
    row[t..t + N].copy_from_slice(&s);
}

/// Zero targets after the last in each pixel's line of a transposed block: the widest tail
/// chunk ([`row_products`], four targets) may read past the last target but stays in its line.
const PAD: usize = 4;

/// Pixels per block of [`products_transposed`]: the block (8 bytes per target and pixel, 23 KB
/// for 45 targets) stays in the L1 cache; 256 pixels ran 1.3x slower at 40 columns.
const TBLOCK: usize = 64;

/// [`products_of_rows`] with each block of targets laid out pixel by pixel (the `nt` targets of
/// pixel `i` side by side, then `PAD` zeros): a row's sums over `W` consecutive targets then
/// read contiguous memory at every pixel and run as `W`-wide vector operations, `W / 4` AVX2
/// registers (or `W / 2` SSE2 ones) of independent chains. Every entry is still its own
/// sequential sum over the pixels in ascending order (a product, then a sum, never fused), so
/// the result is [`products`]' plain loop to the bit.
fn products_transposed(
    rows: &[&[f64]],
    targets: &[&[f64]],
    w: &[f64],
    picked: Option<&[usize]>,
    init: f64,
    first: &(impl Fn(usize) -> usize + Sync),
    which: &[usize],
) -> Vec<Vec<f64>> {
    let nt = targets.len();
    let stride = nt + PAD;
    let mut acc = vec![vec![init; nt]; which.len()];
    let total = picked.map_or(w.len(), |p| p.len());
    let mut tb = vec![0.0; TBLOCK * stride];
    let mut wx = vec![0.0; TBLOCK];
    let mut lo = 0;
    while lo < total {
        let hi = (lo + TBLOCK).min(total);
        let nb = hi - lo;
        let at = |i: usize| picked.map_or(lo + i, |p| p[lo + i]);
        for (k, t) in targets.iter().enumerate() {
            for i in 0..nb {
                tb[i * stride + k] = t[at(i)];
            }
        }
        let tb = &tb[..nb * stride];
        for (&r, row) in which.iter().zip(acc.iter_mut()) {
            let t0 = first(r);
            if t0 >= nt {
                continue;
            }
            let x = rows[r];
            for (i, d) in wx[..nb].iter_mut().enumerate() {
                let j = at(i);
                *d = w[j] * x[j];
            }
            row_products(row, t0, tb, stride, &wx[..nb]);
        }
        lo = hi;
    }
    acc
}

/// `row[t] += sum_i wx[i] tb[i * stride + t]` for every `t >= t0`, in chunks of 16, 8 and 4
/// targets (the last chunk may run into the zero padding, whose sums are not kept).
fn row_products(row: &mut [f64], t0: usize, tb: &[f64], stride: usize, wx: &[f64]) {
    bonnetlab_spectrum::avx2_or_baseline!(row_products_impl(row, t0, tb, stride, wx))
}

#[inline(always)]
fn row_products_impl(row: &mut [f64], t0: usize, tb: &[f64], stride: usize, wx: &[f64]) {
    let nt = row.len();
    let mut t = t0;
    while t < nt {
        let left = nt - t;
        if left >= 16 {
            chunk_products::<16>(row, t, 16, tb, stride, wx);
            t += 16;
        } else if left >= 8 {
            chunk_products::<8>(row, t, 8, tb, stride, wx);
            t += 8;
        } else {
            chunk_products::<PAD>(row, t, left.min(PAD), tb, stride, wx);
            t += PAD;
        }
    }
}

/// `row[t..t + keep] += sum_i wx[i] tb[i * stride + t ..][..keep]` (`keep <= W`), the `W`
/// sums side by side, each sequential over `i`.
#[inline(always)]
fn chunk_products<const W: usize>(
    row: &mut [f64],
    t: usize,
    keep: usize,
    tb: &[f64],
    stride: usize,
    wx: &[f64],
) {
    let mut s = [0.0f64; W];
    s[..keep].copy_from_slice(&row[t..t + keep]);
    for (line, &x) in tb.chunks_exact(stride).zip(wx) {
        let c = &line[t..t + W];
        for k in 0..W {
            s[k] += x * c[k];
        }
    }
    row[t..t + keep].copy_from_slice(&s[..keep]);
}

/// Weighted Gram matrix `G[a][b] = sum_i w_i c_a[i] c_b[i]` and `rhs[a] = sum_i w_i c_a[i] m_i`
/// over the pixels where `sel` is true (all when `None`): each entry (`a <= b`) the sequential
/// sum of `(w_i c_a[i]) c_b[i]` over the pixels in ascending order (see [`products`]).
pub fn gram(
    cols: &[&[f64]],
    m: &[f64],
    w: &[f64],
    sel: Option<&[bool]>,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let n = cols.len();
    let picked: Option<Vec<usize>> = sel.map(|sl| (0..m.len()).filter(|&i| sl[i]).collect());
    let mut targets = cols.to_vec();
    targets.push(m);
    let acc = products(cols, &targets, w, picked.as_deref(), 0.0);
    let mut g = vec![vec![0.0; n]; n];
    let mut rhs = vec![0.0; n];
    for a in 0..n {
        for b in a..n {
            g[a][b] = acc[a][b];
            g[b][a] = acc[a][b];
        }
        rhs[a] = acc[a][n];
    }
    (g, rhs)
}

/// An SVD of a dynamically sized matrix.
type Svd = nalgebra::SVD<f64, nalgebra::Dyn, nalgebra::Dyn>;

/// The SVD of the equilibrated `g` with its scaling `d`, or `None` when `g` is not finite.
fn equilibrated_svd(g: &[Vec<f64>]) -> Option<(Svd, Vec<f64>, f64)> {
    let n = g.len();
    if g.iter()
        .any(|r| r.len() != n || r.iter().any(|v| !v.is_finite()))
    {
        return None;
    }
    let d: Vec<f64> = (0..n)
        .map(|a| {
            if g[a][a] > 0.0 {
                1.0 / g[a][a].sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let a = DMatrix::from_fn(n, n, |i, j| g[i][j] * d[i] * d[j]);
    let svd = a.svd(true, true);
    let smax = svd.singular_values.iter().cloned().fold(0.0, f64::max);
    if !(smax.is_finite() && smax > 0.0) {
        return None;
    }
    Some((svd, d, RCOND * smax))
}

/// Solves `G x = rhs` for symmetric positive semi-definite G in the least-squares sense, with
/// the conditioning guard of the module docs. Returns None on a non-finite or zero system.
pub fn solve(g: &[Vec<f64>], rhs: &[f64]) -> Option<Vec<f64>> {
    if rhs.len() != g.len() || rhs.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (svd, d, eps) = equilibrated_svd(g)?;
    let b = DVector::from_iterator(rhs.len(), rhs.iter().zip(&d).map(|(r, s)| r * s));
    let y = svd.solve(&b, eps).ok()?;
    let x: Vec<f64> = y.iter().zip(&d).map(|(v, s)| v * s).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// (Pseudo-)inverse of a symmetric PSD matrix with the conditioning guard of the module docs:
/// the covariance of a fit whose Gram matrix is `g`.
pub fn inverse(g: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let (svd, d, eps) = equilibrated_svd(g)?;
    let p = svd.pseudo_inverse(eps).ok()?;
    let n = g.len();
    let out: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| p[(i, j)] * d[i] * d[j]).collect())
        .collect();
    out.iter().flatten().all(|v| v.is_finite()).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocked Gram matrix is the plain double loop's to the bit (same terms, same order),
    /// with and without a selection, for column counts around the 4-wide unrolling and pixel
    /// counts across several blocks.
    #[test]
    fn blocked_gram_is_bit_identical_to_the_plain_loop() {
        // The short length stays on one thread; the long one, with 9 or more columns, is
        // above PARALLEL_MIN_PRODUCTS and goes to the pool in row groups.
        for len in [3 * BLOCK + 77, 40_077] {
            gram_against_the_plain_loop(len);
        }
    }

    fn gram_against_the_plain_loop(len: usize) {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for n in [1usize, 3, 4, 5, 8, 9, 12, 15, 21, 38] {
            let cols: Vec<Vec<f64>> = (0..n)
                .map(|_| (0..len).map(|_| next() * 1e3).collect())
                .collect();
            let m: Vec<f64> = (0..len).map(|_| next() * 50.0).collect();
            let w: Vec<f64> = (0..len)
                .map(|i| if i % 11 == 0 { 0.0 } else { next() + 0.6 })
                .collect();
            let sel: Vec<bool> = (0..len).map(|i| (i / 5 + i % 3) % 2 == 0).collect();
            let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
            for s in [None, Some(sel.as_slice())] {
                let (g, r) = gram(&refs, &m, &w, s);
                for a in 0..n {
                    for b in a..n {
                        assert_eq!(g[a][b].to_bits(), g[b][a].to_bits());
                        let mut e = 0.0;
                        for i in 0..len {
                            if s.is_none_or(|sl| sl[i]) {
                                e += w[i] * cols[a][i] * cols[b][i];
                            }
                        }
                        assert_eq!(g[a][b].to_bits(), e.to_bits(), "n {n} ({a}, {b})");
                    }
                    let mut e = 0.0;
                    for i in 0..len {
                        if s.is_none_or(|sl| sl[i]) {
                            e += w[i] * cols[a][i] * m[i];
                        }
                    }
                    assert_eq!(r[a].to_bits(), e.to_bits(), "n {n} rhs {a}");
                }
            }
        }
    }

    /// A rectangular block (`products_from` with every row starting at target 0, unit
    /// weights, from -0.0) is the plain `Iterator::sum` of the products to the bit.
    #[test]
    fn rectangular_products_are_the_plain_sums() {
        let len = 2 * BLOCK + 31;
        let col = |k: usize| -> Vec<f64> {
            (0..len)
                .map(|i| ((i * (2 * k + 3) + k) % 97) as f64 * 0.37 - 17.0 + 1e-3 * i as f64)
                .collect()
        };
        let rows: Vec<Vec<f64>> = (0..5).map(col).collect();
        let targets: Vec<Vec<f64>> = (5..14).map(col).collect();
        let r: Vec<&[f64]> = rows.iter().map(|c| c.as_slice()).collect();
        let t: Vec<&[f64]> = targets.iter().map(|c| c.as_slice()).collect();
        let ones = vec![1.0; len];
        let x = products_from(&r, &t, &ones, None, -0.0, |_| 0);
        for (a, ra) in r.iter().enumerate() {
            for (b, tb) in t.iter().enumerate() {
                let e: f64 = ra.iter().zip(tb.iter()).map(|(p, q)| p * q).sum();
                assert_eq!(x[a][b].to_bits(), e.to_bits(), "({a}, {b})");
            }
        }
    }

    #[test]
    fn recovers_exact_coefficients_and_handles_duplicates() {
        let n = 50;
        let c0: Vec<f64> = (0..n).map(|_| 1.0).collect();
        let c1: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let c2: Vec<f64> = (0..n).map(|i| ((i * 7) % 11) as f64).collect();
        let m: Vec<f64> = (0..n).map(|i| 2.0 - 0.5 * c1[i] + 3.0 * c2[i]).collect();
        let w = vec![1.0; n];
        let (g, r) = gram(&[&c0, &c1, &c2], &m, &w, None);
        let x = solve(&g, &r).unwrap();
        assert!(
            (x[0] - 2.0).abs() < 1e-9 && (x[1] + 0.5).abs() < 1e-11 && (x[2] - 3.0).abs() < 1e-10,
            "{x:?}"
        );
        // Duplicate column: the share is split evenly, fitted values still exact.
        let (g, r) = gram(&[&c0, &c1, &c1, &c2], &m, &w, None);
        let x = solve(&g, &r).unwrap();
        assert!((x[1] + x[2] + 0.5).abs() < 1e-9, "{x:?}");
        assert!((x[1] - x[2]).abs() < 1e-9, "{x:?}");
        // Non-finite input is refused, not propagated.
        assert!(solve(&g, &[f64::NAN, 0.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn inverse_is_the_covariance_of_an_independent_reference() {
        // A 3 x 3 SPD matrix with a known inverse (its adjugate over the determinant, by hand).
        let g = vec![
            vec![4.0, 1.0, 0.5],
            vec![1.0, 3.0, 0.25],
            vec![0.5, 0.25, 2.0],
        ];
        let inv = inverse(&g).unwrap();
        for (i, gi) in g.iter().enumerate() {
            for j in 0..3 {
                let p: f64 = gi.iter().zip(&inv).map(|(a, row)| a * row[j]).sum();
                let e = if i == j { 1.0 } else { 0.0 };
                assert!((p - e).abs() < 1e-12, "{i} {j}: {p}");
            }
        }
        // det = 4 (6 - 0.0625) - 1 (2 - 0.125) + 0.5 (0.25 - 1.5) = 23.75 - 1.875 - 0.625.
        let det = 21.25;
        assert!((inv[0][0] - (3.0 * 2.0 - 0.0625) / det).abs() < 1e-12);
        assert!((inv[0][1] + (1.0 * 2.0 - 0.25 * 0.5) / det).abs() < 1e-12);
    }
}
