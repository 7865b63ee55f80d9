//! A coarse dwell grid for the minimum-dwell solver: the dwell map is parametrised by nodes every
//! `s` fine pixels and spread onto the fine dwell grid by a B-spline (cubic by default, or the
//! bilinear tent), where the residual is always evaluated.
//!
//! Why it can lose little: the TIF is a low-pass filter. When its transfer above the coarse
//! grid's Nyquist frequency is below a tolerance (checked on the fine kernel spectrum, per axis),
//! a dwell map with content above that frequency removes (almost) nothing there, so a map on the
//! coarse nodes reaches nearly the same residual; the transform shrinks by about `s0 * s1`.
//!
//! The model, exact for the spread map: node `k` at fine index `pos(k) = s (k - pad)` spreads its
//! dwell `T_c[k]` (s) over the fine pixels with the spline weights `w(d) = beta(d / s)` of each
//! axis (tent: `1 - |d| / s`, |d| < s; cubic B-spline: |d| < 2 s) divided by `s0 s1` (total
//! dwell kept: the weights sum to `s` per axis). The fine removal at a node is then
//! `sum_k T_c[k] K(pos(m) - pos(k))`, `K = B * spline / (s0 s1)` (B the fine TIF): the coarse
//! TIF is `K` sampled every `s` pixels. Nodes whose spline would leave the fine dwell grid (its
//! border, and the padding that keeps the coarse clear aperture a coarse TIF half-width inside
//! the coarse grid) are held at zero dwell. The cubic spline's images of the node lattice are
//! weaker than the tent's by about the square.
//!
//! The coarse problem: the desired removal low-passed below the coarse Nyquist frequency (no
//! aliased noise), sampled at the nodes less than one node spacing from a fine CA pixel (so
//! the CA's edge pixels lie between constrained nodes). What it approximates: the least squares
//! over those nodes instead of the fine CA pixels. Defect correction (optional) feeds the fine
//! gradient back: after a coarse solve, the fine objective's gradient (exact, fine FFTs) is
//! restricted to the nodes as a linear term, and a few coarse healing passes correct the map.

use ndarray::Array2;

use rustfft::num_complex::Complex;

use super::DwellProblem;
use crate::error::ProcessError;
use crate::fft::Fft2;
use crate::tif::Tif;

/// One axis of the coarse grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Axis {
    /// Coarsening factor (fine pixels per node).
    pub(crate) s: usize,
    /// Support half-width of a node's spline, in nodes (1: tent, 2: cubic B-spline).
    order: usize,
    /// Nodes before fine index 0.
    pad: usize,
    /// Nodes on this axis.
    pub(crate) n: usize,
    /// Fine pixels on this axis.
    n_fine: usize,
}

impl Axis {
    /// The node indices and spline weights (not normalised; 0 when unused) of fine index `i`:
    /// the `2 order` nodes around it.
    fn weights(&self, i: usize) -> [(usize, f64); 4] {
        let k = i / self.s + self.pad;
        let f = (i % self.s) as f64 / self.s as f64;
        let mut w = [(k, 0.0); 4];
        for (n, slot) in w.iter_mut().take(2 * self.order).enumerate() {
            // Node k + m, m = n - (order - 1), at distance f - m nodes.
            let m = n as f64 - (self.order - 1) as f64;
            *slot = (k + n + 1 - self.order, spline(self.order, f - m));
        }
        w
    }

    /// Fine index of node `k`, if inside the fine grid.
    fn pos(&self, k: usize) -> Option<usize> {
        let p = (k as isize - self.pad as isize) * self.s as isize;
        (p >= 0 && (p as usize) < self.n_fine).then_some(p as usize)
    }

    /// Whether node `k`'s whole tent lies on the fine grid (only those nodes carry dwell, so
    /// the prolongation keeps every node's dwell and the coarse model is exact).
    fn whole(&self, k: usize) -> bool {
        let r = self.order * self.s;
        self.pos(k)
            .is_some_and(|p| p + 1 >= r && p + r <= self.n_fine)
    }

    /// An axis of factor `s` over `n_fine` pixels whose clear aperture spans fine indices
    /// `lo..=hi`, padded so that the aperture's nodes lie `hc` nodes inside.
    fn new(s: usize, order: usize, n_fine: usize, lo: usize, hi: usize, hc: usize) -> Axis {
        // Unpadded nodes k = 0.. at fine k s; a node touches the aperture when
        // |pos - i| < order s.
        let r = order * s;
        let n_in = (n_fine - 1) / s + 1;
        let first = (lo + 1).saturating_sub(r).div_ceil(s);
        let last = (hi + r - 1) / s;
        // Fine index i reads nodes i / s - (order - 1) ..= i / s + order.
        let pad = hc.saturating_sub(first).max(order - 1);
        Axis {
            s,
            order,
            pad,
            n: pad + (n_in + order).max(last + hc + 1),
            n_fine,
        }
    }
}

