//! One-dimensional periodograms of the lines of a map (rows for X, columns for Y), with the
//! dropout handling of `metrology.md`:
//!
//! 1. interior gaps of at most `max_gap_px` invalid pixels are filled by linear interpolation
//!    between their valid neighbours (gaps touching a line end are never filled);
//! 2. every contiguous run of (valid or filled) samples at least `min_len` long is a *segment*;
//!    shorter runs are skipped;
//! 3. each segment is detrended on its own (mean, or least-squares line), multiplied by a window
//!    of the segment's length, zero-padded to the line length N and transformed;
//! 4. its two-sided density is dx |Z_k|^2 / sum(w^2) (the segment's own window energy, so a
//!    fully valid line gives dx |Z_k|^2 / (N U) exactly as the spec writes);
//! 5. every segment is used at its own resolution: a segment of m samples is trusted from its
//!    own first unbiased bin up, i.e. at full-line bins k >= ceil(b N / m) where b is the
//!    window's biased-bin count (3 for Hann), exactly as a full line is trusted from bin b up;
//!    below that its zero-padded periodogram is a smear of the DC / detrend notch and is left
//!    out. Bins below b (flagged biased) take every segment;
//! 6. at every bin the contributing segments are averaged with weights equal to their
//!    *measured* sample counts (interpolated samples carry no weight).
//!
//! `LineSums` therefore holds a weight per bin. Bins in [b, ceil(b N / m_max)) where even the
//! longest segment is not trusted take every segment and are reported as biased.
//!
//! Lines are processed in fixed chunks whose partial sums are added in chunk order, so the
//! result does not depend on the number of threads. FFT plans are shared; input, output and
//! scratch buffers live in one `LineWorker` per rayon job and are reused across its lines.

use std::sync::Arc;

#[cfg(test)]
use ndarray::Array2;
use ndarray::ArrayView2;
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};

use crate::form::PlaneModel;
use crate::window::Window;

/// Which direction the lines run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Along X: each row is a line, samples dx apart.
    X,
    /// Along Y: each column is a line, samples dy apart.
    Y,
}

impl Axis {
    pub fn name(&self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
        }
    }
}

/// Per-line detrending applied to each segment after global form removal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Detrend {
    /// Subtract the segment mean.
    #[default]
    Mean,
    /// Subtract the least-squares line through the segment.
    Linear,
}

/// How lines are cut into segments.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineRules {
    pub window: Window,
    pub detrend: Detrend,
    /// Longest interior gap (invalid pixels) that is filled by linear interpolation.
    pub max_gap_px: usize,
    /// Shortest segment analysed.
    pub min_len: usize,
    /// The window's biased-bin count b: a segment of m samples is used from bin
    /// ceil(b N / m) up (and at every bin below b).
    pub biased_bins: usize,
}

impl LineRules {
    /// First full-line bin at which a segment of m samples (lines of n) is trusted.
    pub fn first_bin(&self, m: usize, n: usize) -> usize {
        (self.biased_bins * n).div_ceil(m.max(1))
    }
}

/// Lines per chunk: fixed so that the summation order is independent of the thread count.
const CHUNK_LINES: usize = 32;

/// The sum over a set of lines of weight * (two-sided density / dx), for bins 0..=N/2.
#[derive(Debug, Clone)]
pub(crate) struct LineSums {
    /// sum over the segments trusted at bin k of m_valid * |Z_k|^2 / sum(w^2), k = 0..=N/2.
    pub power: Vec<f64>,
    /// sum over the segments trusted at bin k of m_valid.
    pub bin_weight: Vec<f64>,
    /// The same sums over every segment, whatever its resolution (used only for bins where
    /// no segment is trusted; those are reported as biased).
    pub power_all: Vec<f64>,
    /// sum of measured sample counts m_valid over all segments.
    pub weight: f64,
    /// Longest segment (samples, including interpolated ones).
    pub max_len: usize,
    pub n_lines: usize,
    pub n_segments: usize,
}

impl LineSums {
    pub fn new(nbins: usize) -> Self {
        LineSums {
            power: vec![0.0; nbins],
            bin_weight: vec![0.0; nbins],
            power_all: vec![0.0; nbins],
            weight: 0.0,
            max_len: 0,
            n_lines: 0,
            n_segments: 0,
        }
    }

