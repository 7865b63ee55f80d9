//! The line sums of the 1-D PSDs in one pass per direction, with a fast path for lines that
//! have no invalid pixel (on most maps: all of them).
//!
//! A fully valid line needs no gap filling and no segmenting, and its mean is known from
//! `HeightSums` before it is read, so it is read once straight from the map: model subtraction,
//! mean removal and windowing are one fused loop writing the FFT input, and |Z_k|^2 goes into
//! the chunk's running sum (scaled once per chunk). Lines with invalid pixels, and every line
//! when the detrend is linear, go through `LineWorker::add_line` with the segment rules of
//! `lines`, unchanged.
//!
//! - X (rows): the row is contiguous; the same pass can accumulate the height moments of the
//!   residual (`StatsAcc`) so that height statistics cost no extra pass over the map.
//! - Y (columns): blocks of `COL_BLOCK` adjacent columns are gathered row by row (each row read
//!   is one contiguous run of the block) into per-column buffers whose strides are padded by a
//!   cache line so the block's write streams do not alias in the L1 cache; each buffer is then
//!   the FFT input. No transposed copy of the map is made.
//!
//! Lines are processed in fixed chunks whose partial sums are added in chunk order, so the
//! result does not depend on the number of threads.

use rayon::prelude::*;
use realfft::RealFftPlanner;

use bonnetlab_surface::HeightStats;

use crate::form::PlaneModel;
use crate::lines::{Detrend, LineRules, LineSums, LineWorker};
use crate::scan::{HeightSums, MaskSummary};

/// Rows per chunk of the X pass.
const ROW_CHUNK: usize = 32;
/// Columns gathered together in the Y pass (16 x 8 bytes: two cache lines of every row).
const COL_BLOCK: usize = 64;
/// Padding of the Y buffers' stride, in f64 (one cache line).
const STRIDE_PAD: usize = 8;

/// Rows ahead of the Y gather whose block segments are prefetched.
const PREFETCH_ROWS: usize = 16;

/// Hints the CPU to start loading the cache line of `data[k]` (nothing when k is out of range
/// or the target has no prefetch instruction).
#[inline(always)]
fn prefetch(data: &[f64], k: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = data.get(k) {
        // SAFETY: a prefetch is a hint: it never faults, writes nothing and its pointer comes
        // from a live element of `data`.
        unsafe {
            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                (v as *const f64).cast::<i8>(),
            )
        };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, k);
}

/// A prepared map as the passes read it: contiguous row-major heights and mask, the model to
/// subtract (if any), and the scans of `scan`.
pub(crate) struct MapView<'a> {
    pub heights: &'a [f64],
    pub valid: &'a [bool],
    pub rows: usize,
    pub cols: usize,
    pub model: Option<&'a PlaneModel>,
    pub mask: &'a MaskSummary,
    pub sums: &'a HeightSums,
}

impl MapView<'_> {
    fn row(&self, i: usize) -> (&[f64], &[bool]) {
        let r = i * self.cols..(i + 1) * self.cols;
        (&self.heights[r.clone()], &self.valid[r])
    }

    /// The model along row i as q0 + q1 u + q2 u^2.
    fn row_poly(&self, i: usize) -> [f64; 3] {
        self.model.map_or([0.0; 3], |m| m.row_poly(i))
    }

    fn us(&self) -> Vec<f64> {
        match self.model {
            Some(m) => m.us().to_vec(),
            None => vec![0.0; self.cols],
        }
    }
}

/// Running height moments of the residual about a reference height `mu` (the residual mean
/// known from the fit), four lanes each so the compiler can keep them in vector registers.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StatsAcc {
    count: usize,
    s1: [f64; 4],
    s2: [f64; 4],
    s3: [f64; 4],
    s4: [f64; 4],
    sa: [f64; 4],
    lo: [f64; 4],
    hi: [f64; 4],
}

impl StatsAcc {
    pub fn new() -> Self {
        StatsAcc {
            count: 0,
            s1: [0.0; 4],
            s2: [0.0; 4],
            s3: [0.0; 4],
            s4: [0.0; 4],
            sa: [0.0; 4],
            lo: [f64::INFINITY; 4],
            hi: [f64::NEG_INFINITY; 4],
        }
    }

    #[inline(always)]
    fn push(&mut self, l: usize, d: f64) {
        let d2 = d * d;
        self.s1[l] += d;
        self.s2[l] += d2;
        self.s3[l] += d2 * d;
        self.s4[l] += d2 * d2;
        self.sa[l] += d.abs();
        self.lo[l] = self.lo[l].min(d);
        self.hi[l] = self.hi[l].max(d);
    }