/// The coarse dwell grid of a fine problem, its coarse problem and the transfer operators.
pub(crate) struct CoarseGrid {
    pub(crate) rows: Axis,
    pub(crate) cols: Axis,
    /// The coarse problem (its desired removal is the tent average of the fine one).
    pub(crate) problem: DwellProblem,
    /// Nodes whose tent lies on the fine dwell grid (the others are held at zero).
    pub(crate) free: Array2<bool>,
}

/// The largest factors (rows, cols) up to `max` whose coarse Nyquist band the TIF passes with at
/// most `tol` of its peak transfer, from the fine kernel spectrum (transposed half spectrum of an
/// `n0 x n1` transform).
pub(crate) fn factors(
    spec: &[rustfft::num_complex::Complex<f64>],
    n0: usize,
    n1: usize,
    max: usize,
    tol: f64,
) -> (usize, usize) {
    let peak = spec.iter().fold(0.0f64, |m, k| m.max(k.norm()));
    // Largest transfer at or above each frequency (cycles per fine pixel), per axis.
    let mut above0 = vec![0.0f64; n0 / 2 + 1];
    let mut above1 = vec![0.0f64; n1 / 2 + 1];
    for (idx, k) in spec.iter().enumerate() {
        let (k1, k0) = (idx / n0, idx % n0);
        let k0 = k0.min(n0 - k0);
        let a = k.norm();
        above0[k0] = above0[k0].max(a);
        above1[k1.min(n1 / 2)] = above1[k1.min(n1 / 2)].max(a);
    }
    for v in [&mut above0, &mut above1] {
        for i in (0..v.len().saturating_sub(1)).rev() {
            v[i] = v[i].max(v[i + 1]);
        }
    }
    let pick = |above: &[f64], n: usize| {
        let mut best = 1;
        for s in 2..=max.max(1) {
            // First frequency index at or above the coarse Nyquist n / (2 s).
            let k = (n as f64 / (2.0 * s as f64)).ceil() as usize;
            if k < above.len() && above[k] <= tol * peak {
                best = s;
            }
        }
        best
    };
    (pick(&above0, n0), pick(&above1, n1))
}

impl CoarseGrid {
    /// The coarse grid of `p` with factors `(s0, s1)` (rows, cols); `None` when both are 1.
    pub(crate) fn new(
        p: &DwellProblem,
        s0: usize,
        s1: usize,
        order: usize,
    ) -> Result<Option<CoarseGrid>, ProcessError> {
        if s0 <= 1 && s1 <= 1 {
            return Ok(None);
        }
        let (s0, s1) = (s0.max(1), s1.max(1));
        let (r, c) = p.dim();
        let (mut rlo, mut rhi, mut clo, mut chi) = (usize::MAX, 0, usize::MAX, 0);
        for ((i, j), &a) in p.aperture.indexed_iter() {
            if a {
                rlo = rlo.min(i);
                rhi = rhi.max(i);
                clo = clo.min(j);
                chi = chi.max(j);
            }
        }
        // Coarse TIF: K = B * spline / (s0 s1) sampled every s pixels.
        let (h0, h1) = p.tif.half_widths();
        let (hc0, hc1) = ((h0 + order * s0 - 1) / s0, (h1 + order * s1 - 1) / s1);
        let mut k = Array2::zeros((2 * hc0 + 1, 2 * hc1 + 1));
        let norm = 1.0 / (s0 * s1) as f64;
        for ((a, b), &v) in p.tif.rate_nm_per_s.indexed_iter() {
            if v == 0.0 {
                continue;
            }
            // Offset u = (a - h0, b - h1); node offsets m with |s m - u| < order s.
            let (u0, u1) = (a as isize - h0 as isize, b as isize - h1 as isize);
            let (o0, o1) = (order as isize, order as isize);
            for m0 in u0.div_euclid(s0 as isize) - o0 + 1..=u0.div_euclid(s0 as isize) + o0 {
                let w0 = spline(order, (u0 - s0 as isize * m0) as f64 / s0 as f64);
                if w0 <= 0.0 || m0.unsigned_abs() > hc0 {
                    continue;
                }
                for m1 in u1.div_euclid(s1 as isize) - o1 + 1..=u1.div_euclid(s1 as isize) + o1 {
                    let w1 = spline(order, (u1 - s1 as isize * m1) as f64 / s1 as f64);
                    if w1 <= 0.0 || m1.unsigned_abs() > hc1 {
                        continue;
                    }
                    let idx = ((m0 + hc0 as isize) as usize, (m1 + hc1 as isize) as usize);
                    k[idx] += v * w0 * w1 * norm;
                }
            }
        }
        let tif = Tif::new(k, p.tif.dx_mm * s1 as f64, p.tif.dy_mm * s0 as f64)?;
        let rows = Axis::new(s0, order, r, rlo, rhi, hc0);
        let cols = Axis::new(s1, order, c, clo, chi, hc1);
        let (n0, n1) = (rows.n, cols.n);
        let free = Array2::from_shape_fn((n0, n1), |(k, l)| rows.whole(k) && cols.whole(l));
        // The coarse clear aperture: nodes on fine CA pixels; the coarse desired removal: the
        // fine one low-passed below the coarse Nyquist frequency, sampled there.
        let zl = lowpass(&p.desired_nm, s0, s1);
        // A node is in the coarse CA when a fine CA pixel lies less than a node spacing away
        // (per axis), so that every fine CA pixel lies between constrained nodes.
        let near = |i: usize, j: usize| {
            let (i0, i1) = (i.saturating_sub(s0 - 1), (i + s0).min(r));
            let (j0, j1) = (j.saturating_sub(s1 - 1), (j + s1).min(c));
            (i0..i1).any(|a| (j0..j1).any(|b| p.aperture[(a, b)]))
        };
        let on = |k: usize, l: usize| match (rows.pos(k), cols.pos(l)) {
            (Some(i), Some(j)) if near(i, j) => Some((i, j)),
            _ => None,
        };
        let aperture = Array2::from_shape_fn((n0, n1), |(k, l)| on(k, l).is_some());
        let desired = Array2::from_shape_fn((n0, n1), |(k, l)| on(k, l).map_or(0.0, |ij| zl[ij]));
        let problem = DwellProblem::new(desired, aperture, tif)?;
        Ok(Some(CoarseGrid {
            rows,
            cols,
            problem,
            free,
        }))
    }