    /// Adds one segment: `power` = |Z_k|^2 / sum(w^2), weight `mv` (measured samples), trusted
    /// from bin `first` up and at every bin below `b`.
    pub fn add_segment(&mut self, power: &[f64], mv: f64, m: usize, first: usize, b: usize) {
        for (k, (((a, w), all), p)) in self
            .power
            .iter_mut()
            .zip(self.bin_weight.iter_mut())
            .zip(self.power_all.iter_mut())
            .zip(power)
            .enumerate()
        {
            *all += mv * p;
            if k < b || k >= first {
                *a += mv * p;
                *w += mv;
            }
        }
        self.weight += mv;
        self.max_len = self.max_len.max(m);
        self.n_segments += 1;
    }
    /// Adds `count` full lines of N = `n` samples whose |Z_k|^2 sum to `power_sum`, all with
    /// the full window of energy `energy` (one scaling per chunk instead of per line).
    pub fn add_full_lines(&mut self, power_sum: &[f64], count: usize, n: usize, energy: f64) {
        if count == 0 {
            return;
        }
        let scale = if energy > 0.0 { n as f64 / energy } else { 0.0 };
        let w = (n * count) as f64;
        for (((a, all), bw), p) in self
            .power
            .iter_mut()
            .zip(self.power_all.iter_mut())
            .zip(self.bin_weight.iter_mut())
            .zip(power_sum)
        {
            *a += p * scale;
            *all += p * scale;
            *bw += w;
        }
        self.weight += w;
        self.max_len = self.max_len.max(n);
        self.n_lines += count;
        self.n_segments += count;
    }
    pub fn add(&mut self, o: &LineSums) {
        for (a, b) in self.power.iter_mut().zip(&o.power) {
            *a += b;
        }
        for (a, b) in self.bin_weight.iter_mut().zip(&o.bin_weight) {
            *a += b;
        }
        for (a, b) in self.power_all.iter_mut().zip(&o.power_all) {
            *a += b;
        }
        self.weight += o.weight;
        self.max_len = self.max_len.max(o.max_len);
        self.n_lines += o.n_lines;
        self.n_segments += o.n_segments;
    }
}

/// Reusable per-job state: the FFT plan, buffers, the full-length window.
pub(crate) struct LineWorker {
    n: usize,
    rules: LineRules,
    plan: Arc<dyn RealToComplex<f64>>,
    input: Vec<f64>,
    spectrum: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    full_window: Vec<f64>,
    full_energy: f64,
    power_buf: Vec<f64>,
    z: Vec<f64>,
    ok: Vec<bool>,
}

impl LineWorker {
    pub fn new(n: usize, rules: LineRules, plan: Arc<dyn RealToComplex<f64>>) -> Self {
        let full_window = rules.window.coefficients(n);
        let full_energy = full_window.iter().map(|w| w * w).sum();
        LineWorker {
            n,
            rules,
            input: plan.make_input_vec(),
            spectrum: plan.make_output_vec(),
            scratch: plan.make_scratch_vec(),
            plan,
            full_window,
            full_energy,
            power_buf: Vec::with_capacity(n / 2 + 1),
            z: vec![0.0; n],
            ok: vec![false; n],
        }
    }

    /// Fills the FFT input with `fill` (a full line, already detrended and windowed), transforms
    /// it and adds |Z_k|^2 to `acc` (N/2 + 1 bins). The dense fast path of `dense`.
    pub fn add_power_with(&mut self, fill: impl FnOnce(&mut [f64]), acc: &mut [f64]) {
        fill(&mut self.input);
        let mut input = std::mem::take(&mut self.input);
        self.add_power_of(&mut input, acc);
        self.input = input;
    }

    /// Transforms `input` (a full, detrended and windowed line of N samples; overwritten) and
    /// adds |Z_k|^2 to `acc` (N/2 + 1 bins).
    pub fn add_power_of(&mut self, input: &mut [f64], acc: &mut [f64]) {
        // Lengths match by construction (N-sample lines, plan buffers), so this cannot fail.
        let _ = self
            .plan
            .process_with_scratch(input, &mut self.spectrum, &mut self.scratch);
        add_norm_sqr(acc, &self.spectrum);
    }

    /// Window energy sum(w^2) of a full line.
    pub fn full_energy(&self) -> f64 {
        self.full_energy
    }

