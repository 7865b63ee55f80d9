//! Small dense linear solves for the fits of this crate (at most a handful of unknowns).

/// Solves `a x = b` (row-major n x n) by Gaussian elimination with partial pivoting.
/// Returns `None` when the matrix is singular relative to its scale.
pub(crate) fn solve(mut a: Vec<f64>, mut b: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    if a.len() != n * n || b.len() != n {
        return None;
    }
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..n {
        let piv =
            (col..n).max_by(|&p, &q| a[p * n + col].abs().total_cmp(&a[q * n + col].abs()))?;
        if a[piv * n + col].abs() <= scale * 1e-14 {
            return None;
        }
        if piv != col {
            for k in 0..n {
                a.swap(piv * n + k, col * n + k);
            }
            b.swap(piv, col);
        }
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            for k in col..n {
                a[row * n + k] -= f * a[col * n + k];
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let mut s = b[row];
        for k in row + 1..n {
            s -= a[row * n + k] * x[k];
        }
        x[row] = s / a[row * n + row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Least squares `min |A x - y|` through the normal equations; `rows` yields each row of A
/// with its target.
pub(crate) fn least_squares<'a>(
    rows: impl Iterator<Item = (&'a [f64], f64)>,
    n: usize,
) -> Option<Vec<f64>> {
    let mut ata = vec![0.0; n * n];
    let mut atb = vec![0.0; n];
    for (r, y) in rows {
        for p in 0..n {
            atb[p] += r[p] * y;
            for q in 0..n {
                ata[p * n + q] += r[p] * r[q];
            }
        }
    }
    solve(ata, atb, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_permuted_system_and_rejects_singular() {
        let a = vec![0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0];
        let x = [1.5, -2.0, 0.25];
        let b: Vec<f64> = (0..3)
            .map(|r| (0..3).map(|c| a[r * 3 + c] * x[c]).sum())
            .collect();
        let got = solve(a, b, 3).unwrap();
        for k in 0..3 {
            assert!((got[k] - x[k]).abs() < 1e-12);
        }
        assert!(solve(vec![1.0, 2.0, 2.0, 4.0], vec![1.0, 2.0], 2).is_none());
    }

    #[test]
    fn least_squares_recovers_a_line() {
        let rows: Vec<([f64; 2], f64)> = (0..10)
            .map(|i| ([1.0, i as f64], 3.0 - 0.5 * i as f64))
            .collect();
        let c = least_squares(rows.iter().map(|(r, y)| (&r[..], *y)), 2).unwrap();
        assert!((c[0] - 3.0).abs() < 1e-12 && (c[1] + 0.5).abs() < 1e-12);
    }
}