    /// The fine dwell map (on the fine dwell grid) of a coarse one.
    pub(crate) fn prolong(&self, tc: &Array2<f64>) -> Array2<f64> {
        let norm = 1.0 / (self.rows.s * self.cols.s) as f64;
        let cw: Vec<[(usize, f64); 4]> = (0..self.cols.n_fine)
            .map(|j| self.cols.weights(j))
            .collect();
        Array2::from_shape_fn((self.rows.n_fine, self.cols.n_fine), |(i, j)| {
            let mut v = 0.0;
            for (k, wk) in self.rows.weights(i) {
                if wk == 0.0 {
                    continue;
                }
                for &(l, wl) in &cw[j] {
                    v += wk * wl * tc[(k, l)];
                }
            }
            v * norm
        })
    }

    /// The adjoint of [`Self::prolong`]: `sum_i w(i - pos(k)) x[i] / (s0 s1)`.
    pub(crate) fn prolong_adjoint(&self, fine: &Array2<f64>) -> Array2<f64> {
        restrict_raw(&self.rows, &self.cols, fine, None) / (self.rows.s * self.cols.s) as f64
    }
}

/// Start of the restriction's cosine taper, as a fraction of the coarse Nyquist frequency (case
/// B at s = 5: 0.5, 0.8 and 0.95 gave the same fine residual to 1e-4 nm).
const LOWPASS_FROM: f64 = 0.8;

/// `z` low-passed below the Nyquist frequency of a grid coarser by `(s0, s1)`: even mirror
/// extension (no jump at the edges), then a separable window, 1 below `LOWPASS_FROM` of the
/// coarse Nyquist frequency and a cosine taper to 0 at it.
fn lowpass(z: &Array2<f64>, s0: usize, s1: usize) -> Array2<f64> {
    let (r, c) = z.dim();
    let (n0, n1) = (2 * r, 2 * c);
    let fft = Fft2::new(n0, n1);
    let mut real = vec![0.0; n0 * n1];
    for i in 0..n0 {
        let si = if i < r { i } else { n0 - 1 - i };
        for j in 0..n1 {
            let sj = if j < c { j } else { n1 - 1 - j };
            real[i * n1 + j] = z[(si, sj)];
        }
    }
    let from = LOWPASS_FROM;
    let window = |k: usize, n: usize, s: usize| -> f64 {
        if s <= 1 {
            return 1.0;
        }
        let f = k.min(n - k) as f64 / n as f64;
        let fn_ = 0.5 / s as f64;
        if f <= from * fn_ {
            1.0
        } else if f >= fn_ {
            0.0
        } else {
            let x = (f - from * fn_) / ((1.0 - from) * fn_);
            0.5 * (1.0 + (std::f64::consts::PI * x).cos())
        }
    };
    let len = fft.spectrum_len();
    let mut tmp = vec![Complex::new(0.0, 0.0); len];
    let mut spec = tmp.clone();
    fft.forward(&mut real, &mut tmp, &mut spec);
    let w0: Vec<f64> = (0..n0).map(|k| window(k, n0, s0)).collect();
    for (idx, v) in spec.iter_mut().enumerate() {
        *v *= w0[idx % n0] * window(idx / n0, n1, s1);
    }
    fft.inverse(&mut spec, &mut tmp, &mut real);
    Array2::from_shape_fn((r, c), |(i, j)| real[i * n1 + j])
}

