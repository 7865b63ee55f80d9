//! Least squares for form removal without forming the normal equations.
//!
//! The design matrix [A | z] (one row per valid pixel, p = basis + 1 columns) is reduced block
//! by block with Householder reflections to a p x p upper-triangular R (a streaming "TSQR"),
//! so memory is O(p^2) whatever the map size and the conditioning is that of A, not A^T A.
//! Because R^T R = [A | z]^T [A | z], the small problem on R gives the same solution as the full
//! one. It is then solved by Gram-Schmidt with re-orthogonalisation, dropping any basis column
//! whose remainder is below `DEPENDENCE_TOL` of its norm (for example piston requested together
//! with a Zernike set that already holds it): the residual is still the exact projection onto
//! the span of all requested functions.

/// A column whose part independent of the earlier columns is below this fraction of its norm
/// is treated as linearly dependent and gets a zero coefficient.
pub const DEPENDENCE_TOL: f64 = 1e-9;

/// Upper-triangular factor of a tall matrix with `p` columns, accumulated row block by block.
#[derive(Debug, Clone)]
pub struct StreamingQr {
    p: usize,
    /// Row-major p x p; only the upper triangle is meaningful.
    r: Vec<f64>,
    /// Pending rows, column-major: column j of the block is `block[j * block_rows..]`.
    block: Vec<f64>,
    pending: usize,
    block_rows: usize,
    scratch: Vec<f64>,
}

impl StreamingQr {
    pub fn new(p: usize) -> Self {
        let block_rows = 256;
        StreamingQr {
            p,
            r: vec![0.0; p * p],
            block: vec![0.0; block_rows * p],
            pending: 0,
            block_rows,
            scratch: vec![0.0; block_rows.max(p)],
        }
    }

    /// Adds one row of the design matrix (`row.len() == p`).
    pub fn push_row(&mut self, row: &[f64]) {
        debug_assert_eq!(row.len(), self.p);
        // Column-major block: the reflections below sweep whole columns contiguously.
        for (j, &v) in row.iter().enumerate() {
            self.block[j * self.block_rows + self.pending] = v;
        }
        self.pending += 1;
        if self.pending == self.block_rows {
            self.flush();
        }
    }

    /// Folds another factor's rows (its R) into this one: the TSQR combine step.
    pub fn merge(&mut self, other: StreamingQr) {
        let other_r = other.finish();
        for i in 0..self.p {
            self.push_row(&other_r[i * self.p..(i + 1) * self.p]);
        }
    }

    fn flush(&mut self) {
        let (p, m, stride) = (self.p, self.pending, self.block_rows);
        if m == 0 {
            return;
        }
        let b = &mut self.block;
        let v = &mut self.scratch[..m];
        for k in 0..p {
            let alpha = self.r[k * p + k];
            let col_k = &b[k * stride..k * stride + m];
            let sigma: f64 = col_k.iter().map(|x| x * x).sum();
            if sigma == 0.0 {
                continue;
            }
            let norm = alpha.hypot(sigma.sqrt());
            let beta = if alpha >= 0.0 { -norm } else { norm };
            let v0 = alpha - beta;
            let tau = (beta - alpha) / beta;
            for (vi, &x) in v.iter_mut().zip(col_k) {
                *vi = x / v0;
            }
            for j in k + 1..p {
                let col_j = &mut b[j * stride..j * stride + m];
                let w = tau
                    * (self.r[k * p + j]
                        + v.iter().zip(col_j.iter()).map(|(a, c)| a * c).sum::<f64>());
                self.r[k * p + j] -= w;
                for (c, &vi) in col_j.iter_mut().zip(v.iter()) {
                    *c -= w * vi;
                }
            }
            self.r[k * p + k] = beta;
        }
        self.pending = 0;
    }

    /// The p x p upper-triangular factor (row-major).
    pub fn finish(mut self) -> Vec<f64> {
        self.flush();
        self.r
    }
}

/// Solution of the small problem held in R.
#[derive(Debug, Clone, PartialEq)]
pub struct LsqSolution {
    /// One coefficient per basis column (0 for dropped columns).
    pub coefficients: Vec<f64>,
    /// Indices of basis columns found linearly dependent on earlier ones.
    pub dropped: Vec<usize>,
    /// Norm of the residual z - A c.
    pub residual_norm: f64,
}