    /// Adds one line's segments to `acc` (`acc.power` has N/2 + 1 bins).
    /// Returns whether any segment was used.
    pub fn add_line(&mut self, z: &[f64], valid: &[bool], acc: &mut LineSums) -> bool {
        let (n, rules) = (self.n, self.rules);
        let used = self.for_each_segment(z, valid, |power, m, mv| {
            acc.add_segment(power, mv, m, rules.first_bin(m, n), rules.biased_bins);
        });
        if used {
            acc.n_lines += 1;
        }
        used
    }

    /// Runs `f(|Z_k|^2 / sum w^2 for k = 0..=N/2, m, measured samples)` for every segment of
    /// the line.
    pub fn for_each_segment(
        &mut self,
        z: &[f64],
        valid: &[bool],
        mut f: impl FnMut(&[f64], usize, f64),
    ) -> bool {
        let n = self.n;
        debug_assert_eq!(z.len(), n);
        let mut power = std::mem::take(&mut self.power_buf);
        let mut used = false;
        if valid.iter().all(|&v| v) {
            if n >= self.rules.min_len {
                self.transform_segment(z, &mut power);
                f(&power, n, n as f64);
                used = true;
            }
        } else {
            self.z.copy_from_slice(z);
            self.ok.copy_from_slice(valid);
            fill_short_gaps(&mut self.z, &mut self.ok, self.rules.max_gap_px);
            let mut i = 0;
            while i < n {
                if !self.ok[i] {
                    i += 1;
                    continue;
                }
                let start = i;
                while i < n && self.ok[i] {
                    i += 1;
                }
                let m = i - start;
                if m >= self.rules.min_len && m >= 2 {
                    let filled = std::mem::take(&mut self.z);
                    self.transform_segment(&filled[start..start + m], &mut power);
                    self.z = filled;
                    let measured = valid[start..start + m].iter().filter(|&&v| v).count();
                    f(&power, m, measured as f64);
                    used = true;
                }
            }
        }
        self.power_buf = power;
        used
    }

    /// Detrends, windows, zero-pads and transforms one segment; writes |Z_k|^2 / sum(w^2)
    /// into `power` (N/2 + 1 values).
    fn transform_segment(&mut self, seg: &[f64], power: &mut Vec<f64>) {
        let n = self.n;
        let m = seg.len();
        let (a, b) = trend(seg, self.rules.detrend);
        let mut wbuf = Vec::new();
        let (w, energy): (&[f64], f64) = if m == n {
            (&self.full_window, self.full_energy)
        } else {
            self.rules.window.fill(m, &mut wbuf);
            let e = wbuf.iter().map(|v| v * v).sum();
            (&wbuf, e)
        };
        // Centred abscissa so the linear fit is well conditioned; `trend` uses the same.
        let c = 0.5 * (m as f64 - 1.0);
        if b == 0.0 {
            for ((dst, &zv), &wv) in self.input.iter_mut().zip(seg).zip(w) {
                *dst = (zv - a) * wv;
            }
        } else {
            for (k, ((dst, &zv), &wv)) in self.input.iter_mut().zip(seg).zip(w).enumerate() {
                *dst = (zv - a - b * (k as f64 - c)) * wv;
            }
        }
        self.input[m..].fill(0.0);
        // Lengths match by construction (buffers come from the plan), so this cannot fail.
        let _ =
            self.plan
                .process_with_scratch(&mut self.input, &mut self.spectrum, &mut self.scratch);
        power.clear();
        let inv = if energy > 0.0 { 1.0 / energy } else { 0.0 };
        power.extend(self.spectrum.iter().map(|c| c.norm_sqr() * inv));
    }
}

/// acc[k] += |z[k]|^2.
fn add_norm_sqr(acc: &mut [f64], z: &[Complex<f64>]) {
    avx2_or_baseline!(add_norm_sqr_impl(acc, z))
}

#[inline(always)]
fn add_norm_sqr_impl(acc: &mut [f64], z: &[Complex<f64>]) {
    for (a, c) in acc.iter_mut().zip(z) {
        *a += c.re * c.re + c.im * c.im;
    }
}

/// Least-squares trend of a segment about its centre: (mean, slope per sample).
fn trend(seg: &[f64], detrend: Detrend) -> (f64, f64) {
    let m = seg.len() as f64;
    let mean = seg.iter().sum::<f64>() / m;
    match detrend {
        Detrend::Mean => (mean, 0.0),
        Detrend::Linear => {
            let c = 0.5 * (m - 1.0);
            let (mut sxy, mut sxx) = (0.0, 0.0);
            for (k, &z) in seg.iter().enumerate() {
                let x = k as f64 - c;
                sxy += x * (z - mean);
                sxx += x * x;
            }
            (mean, if sxx > 0.0 { sxy / sxx } else { 0.0 })
        }
    }
}