/// The B-spline of degree `2 order - 1` (1: tent, 2: cubic) at `x` nodes from its centre,
/// 1 (tent) or 2/3 (cubic) at 0; its samples at spacing 1/s sum to s.
fn spline(order: usize, x: f64) -> f64 {
    let x = x.abs();
    if order == 1 {
        (1.0 - x).max(0.0)
    } else if x < 1.0 {
        2.0 / 3.0 - x * x + 0.5 * x * x * x
    } else if x < 2.0 {
        (2.0 - x).powi(3) / 6.0
    } else {
        0.0
    }
}

/// `sum_i w(i - pos(k)) x[i]` over the fine pixels (where `mask` holds, if given).
fn restrict_raw(
    rows: &Axis,
    cols: &Axis,
    x: &Array2<f64>,
    mask: Option<&Array2<bool>>,
) -> Array2<f64> {
    let mut out = Array2::zeros((rows.n, cols.n));
    let cw: Vec<[(usize, f64); 4]> = (0..cols.n_fine).map(|j| cols.weights(j)).collect();
    for ((i, j), &v) in x.indexed_iter() {
        if v == 0.0 || mask.is_some_and(|m| !m[(i, j)]) {
            continue;
        }
        for (k, wk) in rows.weights(i) {
            for &(l, wl) in &cw[j] {
                out[(k, l)] += wk * wl * v;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fft::convolve_direct;

    /// The coarse TIF applied to node dwell equals the fine TIF applied to the prolonged map,
    /// at every node inside the coarse clear aperture (exact model), for both factors and an
    /// aperture whose edges fall between nodes.
    #[test]
    fn coarse_model_is_the_fine_model_at_the_nodes() {
        let mut rng = bonnetlab_surface::rng::Rng::new(3);
        let tif = Tif::gaussian(1.0, 7.0, 2.0, 0.5, 0.5).unwrap();
        let (h0, h1) = tif.half_widths();
        let (r, c) = (23 + 2 * h0, 31 + 2 * h1);
        let z = Array2::from_shape_fn((r, c), |_| rng.normal());
        let a = Array2::from_shape_fn((r, c), |(i, j)| {
            (h0 + 1..r - h0).contains(&i) && (h1..c - h1 - 2).contains(&j)
        });
        let p = DwellProblem::new(z, a, tif).unwrap();
        for (s0, s1, order) in [(2, 3, 1), (3, 2, 1), (4, 4, 1), (2, 3, 2), (3, 3, 2)] {
            let g = CoarseGrid::new(&p, s0, s1, order).unwrap().unwrap();
            let tc =
                Array2::from_shape_fn(
                    g.free.dim(),
                    |ij| {
                        if g.free[ij] {
                            rng.uniform()
                        } else {
                            0.0
                        }
                    },
                );
            let fine = convolve_direct(g.prolong(&tc).view(), p.tif.rate_nm_per_s.view());
            let coarse = convolve_direct(tc.view(), g.problem.tif.rate_nm_per_s.view());
            let scale = coarse.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut n = 0;
            for ((k, l), &m) in g.problem.aperture.indexed_iter() {
                let (Some(i), Some(j)) = (g.rows.pos(k), g.cols.pos(l)) else {
                    continue;
                };
                if m && p.aperture[(i, j)] {
                    n += 1;
                    let e = (fine[(i, j)] - coarse[(k, l)]).abs();
                    assert!(e < 1e-12 * scale, "{s0} x {s1} ({order}) at {k},{l}: {e}");
                }
            }
            assert!(n > 10);
            // The adjoint is the transpose.
            let x = Array2::from_shape_fn((r, c), |_| rng.normal());
            let lhs: f64 = g.prolong(&tc).iter().zip(&x).map(|(a, b)| a * b).sum();
            let rhs: f64 = g
                .prolong_adjoint(&x)
                .iter()
                .zip(&tc)
                .map(|(a, b)| a * b)
                .sum();
            assert!((lhs - rhs).abs() < 1e-12 * lhs.abs().max(1.0));
            // Total dwell is kept by the prolongation.
            assert!((g.prolong(&tc).sum() - tc.sum()).abs() < 1e-9 * tc.sum());
        }
    }
}
