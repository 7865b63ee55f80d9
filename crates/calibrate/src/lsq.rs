//! Small dense least squares on compressed pixel vectors: weighted Gram matrices, a symmetric
//! solve with column equilibration (and a tiny ridge so exactly collinear columns do not abort a
//! fit), residuals and the inverse for covariances.

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

/// Solves `G x = rhs` for symmetric positive semi-definite G. Columns are equilibrated by
/// sqrt(diag); a relative ridge of 1e-10 keeps exactly dependent columns finite (their share is
/// split, the fitted values are unaffected). Returns None on a non-finite system.
pub fn solve(g: &[Vec<f64>], rhs: &[f64]) -> Option<Vec<f64>> {
    let inv = inverse(g)?;
    Some(
        (0..rhs.len())
            .map(|a| (0..rhs.len()).map(|b| inv[a][b] * rhs[b]).sum())
            .collect(),
    )
}

/// Inverse of a symmetric PSD matrix (equilibrated, tiny ridge), by Gauss-Jordan with pivoting.
pub fn inverse(g: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = g.len();
    let d: Vec<f64> = (0..n)
        .map(|a| {
            if g[a][a] > 0.0 {
                1.0 / g[a][a].sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let mut a: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let mut row: Vec<f64> = (0..n).map(|j| g[i][j] * d[i] * d[j]).collect();
            row[i] += 1e-10;
            row.extend((0..n).map(|j| if i == j { 1.0 } else { 0.0 }));
            row
        })
        .collect();
    for c in 0..n {
        let p = (c..n).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if !a[p][c].is_finite() || a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        let piv = a[c][c];
        for v in a[c].iter_mut() {
            *v /= piv;
        }
        for r in 0..n {
            if r != c {
                let f = a[r][c];
                if f != 0.0 {
                    let pivot_row = a[c].clone();
                    for (ark, ack) in a[r].iter_mut().zip(&pivot_row).take(2 * n) {
                        *ark -= f * ack;
                    }
                }
            }
        }
    }
    let out: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| a[i][n + j] * d[i] * d[j]).collect())
        .collect();
    if out.iter().flatten().all(|v| v.is_finite()) {
        Some(out)
    } else {
        None
    }
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
            (x[0] - 2.0).abs() < 1e-6 && (x[1] + 0.5).abs() < 1e-8 && (x[2] - 3.0).abs() < 1e-8
        );
        // duplicate column: fitted values still exact
        let (g, r) = gram(&[&c0, &c1, &c1, &c2], &m, &w, None);
        let x = solve(&g, &r).unwrap();
        assert!((x[1] + x[2] + 0.5).abs() < 1e-6);
    }
}
