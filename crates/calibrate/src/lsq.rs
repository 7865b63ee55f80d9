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

/// Relative singular-value cut-off of the equilibrated Gram matrix (see the module docs).
pub const RCOND: f64 = 1e-10;

/// Weighted Gram matrix `G[a][b] = sum_i w_i c_a[i] c_b[i]` and `rhs[a] = sum_i w_i c_a[i] m_i`
/// over the pixels where `sel` is true (all when `None`).
pub fn gram(
    cols: &[&[f64]],
    m: &[f64],
    w: &[f64],
    sel: Option<&[bool]>,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let n = cols.len();
    let mut g = vec![vec![0.0; n]; n];
    let mut rhs = vec![0.0; n];
    let len = m.len();
    // Blocked accumulation keeps the inner loop over pixels contiguous.
    for a in 0..n {
        for b in a..n {
            let (ca, cb) = (cols[a], cols[b]);
            let mut s = 0.0;
            match sel {
                Some(sl) => {
                    for i in 0..len {
                        if sl[i] {
                            s += w[i] * ca[i] * cb[i];
                        }
                    }
                }
                None => {
                    for i in 0..len {
                        s += w[i] * ca[i] * cb[i];
                    }
                }
            }
            g[a][b] = s;
            g[b][a] = s;
        }
        let ca = cols[a];
        let mut s = 0.0;
        for i in 0..len {
            if sel.is_none_or(|sl| sl[i]) {
                s += w[i] * ca[i] * m[i];
            }
        }
        rhs[a] = s;
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