    pub fn add(&mut self, o: &StatsAcc) {
        self.count += o.count;
        for l in 0..4 {
            self.s1[l] += o.s1[l];
            self.s2[l] += o.s2[l];
            self.s3[l] += o.s3[l];
            self.s4[l] += o.s4[l];
            self.sa[l] += o.sa[l];
            self.lo[l] = self.lo[l].min(o.lo[l]);
            self.hi[l] = self.hi[l].max(o.hi[l]);
        }
    }

    /// Height parameters as `bonnetlab_surface::height_stats` defines them (about the mean of
    /// the valid residual heights). The moments about `mu` are shifted to the exact mean; the
    /// shift is rounding-sized, so Sa (not a polynomial moment) keeps its value about `mu`.
    pub fn finish(&self, mu: f64) -> Option<HeightStats> {
        if self.count == 0 {
            return None;
        }
        let n = self.count as f64;
        let sum = |a: &[f64; 4]| (a[0] + a[1]) + (a[2] + a[3]);
        let m1 = sum(&self.s1) / n;
        let m2 = sum(&self.s2) / n;
        let m3 = sum(&self.s3) / n;
        let m4 = sum(&self.s4) / n;
        let var = (m2 - m1 * m1).max(0.0);
        let c3 = m3 - 3.0 * m1 * m2 + 2.0 * m1 * m1 * m1;
        let c4 = m4 - 4.0 * m1 * m3 + 6.0 * m1 * m1 * m2 - 3.0 * m1 * m1 * m1 * m1;
        let rms = var.sqrt();
        let (ssk, sku) = if var > 0.0 {
            (Some(c3 / (var * rms)), Some(c4 / (var * var)))
        } else {
            (None, None)
        };
        let lo = self.lo.iter().copied().fold(f64::INFINITY, f64::min) - m1;
        let hi = self.hi.iter().copied().fold(f64::NEG_INFINITY, f64::max) - m1;
        Some(HeightStats {
            valid: self.count,
            mean_nm: mu + m1,
            pv_nm: hi - lo,
            rms_nm: rms,
            sa_nm: sum(&self.sa) / n,
            sp_nm: hi,
            sv_nm: -lo + 0.0,
            sz_nm: hi - lo,
            ssk,
            sku,
        })
    }
}

/// Whether fully valid lines of length n may take the fast path.
fn dense_ok(rules: &LineRules, n: usize) -> bool {
    rules.detrend == Detrend::Mean && n >= rules.min_len
}

/// Sums the segment periodograms of all rows (X lines); with `stats_mu`, also the height
/// moments of every valid residual pixel about that height.
pub(crate) fn sum_rows(
    map: &MapView,
    rules: LineRules,
    stats_mu: Option<f64>,
) -> (LineSums, Option<StatsAcc>) {
    let (rows, n) = (map.rows, map.cols);
    let nbins = n / 2 + 1;
    let plan = RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let w = rules.window.coefficients(n);
    let us = map.us();
    let ubar = us.iter().sum::<f64>() / n as f64;
    let u2bar = us.iter().map(|u| u * u).sum::<f64>() / n as f64;
    let fast = dense_ok(&rules, n);
    let chunks: Vec<usize> = (0..rows.div_ceil(ROW_CHUNK)).collect();
    let partial: Vec<(LineSums, StatsAcc)> = chunks
        .par_iter()
        .map_init(
            || {
                (
                    LineWorker::new(n, rules, plan.clone()),
                    vec![0.0; nbins],
                    vec![0.0; n],
                )
            },
            |(worker, full_power, line), &c| {
                let mut acc = LineSums::new(nbins);
                let mut st = StatsAcc::new();
                full_power.fill(0.0);
                let mut full = 0;
                for i in c * ROW_CHUNK..((c + 1) * ROW_CHUNK).min(rows) {
                    let (z, v) = map.row(i);
                    let [q0, q1, q2] = map.row_poly(i);
                    if fast && map.mask.row_full(i) {
                        let mean = map.sums.row[i][0] / n as f64 - (q0 + q1 * ubar + q2 * u2bar);
                        worker.add_power_with(
                            |input| match stats_mu {
                                Some(mu) => fill_row_with_stats(
                                    input,
                                    z,
                                    &us,
                                    &w,
                                    [q0, q1, q2],
                                    mean,
                                    mu,
                                    &mut st,
                                ),
                                None => fill_row(input, z, &us, &w, [q0 + mean, q1, q2]),
                            },
                            full_power,
                        );
                        full += 1;
                        continue;
                    }
                    for ((o, &zj), &u) in line.iter_mut().zip(z).zip(&us) {
                        *o = zj - (q0 + u * (q1 + q2 * u));
                    }
                    if let Some(mu) = stats_mu {
                        for (k, (&r, &ok)) in line.iter().zip(v).enumerate() {
                            if ok {
                                st.push(k % 4, r - mu);
                                st.count += 1;
                            }
                        }
                    }
                    worker.add_line(line, v, &mut acc);
                }
                acc.add_full_lines(full_power, full, n, worker.full_energy());
                (acc, st)
            },
        )
        .collect();
    let mut total = LineSums::new(nbins);
    let mut stats = StatsAcc::new();
    for (p, s) in &partial {
        total.add(p);
        stats.add(s);
    }
    (total, stats_mu.map(|_| stats))
}