/// Fills interior runs of at most `max_gap` invalid samples by linear interpolation between
/// the valid samples on either side, and marks them usable.
pub(crate) fn fill_short_gaps(z: &mut [f64], ok: &mut [bool], max_gap: usize) {
    if max_gap == 0 {
        return;
    }
    let n = z.len();
    let mut i = 0;
    // Skip the leading invalid run: gaps touching an end are not filled.
    while i < n && !ok[i] {
        i += 1;
    }
    while i < n {
        if ok[i] {
            i += 1;
            continue;
        }
        let left = i - 1; // ok[left] holds: the loop only reaches here after a valid sample
        let mut j = i;
        while j < n && !ok[j] {
            j += 1;
        }
        if j < n && j - i <= max_gap {
            let (zl, zr) = (z[left], z[j]);
            let span = (j - left) as f64;
            for k in i..j {
                let t = (k - left) as f64 / span;
                z[k] = zl + (zr - zl) * t;
                ok[k] = true;
            }
        }
        i = j;
    }
}

/// Sums the segment periodograms of all lines of `heights` along `axis`: the reference (one
/// general path for every line) that the dense passes of `dense` are tested against.
#[cfg(test)]
pub(crate) fn sum_lines(
    heights: ArrayView2<f64>,
    valid: ArrayView2<bool>,
    axis: Axis,
    rules: LineRules,
    model: Option<&PlaneModel>,
) -> LineSums {
    let (rows, cols) = heights.dim();
    let (n, n_lines) = match axis {
        Axis::X => (cols, rows),
        Axis::Y => (rows, cols),
    };
    let nbins = n / 2 + 1;
    let plan = RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let chunks: Vec<usize> = (0..n_lines.div_ceil(CHUNK_LINES)).collect();
    let partial: Vec<LineSums> = chunks
        .par_iter()
        .map_init(
            || (LineWorker::new(n, rules, plan.clone()), Block::new(n)),
            |(worker, block), &c| {
                let first = c * CHUNK_LINES;
                let count = CHUNK_LINES.min(n_lines - first);
                block.load(heights, valid, axis, first, count, model);
                let mut acc = LineSums::new(nbins);
                for l in 0..count {
                    let (z, v) = block.line(l);
                    worker.add_line(z, v, &mut acc);
                }
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

/// Runs `f(line index, per-line one-sided-ready power sums)` for every line, in parallel, and
/// collects the results in line order. The closure receives the line's LineSums.
pub(crate) fn map_lines<T: Send>(
    heights: ArrayView2<f64>,
    valid: ArrayView2<bool>,
    axis: Axis,
    rules: LineRules,
    model: Option<&PlaneModel>,
    f: impl Fn(&LineSums) -> T + Sync,
) -> Vec<T> {
    let (rows, cols) = heights.dim();
    let (n, n_lines) = match axis {
        Axis::X => (cols, rows),
        Axis::Y => (rows, cols),
    };
    let nbins = n / 2 + 1;
    let plan = RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let chunks: Vec<usize> = (0..n_lines.div_ceil(CHUNK_LINES)).collect();
    let per_chunk: Vec<Vec<T>> = chunks
        .par_iter()
        .map_init(
            || (LineWorker::new(n, rules, plan.clone()), Block::new(n)),
            |(worker, block), &c| {
                let first = c * CHUNK_LINES;
                let count = CHUNK_LINES.min(n_lines - first);
                block.load(heights, valid, axis, first, count, model);
                (0..count)
                    .map(|l| {
                        let (z, v) = block.line(l);
                        let mut acc = LineSums::new(nbins);
                        worker.add_line(z, v, &mut acc);
                        f(&acc)
                    })
                    .collect()
            },
        )
        .collect();
    per_chunk.into_iter().flatten().collect()
}

/// A block of up to CHUNK_LINES lines copied into contiguous memory. For Y the copy is a
/// blocked transpose (row by row, CHUNK_LINES adjacent values at a time), which keeps the
/// reads cache friendly instead of striding a whole row per sample.
struct Block {
    n: usize,
    z: Vec<f64>,
    v: Vec<bool>,
    /// Model values of the current row (X) or of the block's columns in one row (Y).
    m: Vec<f64>,
}

impl Block {
    fn new(n: usize) -> Self {
        Block {
            n,
            z: vec![0.0; n * CHUNK_LINES],
            v: vec![false; n * CHUNK_LINES],
            m: vec![0.0; n.max(CHUNK_LINES)],
        }
    }

    fn load(
        &mut self,
        heights: ArrayView2<f64>,
        valid: ArrayView2<bool>,
        axis: Axis,
        first: usize,
        count: usize,
        model: Option<&PlaneModel>,
    ) {
        let n = self.n;
        match axis {
            Axis::X => {
                for l in 0..count {
                    let hz = heights.row(first + l);
                    let hv = valid.row(first + l);
                    let m = &mut self.m[..n];
                    match model {
                        Some(md) => md.row(first + l, m),
                        None => m.fill(0.0),
                    }
                    for ((d, s), mv) in self.z[l * n..(l + 1) * n]
                        .iter_mut()
                        .zip(hz.iter())
                        .zip(m.iter())
                    {
                        *d = *s - *mv;
                    }
                    for (d, s) in self.v[l * n..(l + 1) * n].iter_mut().zip(hv.iter()) {
                        *d = *s;
                    }
                }
            }
            Axis::Y => {
                // Tiles of TILE rows x `count` columns: the reads of a tile stay in L1 and
                // every line's writes are contiguous runs of TILE values.
                const TILE: usize = 32;
                let mut mt = [[0.0f64; CHUNK_LINES]; TILE];
                for i0 in (0..n).step_by(TILE) {
                    let i1 = (i0 + TILE).min(n);
                    for (t, i) in (i0..i1).enumerate() {
                        let m = &mut mt[t][..count];
                        match model {
                            Some(md) => md.row_from(i, first, m),
                            None => m.fill(0.0),
                        }
                    }
                    for l in 0..count {
                        let zl = &mut self.z[l * n + i0..l * n + i1];
                        for (t, d) in zl.iter_mut().enumerate() {
                            *d = heights[(i0 + t, first + l)] - mt[t][l];
                        }
                        let vl = &mut self.v[l * n + i0..l * n + i1];
                        for (t, d) in vl.iter_mut().enumerate() {
                            *d = valid[(i0 + t, first + l)];
                        }
                    }
                }
            }
        }
    }

    fn line(&self, l: usize) -> (&[f64], &[bool]) {
        let n = self.n;
        (&self.z[l * n..(l + 1) * n], &self.v[l * n..(l + 1) * n])
    }
}

/// Convenience for tests: the valid mask of a dense map.
#[cfg(test)]
pub(crate) fn all_valid(dim: (usize, usize)) -> Array2<bool> {
    Array2::from_elem(dim, true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gap_filling_is_linear_and_leaves_ends_and_long_gaps() {
        let mut z = vec![0.0, 1.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0, 9.0, 0.0];
        let mut ok = vec![
            false, true, false, false, true, false, false, false, false, true, false,
        ];
        fill_short_gaps(&mut z, &mut ok, 3);
        assert_eq!(&z[..5], &[0.0, 1.0, 2.0, 3.0, 4.0]);
        assert_eq!(
            ok,
            vec![false, true, true, true, true, false, false, false, false, true, false]
        );
    }

    #[test]
    fn linear_detrend_removes_a_ramp() {
        let seg: Vec<f64> = (0..11).map(|k| 2.0 + 0.5 * k as f64).collect();
        let (a, b) = trend(&seg, Detrend::Linear);
        assert!((a - 4.5).abs() < 1e-12 && (b - 0.5).abs() < 1e-12);
    }

    #[test]
    fn y_lines_equal_x_lines_of_the_transpose() {
        let h = Array2::from_shape_fn((37, 70), |(i, j)| ((i * 7 + j * 13) % 11) as f64);
        let mut v = all_valid(h.dim());
        v[(3, 5)] = false;
        v[(20, 40)] = false;
        let rules = LineRules {
            window: Window::Hann,
            detrend: Detrend::Mean,
            max_gap_px: 2,
            min_len: 8,
            biased_bins: 3,
        };
        let a = sum_lines(h.view(), v.view(), Axis::Y, rules, None);
        let ht = h.t().to_owned();
        let vt = v.t().to_owned();
        let b = sum_lines(ht.view(), vt.view(), Axis::X, rules, None);
        assert_eq!(a.power, b.power);
        assert_eq!(a.weight, b.weight);
    }
}
