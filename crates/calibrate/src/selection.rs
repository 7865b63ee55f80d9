//! Hold-out selection of effects.
//!
//! The analysis pixels are cut into square blocks (about a tenth of the shorter map side, at
//! least 4 pixels) coloured like a checkerboard: half A and half B. A candidate is fitted
//! (jointly with the current model) on one half and scored on the other, both ways (two-fold).
//! Per block b of the scoring half, `d_b = SSE_without - SSE_with` (squared residuals of the
//! current model vs the model with the candidate, each fitted on the other half). The held-out
//! reduction is `Delta = sum_b d_b`; its standard error is `sqrt(n_b) * sd(d_b)` (blocks as the
//! independent units, so spatially correlated residuals do not overstate significance).
//! The block sign test (share of blocks where the candidate helps; z = (n_+ - n/2) / sqrt(n/4))
//! is the robust alternative when a few blocks dominate the variance; `z` is the larger of the
//! two. A candidate is significant when `z >= Z_MIN` and `Delta` is at least `MIN_FRACTION`
//! of the held-out SSE of the current model. Under pure noise a fitted extra column can only
//! lose on held-out data on average, so noise yields no accepted effect.

use crate::lsq;
use crate::model::{Eval, Problem};

/// Significance threshold on the held-out z statistic.
pub const Z_MIN: f64 = 4.0;
/// Minimum held-out reduction as a fraction of the held-out residual sum of squares.
pub const MIN_FRACTION: f64 = 0.005;

pub struct Split {
    pub half_a: Vec<bool>,
    pub block: Vec<usize>,
    pub n_blocks: usize,
}

pub fn split(p: &Problem) -> Split {
    let g = &p.grid;
    let b = (g.rows.min(g.cols) / 10).max(4);
    let nbc = g.cols.div_ceil(b);
    let nbr = g.rows.div_ceil(b);
    let mut half_a = Vec::with_capacity(p.idx.len());
    let mut block = Vec::with_capacity(p.idx.len());
    for &k in &p.idx {
        let (i, j) = (k / g.cols, k % g.cols);
        let (bi, bj) = (i / b, j / b);
        half_a.push((bi + bj) % 2 == 0);
        block.push(bi * nbc + bj);
    }
    Split {
        half_a,
        block,
        n_blocks: nbr * nbc,
    }
}

/// Gram matrices of the current columns on each half (reused for every candidate of a round).
pub struct BaseGram {
    g: [Vec<Vec<f64>>; 2],
    r: [Vec<f64>; 2],
    sel: [Vec<bool>; 2],
}

pub fn base_gram(ev: &Eval, sp: &Split) -> BaseGram {
    let cols: Vec<&[f64]> = ev.cols.iter().map(|c| c.as_slice()).collect();
    let sa: Vec<bool> = sp.half_a.clone();
    let sb: Vec<bool> = sp.half_a.iter().map(|v| !v).collect();
    let (ga, ra) = lsq::gram(&cols, &ev.m, &ev.w, Some(&sa));
    let (gb, rb) = lsq::gram(&cols, &ev.m, &ev.w, Some(&sb));
    BaseGram {
        g: [ga, gb],
        r: [ra, rb],
        sel: [sa, sb],
    }
}

#[derive(Debug, Clone, Copy, Default)]
pub struct Score {
    /// Held-out reduction of the sum of squares (nm^2), both folds.
    pub delta: f64,
    pub z: f64,
    pub fraction: f64,
}

impl Score {
    pub fn significant(&self) -> bool {
        self.z >= Z_MIN && self.fraction >= MIN_FRACTION && self.delta > 0.0
    }
}

fn dot_sel(a: &[f64], b: &[f64], w: &[f64], sel: &[bool]) -> f64 {
    let mut s = 0.0;
    for i in 0..a.len() {
        if sel[i] {
            s += w[i] * a[i] * b[i];
        }
    }
    s
}

/// Two-fold held-out score of adding `extra` columns to the current model.
// Index loops fill a symmetric Gram matrix; iterators would hide the (row, column) pairing.
#[allow(clippy::needless_range_loop)]
pub fn holdout(ev: &Eval, extra: &[Vec<f64>], sp: &Split, bg: &BaseGram) -> Score {
    let nb = ev.cols.len();
    let ne = extra.len();
    let mut d = vec![0.0; sp.n_blocks];
    let mut sse_base = 0.0;
    for fold in 0..2 {
        let sel = &bg.sel[fold];
        // Full Gram = base + cross terms with the extra columns.
        let n = nb + ne;
        let mut g = vec![vec![0.0; n]; n];
        let mut r = vec![0.0; n];
        for a in 0..nb {
            g[a][..nb].copy_from_slice(&bg.g[fold][a]);
            r[a] = bg.r[fold][a];
        }
        for e in 0..ne {
            for a in 0..nb {
                let v = dot_sel(&extra[e], &ev.cols[a], &ev.w, sel);
                g[nb + e][a] = v;
                g[a][nb + e] = v;
            }
            for f in e..ne {
                let v = dot_sel(&extra[e], &extra[f], &ev.w, sel);
                g[nb + e][nb + f] = v;
                g[nb + f][nb + e] = v;
            }
            r[nb + e] = dot_sel(&extra[e], &ev.m, &ev.w, sel);
        }
        let base_g: Vec<Vec<f64>> = g[..nb].iter().map(|row| row[..nb].to_vec()).collect();
        let (Some(cb), Some(cf)) = (lsq::solve(&base_g, &r[..nb]), lsq::solve(&g, &r)) else {
            return Score::default();
        };
        // Score on the other half.
        let test = &bg.sel[1 - fold];
        for i in 0..ev.m.len() {
            if !test[i] || ev.w[i] == 0.0 {
                continue;
            }
            let pb: f64 = cb.iter().zip(&ev.cols).map(|(c, col)| c * col[i]).sum();
            let mut pf: f64 = cf[..nb]
                .iter()
                .zip(&ev.cols)
                .map(|(c, col)| c * col[i])
                .sum();
            for e in 0..ne {
                pf += cf[nb + e] * extra[e][i];
            }
            let (eb, ef) = (ev.m[i] - pb, ev.m[i] - pf);
            d[sp.block[i]] += eb * eb - ef * ef;
            sse_base += eb * eb;
        }
    }
    let used: Vec<f64> = d.iter().cloned().filter(|v| *v != 0.0).collect();
    let nbk = used.len() as f64;
    if nbk < 4.0 {
        return Score::default();
    }
    let delta: f64 = used.iter().sum();
    let mean = delta / nbk;
    let var = used.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nbk - 1.0);
    let se = (var * nbk).sqrt().max(1e-300);
    let z_mean = delta / se;
    // Sign test over blocks: robust when a few blocks (edges, defects) dominate the variance.
    let n_pos = used.iter().filter(|v| **v > 0.0).count() as f64;
    let z_sign = (n_pos - 0.5 * nbk) / (0.25 * nbk).sqrt();
    Score {
        delta,
        z: z_mean.max(z_sign),
        fraction: delta / sse_base.max(1e-300),
    }
}