/// input[j] = (z[j] - (a + b u_j + c u_j^2)) w[j], with a holding the model's constant and the
/// line mean.
fn fill_row(input: &mut [f64], z: &[f64], us: &[f64], w: &[f64], abc: [f64; 3]) {
    avx2_or_baseline!(fill_row_impl(input, z, us, w, abc))
}

#[inline(always)]
fn fill_row_impl(input: &mut [f64], z: &[f64], us: &[f64], w: &[f64], [a, b, c]: [f64; 3]) {
    for (((o, &zj), &u), &wj) in input.iter_mut().zip(z).zip(us).zip(w) {
        *o = (zj - (a + u * (b + c * u))) * wj;
    }
}

/// As `fill_row`, also pushing every residual r = z - model into the moments about `mu`.
/// The moments live in local four-lane arrays (registers) for the row and are added to `st`
/// once; min / max are plain comparisons (heights are finite, no NaN handling needed).
#[allow(clippy::too_many_arguments)]
fn fill_row_with_stats(
    input: &mut [f64],
    z: &[f64],
    us: &[f64],
    w: &[f64],
    q: [f64; 3],
    mean: f64,
    mu: f64,
    st: &mut StatsAcc,
) {
    avx2_or_baseline!(fill_row_with_stats_impl(input, z, us, w, q, mean, mu, st))
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn fill_row_with_stats_impl(
    input: &mut [f64],
    z: &[f64],
    us: &[f64],
    w: &[f64],
    [q0, q1, q2]: [f64; 3],
    mean: f64,
    mu: f64,
    st: &mut StatsAcc,
) {
    let (mut s1, mut s2, mut s3, mut s4, mut sa) = (
        [0.0f64; 4],
        [0.0f64; 4],
        [0.0f64; 4],
        [0.0f64; 4],
        [0.0f64; 4],
    );
    let (mut lo, mut hi) = (st.lo, st.hi);
    let n4 = z.len() / 4 * 4;
    for (((oc, zc), uc), wc) in input[..n4]
        .chunks_exact_mut(4)
        .zip(z[..n4].chunks_exact(4))
        .zip(us[..n4].chunks_exact(4))
        .zip(w[..n4].chunks_exact(4))
    {
        for l in 0..4 {
            let u = uc[l];
            let r = zc[l] - (q0 + u * (q1 + q2 * u));
            oc[l] = (r - mean) * wc[l];
            let d = r - mu;
            let d2 = d * d;
            s1[l] += d;
            s2[l] += d2;
            s3[l] += d2 * d;
            s4[l] += d2 * d2;
            sa[l] += d.abs();
            lo[l] = if d < lo[l] { d } else { lo[l] };
            hi[l] = if d > hi[l] { d } else { hi[l] };
        }
    }
    for l in 0..4 {
        st.s1[l] += s1[l];
        st.s2[l] += s2[l];
        st.s3[l] += s3[l];
        st.s4[l] += s4[l];
        st.sa[l] += sa[l];
    }
    st.lo = lo;
    st.hi = hi;
    for k in n4..z.len() {
        let u = us[k];
        let r = z[k] - (q0 + u * (q1 + q2 * u));
        st.push(k % 4, r - mu);
        input[k] = (r - mean) * w[k];
    }
    st.count += z.len();
}

/// Copies z - g(v_i) of columns j0..j0 + cnt of the row-major map (`cols` wide) into `buf`,
/// column c at `c * stride`. Four rows are read together so that every buffer receives four
/// adjacent values at a time. Each row read starts a new page, which the hardware prefetchers
/// do not follow: rows `PREFETCH_ROWS` ahead are requested explicitly.
fn gather_block(
    heights: &[f64],
    cols: usize,
    j0: usize,
    cnt: usize,
    g: &[f64],
    buf: &mut [f64],
    stride: usize,
) {
    avx2_or_baseline!(gather_block_impl(heights, cols, j0, cnt, g, buf, stride))
}

#[inline(always)]
fn gather_block_impl(
    heights: &[f64],
    cols: usize,
    j0: usize,
    cnt: usize,
    g: &[f64],
    buf: &mut [f64],
    stride: usize,
) {
    let n = g.len();
    let n4 = n / 4 * 4;
    let seg = |i: usize| &heights[i * cols + j0..i * cols + j0 + cnt];
    for i in (0..n4).step_by(4) {
        for t in 0..4 {
            let ahead = (i + t + PREFETCH_ROWS) * cols + j0;
            for off in (0..cnt).step_by(8) {
                prefetch(heights, ahead + off);
            }
        }
        let (r0, r1, r2, r3) = (seg(i), seg(i + 1), seg(i + 2), seg(i + 3));
        let (g0, g1, g2, g3) = (g[i], g[i + 1], g[i + 2], g[i + 3]);
        for (c, dst) in buf.chunks_exact_mut(stride).take(cnt).enumerate() {
            let d = &mut dst[i..i + 4];
            d[0] = r0[c] - g0;
            d[1] = r1[c] - g1;
            d[2] = r2[c] - g2;
            d[3] = r3[c] - g3;
        }
    }
    for i in n4..n {
        for (dst, &z) in buf.chunks_exact_mut(stride).zip(seg(i)) {
            dst[i] = z - g[i];
        }
    }
}

/// Sums the segment periodograms of all columns (Y lines).
pub(crate) fn sum_cols(map: &MapView, rules: LineRules) -> LineSums {
    let (n, cols) = (map.rows, map.cols);
    let nbins = n / 2 + 1;
    let plan = RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let w = rules.window.coefficients(n);
    // Along a column the model is p0(u_j) + p1 v + p2 v^2 with p1, p2 the same for every
    // column; p0 is constant along the line, so the mean removal absorbs it on the fast path.
    let (p1, p2) = match map.model {
        Some(m) => {
            let [_, p1, p2] = m.col_poly(0);
            (p1, p2)
        }
        None => (0.0, 0.0),
    };
    let g: Vec<f64> = (0..n)
        .map(|i| match map.model {
            Some(m) => {
                let v = m.v_of(i);
                v * (p1 + p2 * v)
            }
            None => 0.0,
        })
        .collect();
    let gbar = g.iter().sum::<f64>() / n as f64;
    let fast = dense_ok(&rules, n);
    let stride = n + STRIDE_PAD;
    let chunks: Vec<usize> = (0..cols.div_ceil(COL_BLOCK)).collect();
    let partial: Vec<LineSums> = chunks
        .par_iter()
        .map_init(
            || {
                (
                    LineWorker::new(n, rules, plan.clone()),
                    vec![0.0; nbins],
                    vec![0.0; stride * COL_BLOCK],
                    vec![false; n],
                )
            },
            |(worker, full_power, buf, vcol), &b| {
                let j0 = b * COL_BLOCK;
                let cnt = COL_BLOCK.min(cols - j0);
                gather_block(map.heights, cols, j0, cnt, &g, buf, stride);
                let mut acc = LineSums::new(nbins);
                full_power.fill(0.0);
                let mut full = 0;
                for c in 0..cnt {
                    let j = j0 + c;
                    let line = &mut buf[c * stride..c * stride + n];
                    if fast && map.mask.col_full(j) {
                        let b = map.sums.col[j] / n as f64 - gbar;
                        for (x, &wi) in line.iter_mut().zip(&w) {
                            *x = (*x - b) * wi;
                        }
                        worker.add_power_of(line, full_power);
                        full += 1;
                        continue;
                    }
                    let p0 = map.model.map_or(0.0, |m| m.col_poly(j)[0]);
                    for x in line.iter_mut() {
                        *x -= p0;
                    }
                    for (i, o) in vcol.iter_mut().enumerate() {
                        *o = map.valid[i * cols + j];
                    }
                    worker.add_line(line, vcol, &mut acc);
                }
                acc.add_full_lines(full_power, full, n, worker.full_energy());
                acc
            },
        )
        .collect();
    let mut total = LineSums::new(nbins);
    for p in &partial {
        total.add(p);
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::form::prepare;
    use crate::lines::{sum_lines, Axis};
    use crate::psd1d::{stats_psd_xy, PsdOptions};
    use crate::window::Window;
    use bonnetlab_surface::{height_stats, remove_terms, rng::Rng, Surface, Term};
    use ndarray::Array2;

    /// A 70 x 91 map with form, a ripple and noise; `holes` drops a few pixels (some rows and
    /// columns stay fully valid, so both paths run in one pass).
    fn map(holes: bool) -> Surface {
        let mut r = Rng::new(21);
        let z = Array2::from_shape_fn((70, 91), |(i, j)| {
            let (x, y) = (j as f64 * 0.2, i as f64 * 0.3);
            if holes && ((i % 9 == 4 && j % 13 == 2) || (i == 50 && j > 60)) {
                f64::NAN
            } else {
                500.0 + 2.0 * x - 1.5 * y
                    + 0.04 * (x * x + y * y)
                    + 3.0 * (2.0 * std::f64::consts::PI * y / 3.0).sin()
                    + r.normal()
            }
        });
        Surface::new(z, Some(0.2), Some(0.3)).unwrap()
    }

    fn close(a: &[f64], b: &[f64]) {
        let peak = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-12 * peak, "{x} vs {y}");
        }
    }

    #[test]
    fn dense_passes_equal_the_general_path() {
        for holes in [false, true] {
            let s = map(holes);
            for (terms, window) in [
                (vec![Term::Piston, Term::Tilt, Term::Power], Window::Hann),
                (vec![], Window::Blackman),
            ] {
                let p = prepare(&s, &terms).unwrap();
                let map = MapView {
                    heights: p.surface.heights_nm().as_slice().unwrap(),
                    valid: p.surface.valid().as_slice().unwrap(),
                    rows: 70,
                    cols: 91,
                    model: p.model.as_ref(),
                    mask: &p.mask,
                    sums: &p.sums,
                };
                for axis in [Axis::X, Axis::Y] {
                    let n = if axis == Axis::X { 91 } else { 70 };
                    let rules = LineRules {
                        window,
                        detrend: Detrend::Mean,
                        max_gap_px: 2,
                        min_len: n / 4,
                        biased_bins: window.main_lobe_half_width_bins() + 1,
                    };
                    let fast = match axis {
                        Axis::X => sum_rows(&map, rules, None).0,
                        Axis::Y => sum_cols(&map, rules),
                    };
                    let reference = sum_lines(
                        p.surface.heights_nm().view(),
                        p.surface.valid().view(),
                        axis,
                        rules,
                        p.model.as_ref(),
                    );
                    close(&fast.power, &reference.power);
                    close(&fast.power_all, &reference.power_all);
                    assert_eq!(fast.bin_weight, reference.bin_weight);
                    assert_eq!(fast.weight, reference.weight);
                    assert_eq!(fast.max_len, reference.max_len);
                    assert_eq!(fast.n_lines, reference.n_lines);
                    assert_eq!(fast.n_segments, reference.n_segments);
                }
            }
        }
    }

    #[test]
    fn stats_equal_height_stats_of_the_residual() {
        for holes in [false, true] {
            let s = map(holes);
            for terms in [
                vec![Term::Piston, Term::Tilt],
                vec![],
                vec![Term::Zernike(9)],
            ] {
                let opts = PsdOptions {
                    remove: terms.clone(),
                    ..PsdOptions::default()
                };
                let (st, x, _) = stats_psd_xy(&s, &opts).unwrap();
                let residual = if terms.is_empty() {
                    s.clone()
                } else {
                    remove_terms(&s, &terms).unwrap().0
                };
                let e = height_stats(&residual).unwrap();
                assert_eq!(st.valid, e.valid);
                for (a, b) in [
                    (st.mean_nm, e.mean_nm),
                    (st.rms_nm, e.rms_nm),
                    (st.sa_nm, e.sa_nm),
                    (st.sp_nm, e.sp_nm),
                    (st.sv_nm, e.sv_nm),
                    (st.pv_nm, e.pv_nm),
                    (st.ssk.unwrap_or(0.0), e.ssk.unwrap_or(0.0)),
                    (st.sku.unwrap_or(0.0), e.sku.unwrap_or(0.0)),
                ] {
                    // The fits differ only by rounding: nm-level agreement far below 1e-9.
                    assert!(
                        (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
                        "{terms:?}: {a} vs {b}"
                    );
                }
                assert_eq!(x.removed, residual.removed);
            }
        }
    }
}