/// Solves min |A c - z| from the factor R of [A | z] (p x p, p = basis + 1).
pub fn solve_from_r(r: &[f64], p: usize) -> LsqSolution {
    let nb = p - 1;
    let col = |j: usize| -> Vec<f64> { (0..p).map(|i| r[i * p + j]).collect() };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut q: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    // t[k] holds the Gram-Schmidt coefficients of kept column k against q[0..=k].
    let mut t: Vec<Vec<f64>> = Vec::new();
    let mut dropped = Vec::new();
    for j in 0..nb {
        let a = col(j);
        let norm_a = dot(&a, &a).sqrt();
        let mut v = a;
        let mut coef = vec![0.0; q.len()];
        for _pass in 0..2 {
            for (i, qi) in q.iter().enumerate() {
                let c = dot(qi, &v);
                coef[i] += c;
                for (vk, qk) in v.iter_mut().zip(qi) {
                    *vk -= c * qk;
                }
            }
        }
        let nv = dot(&v, &v).sqrt();
        if norm_a == 0.0 || nv <= DEPENDENCE_TOL * norm_a {
            dropped.push(j);
            continue;
        }
        for vk in v.iter_mut() {
            *vk /= nv;
        }
        coef.push(nv);
        q.push(v);
        t.push(coef);
        kept.push(j);
    }
    let z = col(nb);
    let y: Vec<f64> = q.iter().map(|qi| dot(qi, &z)).collect();
    let proj2: f64 = y.iter().map(|v| v * v).sum();
    let residual_norm = (dot(&z, &z) - proj2).max(0.0).sqrt();
    // Back-substitution: column kept[k] = sum_{i <= k} t[k][i] q_i.
    let nk = kept.len();
    let mut c = vec![0.0; nk];
    for k in (0..nk).rev() {
        let mut s = y[k];
        for (l, cl) in c.iter().enumerate().skip(k + 1) {
            s -= t[l][k] * cl;
        }
        c[k] = s / t[k][k];
    }
    let mut coefficients = vec![0.0; nb];
    for (k, &j) in kept.iter().enumerate() {
        coefficients[j] = c[k];
    }
    LsqSolution {
        coefficients,
        dropped,
        residual_norm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn matches_a_known_fit_and_residual() {
        // z = 2 + 3 x - x^2 + noise on 1000 points; compare with normal equations by brute force.
        let mut rng = Rng::new(3);
        let rows: Vec<[f64; 4]> = (0..1000)
            .map(|i| {
                let x = i as f64 / 999.0 * 2.0 - 1.0;
                [1.0, x, x * x, 2.0 + 3.0 * x - x * x + 0.01 * rng.normal()]
            })
            .collect();
        let mut qr = StreamingQr::new(4);
        for r in &rows {
            qr.push_row(r);
        }
        let sol = solve_from_r(&qr.finish(), 4);
        // Brute-force normal equations (3 x 3 Cramer's rule).
        let mut g = [[0.0; 3]; 3];
        let mut h = [0.0; 3];
        for r in &rows {
            for a in 0..3 {
                h[a] += r[a] * r[3];
                for b in 0..3 {
                    g[a][b] += r[a] * r[b];
                }
            }
        }
        let det = |m: [[f64; 3]; 3]| {
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        };
        let d = det(g);
        for k in 0..3 {
            let mut mk = g;
            for a in 0..3 {
                mk[a][k] = h[a];
            }
            let ck = det(mk) / d;
            assert!(
                (sol.coefficients[k] - ck).abs() < 1e-9,
                "{k}: {} vs {ck}",
                sol.coefficients[k]
            );
        }
        let rss: f64 = rows
            .iter()
            .map(|r| {
                let f: f64 = (0..3).map(|a| r[a] * sol.coefficients[a]).sum();
                (r[3] - f).powi(2)
            })
            .sum();
        assert!((sol.residual_norm - rss.sqrt()).abs() < 1e-9);
        assert!(sol.dropped.is_empty());
    }

    #[test]
    fn duplicate_column_is_dropped_and_merge_equals_one_stream() {
        let rows: Vec<[f64; 4]> = (0..700)
            .map(|i| {
                let x = (i as f64 * 0.37).sin();
                [1.0, x, 1.0, 5.0 - 2.0 * x]
            })
            .collect();
        let mut one = StreamingQr::new(4);
        let mut a = StreamingQr::new(4);
        let mut b = StreamingQr::new(4);
        for (i, r) in rows.iter().enumerate() {
            one.push_row(r);
            if i < 300 {
                a.push_row(r)
            } else {
                b.push_row(r)
            }
        }
        a.merge(b);
        for sol in [solve_from_r(&one.finish(), 4), solve_from_r(&a.finish(), 4)] {
            assert_eq!(sol.dropped, vec![2]);
            assert!((sol.coefficients[0] - 5.0).abs() < 1e-12);
            assert!((sol.coefficients[1] + 2.0).abs() < 1e-12);
            assert!(sol.residual_norm < 1e-10);
        }
    }
}
