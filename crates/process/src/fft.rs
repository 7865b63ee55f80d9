//! Real 2-D FFTs and linear convolution by zero-padded FFT, with plans, kernel spectra and
//! scratch buffers kept in a reusable workspace (fresh buffers cost more than the FFT itself).
//!
//! Layout: real arrays are `n0 x n1` row-major. The half spectrum is stored *transposed*,
//! `(n1/2 + 1) x n0`, so the column transforms run on contiguous memory; callers only multiply
//! spectra pointwise, so the layout never leaks. Inverse transforms are normalised (1/(n0 n1)).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use crate::memory::zeroed_dense;
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
pub use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

/// Smallest n' >= n whose only prime factors are 2, 3, 5 and 7 (fast FFT sizes).
pub fn fast_len(n: usize) -> usize {
    smooth_len(n, &[2, 3, 5, 7], false)
}

/// Smallest n' >= n (odd when `odd`) whose prime factors are all in `primes`.
pub fn smooth_len(n: usize, primes: &[usize], odd: bool) -> usize {
    let step = if odd { 2 } else { 1 };
    let mut m = if odd { n.max(1) | 1 } else { n.max(1) };
    loop {
        let mut k = m;
        for &p in primes {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += step;
    }
}

/// A real 2-D FFT of fixed size with its plans.
pub struct Fft2 {
    n0: usize,
    n1: usize,
    nh: usize,
    r2c: Arc<dyn RealToComplex<f64>>,
    c2r: Arc<dyn ComplexToReal<f64>>,
    col_fwd: Arc<dyn Fft<f64>>,
    col_inv: Arc<dyn Fft<f64>>,
    /// `exp(-2 pi i m / n1)`, m < n1: the row transform of a single column (see
    /// [`Fft2::forward_columns`]).
    row_twiddles: Vec<Complex<f64>>,
    /// Transforms run so far (forward and inverse), for work counts in solvers and benches.
    count: AtomicUsize,
}

impl std::fmt::Debug for Fft2 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({} x {})", self.n0, self.n1)
    }
}

const PAR_ROWS: usize = 16;

/// The process's FFT planners (real and complex), shared: a length is planned once, and every
/// later plan of it is the same `Arc` (the same algorithm, so the same bits as a fresh plan).
static PLANNERS: std::sync::Mutex<Option<(RealFftPlanner<f64>, FftPlanner<f64>)>> =
    std::sync::Mutex::new(None);

/// Runs `f` with the shared planners.
fn planned<T>(f: impl FnOnce(&mut RealFftPlanner<f64>, &mut FftPlanner<f64>) -> T) -> T {
    // A panic inside a planner leaves nothing half-written that a later plan could see.
    let mut g = PLANNERS.lock().unwrap_or_else(|e| e.into_inner());
    let (rp, cp) = g.get_or_insert_with(|| (RealFftPlanner::new(), FftPlanner::new()));
    f(rp, cp)
}

/// A forward real-to-complex transform of length `n`, planned once per process.
pub fn real_forward(n: usize) -> Arc<dyn RealToComplex<f64>> {
    planned(|rp, _| rp.plan_fft_forward(n.max(1)))
}

/// Forward and inverse complex transforms of length `n` (unnormalised), planned once per
/// process.
pub fn complex_pair(n: usize) -> (Arc<dyn Fft<f64>>, Arc<dyn Fft<f64>>) {
    planned(|_, cp| (cp.plan_fft_forward(n.max(1)), cp.plan_fft_inverse(n.max(1))))
}

/// Transforms with fewer real samples than this run on the calling thread: below it, rayon's
/// hand-offs (six fork-joins per transform pair) cost more than they gain on a shared 2-core
/// machine (see reports/performance_process.md for the dwell-grid sizes).
pub const PARALLEL_MIN_LEN: usize = 1 << 18;

impl Fft2 {
    pub fn new(n0: usize, n1: usize) -> Fft2 {
        let n0 = n0.max(1);
        let n1 = n1.max(1);
        let (r2c, c2r, col_fwd, col_inv) = planned(|rp, cp| {
            (
                rp.plan_fft_forward(n1),
                rp.plan_fft_inverse(n1),
                cp.plan_fft_forward(n0),
                cp.plan_fft_inverse(n0),
            )
        });
        Fft2 {
            n0,
            n1,
            nh: n1 / 2 + 1,
            r2c,
            c2r,
            col_fwd,
            col_inv,
            row_twiddles: (0..n1)
                .map(|m| {
                    let a = -2.0 * std::f64::consts::PI * m as f64 / n1 as f64;
                    Complex::new(a.cos(), a.sin())
                })
                .collect(),
            count: AtomicUsize::new(0),
        }
    }

    /// Number of 2-D transforms (forward or inverse) this plan has run.
    pub fn transforms(&self) -> usize {
        self.count.load(Ordering::Relaxed)
    }

    pub fn shape(&self) -> (usize, usize) {
        (self.n0, self.n1)
    }

    /// Whether transforms of this size use the rayon pool.
    pub fn is_parallel(&self) -> bool {
        self.n0 * self.n1 >= PARALLEL_MIN_LEN
    }

    /// Weight of spectrum element `idx` in a Parseval sum over the half spectrum: 1 for the
    /// zero (and, for even n1, the Nyquist) column frequency, 2 for the others, whose conjugate
    /// twins are not stored.
    pub fn parseval_weight(&self, idx: usize) -> f64 {
        let k1 = idx / self.n0;
        if k1 == 0 || (self.n1.is_multiple_of(2) && k1 == self.nh - 1) {
            1.0
        } else {
            2.0
        }
    }

    /// Length of a (transposed) half spectrum.
    pub fn spectrum_len(&self) -> usize {
        self.nh * self.n0
    }

    /// Forward transform of `real` (`n0 * n1`, destroyed) into `spec` (transposed half
    /// spectrum); `tmp` is scratch of `spectrum_len()`.
    pub fn forward(&self, real: &mut [f64], tmp: &mut [Complex<f64>], spec: &mut [Complex<f64>]) {
        self.forward_live(real, tmp, spec, None);
    }

    /// [`Self::forward`] of an input whose rows `i` with `live[i] == false` are all zero (they
    /// are not read: their row transforms are zero without being run). Rows beyond
    /// `live.len()` are taken as zero too. The result is the same, bit for bit.
    pub fn forward_live(
        &self,
        real: &mut [f64],
        tmp: &mut [Complex<f64>],
        spec: &mut [Complex<f64>],
        live: Option<&[bool]>,
    ) {
        self.count.fetch_add(1, Ordering::Relaxed);
        let (n0, n1, nh) = (self.n0, self.n1, self.nh);
        // Rows whose row transform is run; the others are zero, neither written to `tmp` nor
        // read from it (the transpose writes their zeros into `spec` directly).
        let on_rows: Option<Vec<usize>> = live.map(|l| {
            (0..n0)
                .filter(|&i| l.get(i).copied().unwrap_or(false))
                .collect()
        });
        let rows = |first: usize, rin: &mut [f64], cout: &mut [Complex<f64>]| {
            let mut scratch = self.r2c.make_scratch_vec();
            for (k, (r, c)) in rin.chunks_mut(n1).zip(cout.chunks_mut(nh)).enumerate() {
                let on = live.is_none_or(|l| l.get(first + k).copied().unwrap_or(false));
                if on {
                    // Lengths match by construction, so the only error case cannot occur.
                    let _ = self.r2c.process_with_scratch(r, c, &mut scratch);
                }
            }
        };
        let cols = |chunk: &mut [Complex<f64>]| {
            let mut scratch = vec![Complex::new(0.0, 0.0); self.col_fwd.get_inplace_scratch_len()];
            self.col_fwd.process_with_scratch(chunk, &mut scratch);
        };
        if self.is_parallel() {
            real.par_chunks_mut(n1 * PAR_ROWS)
                .zip(tmp.par_chunks_mut(nh * PAR_ROWS))
                .enumerate()
                .for_each(|(b, (rin, cout))| rows(b * PAR_ROWS, rin, cout));
            transpose_rows(tmp, spec, n0, nh, on_rows.as_deref(), true);
            spec.par_chunks_mut(n0 * PAR_ROWS).for_each(cols);
        } else {
            rows(0, real, tmp);
            transpose_rows(tmp, spec, n0, nh, on_rows.as_deref(), false);
            cols(spec);
        }
    }

    /// Forward transform (into `spec`, transposed half spectrum) of an input that is zero
    /// except in columns `live` of its first `input.nrows()` rows (at most `n0`): one column
    /// transform per live column and its row phase ramp, `S(k0, k1) = sum_j X_j(k0)
    /// exp(-2 pi i k1 j / n1)`. Cheaper than [`Self::forward`] for a few live columns (a
    /// raster's step-overs); equal to it up to rounding. `buf` is scratch.
    pub fn forward_columns(
        &self,
        input: ArrayView2<f64>,
        live: &[usize],
        spec: &mut [Complex<f64>],
        buf: &mut Vec<Complex<f64>>,
    ) {
        self.count.fetch_add(1, Ordering::Relaxed);
        let (n0, n1, nh) = (self.n0, self.n1, self.nh);
        let zero = Complex::new(0.0, 0.0);
        spec.fill(zero);
        let mut scratch = vec![zero; self.col_fwd.get_inplace_scratch_len()];
        for &j in live {
            buf.clear();
            buf.extend(
                input
                    .column(j)
                    .iter()
                    .take(n0)
                    .map(|&v| Complex::new(v, 0.0)),
            );
            buf.resize(n0, zero);
            self.col_fwd.process_with_scratch(buf, &mut scratch);
            for (k1, dst) in spec.chunks_mut(n0).take(nh).enumerate() {
                let t = self.row_twiddles[(k1 * j) % n1];
                for (d, x) in dst.iter_mut().zip(buf.iter()) {
                    *d += x * t;
                }
            }
        }
    }

    /// Inverse transform of `spec` (destroyed) into `real`, normalised.
    pub fn inverse(&self, spec: &mut [Complex<f64>], tmp: &mut [Complex<f64>], real: &mut [f64]) {
        self.inverse_rows(spec, tmp, real, self.n0);
    }

    /// [`Self::inverse`] of which only the first `keep` rows of `real` are needed: the other
    /// rows are neither transposed nor row-transformed (they are left as they were). The kept
    /// rows are the full inverse's, bit for bit.
    pub fn inverse_rows(
        &self,
        spec: &mut [Complex<f64>],
        tmp: &mut [Complex<f64>],
        real: &mut [f64],
        keep: usize,
    ) {
        self.count.fetch_add(1, Ordering::Relaxed);
        let (n0, n1, nh) = (self.n0, self.n1, self.nh);
        let keep = keep.min(n0);
        let cols = |chunk: &mut [Complex<f64>]| {
            let mut scratch = vec![Complex::new(0.0, 0.0); self.col_inv.get_inplace_scratch_len()];
            self.col_inv.process_with_scratch(chunk, &mut scratch);
        };
        let norm = 1.0 / (n0 * n1) as f64;
        let rows = |cin: &mut [Complex<f64>], rout: &mut [f64]| {
            let mut scratch = self.c2r.make_scratch_vec();
            for (c, r) in cin.chunks_mut(nh).zip(rout.chunks_mut(n1)) {
                c[0].im = 0.0;
                if n1.is_multiple_of(2) {
                    c[nh - 1].im = 0.0;
                }
                let _ = self.c2r.process_with_scratch(c, r, &mut scratch);
                r.iter_mut().for_each(|v| *v *= norm);
            }
        };
        let (tmp, real) = (&mut tmp[..keep * nh], &mut real[..keep * n1]);
        if self.is_parallel() {
            spec.par_chunks_mut(n0 * PAR_ROWS).for_each(cols);
            transpose(spec, tmp, nh, n0, keep, true);
            tmp.par_chunks_mut(nh * PAR_ROWS)
                .zip(real.par_chunks_mut(n1 * PAR_ROWS))
                .for_each(|(cin, rout)| rows(cin, rout));
        } else {
            cols(spec);
            transpose(spec, tmp, nh, n0, keep, false);
            rows(tmp, real);
        }
    }
}

/// Blocks of the transposes (B x B elements, 16 KB of complex values).
const B: usize = 32;

/// Blocked transpose of the first `keep` columns of an `rows x cols` row-major matrix into
/// `keep x rows` (`dst` holds `keep * rows`).
fn transpose(
    src: &[Complex<f64>],
    dst: &mut [Complex<f64>],
    rows: usize,
    cols: usize,
    keep: usize,
    parallel: bool,
) {
    let block = |(cb, dchunk): (usize, &mut [Complex<f64>])| {
        let c0 = cb * B;
        let c1 = (c0 + B).min(keep);
        for r0 in (0..rows).step_by(B) {
            let r1 = (r0 + B).min(rows);
            for c in c0..c1 {
                let drow = &mut dchunk[(c - c0) * rows..(c - c0 + 1) * rows];
                for r in r0..r1 {
                    drow[r] = src[r * cols + c];
                }
            }
        }
    };
    let dst = &mut dst[..keep * rows];
    if parallel {
        dst.par_chunks_mut(rows * B).enumerate().for_each(block);
    } else {
        dst.chunks_mut(rows * B).enumerate().for_each(block);
    }
}

/// [`transpose`] of an `rows x cols` matrix of which only the rows `on` (ascending; all when
/// `None`) are read: the others are taken as zero (their places in `dst` are zero-filled).
fn transpose_rows(
    src: &[Complex<f64>],
    dst: &mut [Complex<f64>],
    rows: usize,
    cols: usize,
    on: Option<&[usize]>,
    parallel: bool,
) {
    let Some(on) = on else {
        return transpose(src, dst, rows, cols, cols, parallel);
    };
    let zero = Complex::new(0.0, 0.0);
    let block = |(cb, dchunk): (usize, &mut [Complex<f64>])| {
        dchunk.fill(zero);
        let c0 = cb * B;
        let c1 = (c0 + B).min(cols);
        for rs in on.chunks(B) {
            for c in c0..c1 {
                let drow = &mut dchunk[(c - c0) * rows..(c - c0 + 1) * rows];
                for &r in rs {
                    drow[r] = src[r * cols + c];
                }
            }
        }
    };
    if parallel {
        dst.par_chunks_mut(rows * B).enumerate().for_each(block);
    } else {
        dst.chunks_mut(rows * B).enumerate().for_each(block);
    }
}

/// Linear convolution with a fixed kernel by zero-padded FFT (plans, kernel spectrum and
/// buffers reused across calls).
///
/// The kernel's centre pixel is `(k0 / 2, k1 / 2)` (odd sizes: the middle). `apply` returns
/// `out[i, j] = sum_{a,b} in[i - a, j - b] K[a + k0/2, b + k1/2]` over the input's own shape
/// ("same" mode), exact (no wrap-around) because the transform is padded by the kernel size.
pub struct Convolver {
    fft: Fft2,
    rows: usize,
    cols: usize,
    kernel_hat: Vec<Complex<f64>>,
    real: Vec<f64>,
    tmp: Vec<Complex<f64>>,
    spec: Vec<Complex<f64>>,
}

impl std::fmt::Debug for Convolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Convolver({} x {} via {:?})",
            self.rows, self.cols, self.fft
        )
    }
}

impl Convolver {
    /// A convolver for inputs of `rows x cols` with `kernel`.
    pub fn new(rows: usize, cols: usize, kernel: ArrayView2<f64>) -> Convolver {
        let (k0, k1) = kernel.dim();
        let n0 = fast_len(rows + k0);
        let n1 = fast_len(cols + k1);
        Self::with_fft_size(rows, cols, kernel, n0, n1)
    }

    /// As `new` but with an explicit transform size (at least the input size). Outputs at pixels
    /// farther than the kernel half-width from the input border are exact for any such size
    /// (used by the dwell solvers, whose aperture is the dwell grid shrunk by that half-width).
    pub fn with_fft_size(
        rows: usize,
        cols: usize,
        kernel: ArrayView2<f64>,
        n0: usize,
        n1: usize,
    ) -> Convolver {
        let n0 = n0.max(rows).max(1);
        let n1 = n1.max(cols).max(1);
        let fft = Fft2::new(n0, n1);
        let kernel_hat = kernel_hat(&fft, kernel);
        let real = vec![0.0; n0 * n1];
        let tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
        let spec = tmp.clone();
        Convolver {
            fft,
            rows,
            cols,
            kernel_hat,
            real,
            tmp,
            spec,
        }
    }

    /// Input shape this convolver takes.
    pub fn shape(&self) -> (usize, usize) {
        (self.rows, self.cols)
    }

    /// The transform itself (for solvers that stay in the frequency domain).
    pub fn fft(&self) -> &Fft2 {
        &self.fft
    }

    /// The transform size.
    pub fn fft_shape(&self) -> (usize, usize) {
        self.fft.shape()
    }

    /// Convolution ("same" mode) of `input` (`rows x cols`) with the kernel.
    pub fn apply(&mut self, input: ArrayView2<f64>) -> Array2<f64> {
        let mut out = Array2::zeros((self.rows, self.cols));
        self.run(input, false, &mut out);
        out
    }

    /// Correlation with the kernel (the adjoint of `apply`).
    pub fn apply_adjoint(&mut self, input: ArrayView2<f64>) -> Array2<f64> {
        let mut out = Array2::zeros((self.rows, self.cols));
        self.run(input, true, &mut out);
        out
    }

    /// Convolution (or correlation when `adjoint`) into an existing output.
    pub fn run(&mut self, input: ArrayView2<f64>, adjoint: bool, out: &mut Array2<f64>) {
        let n1 = self.fft.shape().1;
        load_padded(&mut self.real, n1, input, self.rows, self.cols);
        self.fft
            .forward(&mut self.real, &mut self.tmp, &mut self.spec);
        let kh = &self.kernel_hat;
        let mul = |(s, k): (&mut Complex<f64>, &Complex<f64>)| {
            *s *= if adjoint { k.conj() } else { *k };
        };
        if self.fft.is_parallel() {
            self.spec.par_iter_mut().zip(kh.par_iter()).for_each(mul);
        } else {
            self.spec.iter_mut().zip(kh.iter()).for_each(mul);
        }
        self.fft
            .inverse(&mut self.spec, &mut self.tmp, &mut self.real);
        let (or, oc) = out.dim();
        for i in 0..or.min(self.rows) {
            let src = &self.real[i * n1..i * n1 + oc.min(self.cols)];
            for (d, s) in out.row_mut(i).iter_mut().zip(src.iter()) {
                *d = *s;
            }
        }
    }

    /// Transfer function magnitudes |K(f)| (transposed half-spectrum order) and the spectrum
    /// itself, for inverse filters.
    pub fn kernel_spectrum(&self) -> &[Complex<f64>] {
        &self.kernel_hat
    }

    /// Applies an arbitrary pointwise filter `H(K(f))` in the frequency domain to `input`.
    pub fn filter(
        &mut self,
        input: ArrayView2<f64>,
        h: impl Fn(Complex<f64>) -> Complex<f64> + Sync,
    ) -> Array2<f64> {
        let n1 = self.fft.shape().1;
        load_padded(&mut self.real, n1, input, self.rows, self.cols);
        self.fft
            .forward(&mut self.real, &mut self.tmp, &mut self.spec);
        let kh = &self.kernel_hat;
        let mul = |(s, k): (&mut Complex<f64>, &Complex<f64>)| *s *= h(*k);
        if self.fft.is_parallel() {
            self.spec.par_iter_mut().zip(kh.par_iter()).for_each(mul);
        } else {
            self.spec.iter_mut().zip(kh.iter()).for_each(mul);
        }
        self.fft
            .inverse(&mut self.spec, &mut self.tmp, &mut self.real);
        let mut out = Array2::zeros((self.rows, self.cols));
        for i in 0..self.rows {
            for (d, s) in out.row_mut(i).iter_mut().zip(self.real[i * n1..].iter()) {
                *d = *s;
            }
        }
        out
    }
}

/// The half spectrum of `kernel` placed with its centre pixel `(k0 / 2, k1 / 2)` at the origin
/// (wrapped), for a transform of `fft`'s size.
pub(crate) fn kernel_hat(fft: &Fft2, kernel: ArrayView2<f64>) -> Vec<Complex<f64>> {
    let (n0, n1) = fft.shape();
    let mut real = zeroed_dense(n0 * n1);
    let mut tmp = zeroed_dense(fft.spectrum_len());
    kernel_hat_with(fft, kernel, &mut real, &mut tmp)
}

/// [`kernel_hat`] through the caller's scratch (`real`: n0 x n1, `tmp`: a spectrum; both
/// overwritten).
fn kernel_hat_with(
    fft: &Fft2,
    kernel: ArrayView2<f64>,
    real: &mut [f64],
    tmp: &mut [Complex<f64>],
) -> Vec<Complex<f64>> {
    let (n0, n1) = fft.shape();
    let (k0, k1) = kernel.dim();
    let (c0, c1) = (k0 / 2, k1 / 2);
    // The kernel's rows wrap to the first and last few rows of the transform; only those are
    // written (zeroed first) and transformed ([`Fft2::forward_live`], the same bits as a full
    // transform), the others are zero rows a full transform would run for nothing.
    let row_of = |a: usize| (a as isize - c0 as isize).rem_euclid(n0 as isize) as usize;
    let mut live = vec![false; n0];
    for a in 0..k0 {
        let i = row_of(a);
        if !live[i] {
            live[i] = true;
            real[i * n1..(i + 1) * n1].fill(0.0);
        }
    }
    for ((a, b), &v) in kernel.indexed_iter() {
        let i = row_of(a);
        let j = (b as isize - c1 as isize).rem_euclid(n1 as isize) as usize;
        real[i * n1 + j] += v;
    }
    let mut hat = zeroed_dense(fft.spectrum_len());
    fft.forward_live(real, tmp, &mut hat, Some(&live));
    hat
}

/// A sum of linear convolutions, each input with its own kernel, through one inverse transform
/// (plans, kernel spectra and buffers reused across calls). Same conventions as [`Convolver`]
/// ("same" mode, kernel centre at `(k0 / 2, k1 / 2)`); the transform size is given, and outputs
/// farther than the largest kernel half-width from the input border are exact for any size at
/// least the input's.
pub struct MultiConvolver {
    fft: Fft2,
    rows: usize,
    cols: usize,
    kernel_hats: Vec<Arc<Vec<Complex<f64>>>>,
    real: Vec<f64>,
    tmp: Vec<Complex<f64>>,
    spec: Vec<Complex<f64>>,
    acc: Vec<Complex<f64>>,
    /// Rows of the current input that are not all zero.
    live: Vec<bool>,
    /// Columns of the current input that are not all zero (when few), and a column buffer.
    live_cols: Vec<usize>,
    colbuf: Vec<Complex<f64>>,
}

impl std::fmt::Debug for MultiConvolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "MultiConvolver({} kernels, {} x {} via {:?})",
            self.kernel_hats.len(),
            self.rows,
            self.cols,
            self.fft
        )
    }
}

impl MultiConvolver {
    pub fn with_fft_size(
        rows: usize,
        cols: usize,
        kernels: &[ArrayView2<f64>],
        n0: usize,
        n1: usize,
    ) -> MultiConvolver {
        let fft = Fft2::new(n0.max(rows).max(1), n1.max(cols).max(1));
        let (n0, n1) = fft.shape();
        let len = fft.spectrum_len();
        let mut real = zeroed_dense(n0 * n1);
        let mut tmp = zeroed_dense(len);
        let kernel_hats = kernels
            .iter()
            .map(|k| Arc::new(kernel_hat_with(&fft, k.view(), &mut real, &mut tmp)))
            .collect();
        MultiConvolver {
            fft,
            rows,
            cols,
            kernel_hats,
            real,
            tmp,
            spec: zeroed_dense(len),
            acc: zeroed_dense(len),
            live: Vec::new(),
            live_cols: Vec::new(),
            colbuf: Vec::new(),
        }
    }

    /// The transform (its [`Fft2::transforms`] counts the work done).
    pub fn fft(&self) -> &Fft2 {
        &self.fft
    }

    /// Adds a kernel (one forward transform); returns its index for [`Self::apply_sum`].
    pub fn push_kernel(&mut self, kernel: ArrayView2<f64>) -> usize {
        let hat = self.kernel_spectrum(kernel);
        self.push_kernel_spectrum(hat)
    }

    /// Replaces kernel `idx` (one forward transform).
    pub fn set_kernel(&mut self, idx: usize, kernel: ArrayView2<f64>) {
        self.kernel_hats[idx] = self.kernel_spectrum(kernel);
    }

    /// The spectrum of a kernel at this convolver's transform size (one forward transform), to
    /// hand to [`Self::push_kernel_spectrum`] or [`Self::set_kernel_spectrum`] of a convolver
    /// of the same transform size.
    pub fn kernel_spectrum(&mut self, kernel: ArrayView2<f64>) -> Arc<Vec<Complex<f64>>> {
        Arc::new(kernel_hat_with(
            &self.fft,
            kernel,
            &mut self.real,
            &mut self.tmp,
        ))
    }

    /// Adds a kernel by its spectrum ([`Self::kernel_spectrum`], no transform); returns its
    /// index.
    pub fn push_kernel_spectrum(&mut self, hat: Arc<Vec<Complex<f64>>>) -> usize {
        assert_eq!(
            hat.len(),
            self.fft.spectrum_len(),
            "kernel spectrum of another size"
        );
        self.kernel_hats.push(hat);
        self.kernel_hats.len() - 1
    }

    /// Replaces kernel `idx` by a spectrum ([`Self::kernel_spectrum`], no transform).
    pub fn set_kernel_spectrum(&mut self, idx: usize, hat: Arc<Vec<Complex<f64>>>) {
        assert_eq!(
            hat.len(),
            self.fft.spectrum_len(),
            "kernel spectrum of another size"
        );
        self.kernel_hats[idx] = hat;
    }

    /// Keeps only the first `n` kernels (drops cached ones).
    pub fn truncate_kernels(&mut self, n: usize) {
        self.kernel_hats.truncate(n);
    }

    /// Input shape (rows, cols) the convolver was built for.
    pub fn input_dim(&self) -> (usize, usize) {
        (self.rows, self.cols)
    }

    pub fn kernel_count(&self) -> usize {
        self.kernel_hats.len()
    }

    /// `sum_k inputs[k] * kernels[k]` on the input shape; `None` inputs (no dwell of that kind)
    /// cost nothing. Inputs beyond the number of kernels are ignored. Rows of an input that are
    /// all zero (a raster's line map has one row in `pitch / pixel`) skip their row transform.
    pub fn apply_sum(&mut self, inputs: &[Option<ArrayView2<f64>>]) -> Array2<f64> {
        self.apply_sum_window(inputs, (0, 0), (self.rows, self.cols))
    }

    /// [`MultiConvolver::apply_sum`] on the window of `shape` at `origin` of the input shape
    /// only (no full-size output is formed: the removal keeps the map inside its grown grid).
    pub fn apply_sum_window(
        &mut self,
        inputs: &[Option<ArrayView2<f64>>],
        origin: (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        let ordered: Vec<(usize, ArrayView2<f64>)> = inputs
            .iter()
            .enumerate()
            .filter_map(|(k, v)| v.map(|v| (k, v)))
            .collect();
        self.apply_sum_window_ordered(&ordered, origin, shape)
    }

    /// [`MultiConvolver::apply_sum_window`] with the inputs given as (kernel index, input)
    /// pairs, summed in the order given (an index may appear more than once). The result
    /// depends on that order only, not on where the kernels sit: a caller that lists its
    /// inputs in an order of its own gets the same bits whichever slots its kernels took.
    pub fn apply_sum_window_ordered(
        &mut self,
        inputs: &[(usize, ArrayView2<f64>)],
        origin: (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        let hinted: Vec<HintedInput> = inputs.iter().map(|(k, v)| (*k, v.view(), None)).collect();
        self.apply_sum_window_hinted(&hinted, origin, shape)
    }

    /// [`MultiConvolver::apply_sum_window_ordered`] with, per input, the rows that may hold
    /// anything (`Some(rows)`: row `i` is all zero where `rows[i]` is false, and is then not
    /// read at all; `None`: every row is looked at). Same result, bit for bit; a caller that
    /// knows where it wrote (a raster's phase maps: one row per line) saves reading, and
    /// faulting in, the pages of a large map it never touched.
    pub fn apply_sum_window_hinted(
        &mut self,
        inputs: &[HintedInput],
        origin: (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        self.check_window(origin, shape);
        let mut any = false;
        for (k, input, hint) in inputs {
            self.forward_input(*input, *hint);
            let kh = self.kernel_hats[*k].clone();
            Self::accumulate(&mut self.acc, &self.spec, &kh, !any, self.fft.is_parallel());
            any = true;
        }
        self.inverse_window(any, origin, shape)
    }

    /// The spectrum of one input at this convolver's transform size (rows flagged false in
    /// `hint` are not read), to be convolved later through [`Self::apply_spectra_window`] with
    /// kernels not known yet: a scan of the TIF's width transforms the dwell once and only the
    /// kernels per width.
    pub fn input_spectrum(
        &mut self,
        input: ArrayView2<f64>,
        hint: Option<&[bool]>,
    ) -> Vec<Complex<f64>> {
        self.forward_input(input, hint);
        self.spec.clone()
    }

    /// `sum_k input_k * kernel_k` from both spectra ([`Self::input_spectrum`],
    /// [`Self::kernel_spectrum`]), summed in the order given, on the window of `shape` at
    /// `origin`: what [`Self::apply_sum_window_hinted`] gives for the same inputs and kernels.
    pub fn apply_spectra_window(
        &mut self,
        pairs: &[SpectrumPair],
        origin: (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        self.check_window(origin, shape);
        let len = self.fft.spectrum_len();
        let mut any = false;
        for (input, kernel) in pairs {
            assert!(
                input.len() == len && kernel.len() == len,
                "spectrum of another size"
            );
            Self::accumulate(&mut self.acc, input, kernel, !any, self.fft.is_parallel());
            any = true;
        }
        self.inverse_window(any, origin, shape)
    }

    fn check_window(&self, (r0, c0): (usize, usize), shape: (usize, usize)) {
        assert!(
            r0 + shape.0 <= self.rows && c0 + shape.1 <= self.cols,
            "output window outside the convolution"
        );
    }

    /// Forward transform of one input into `spec`.
    fn forward_input(&mut self, input: ArrayView2<f64>, hint: Option<&[bool]>) {
        let n1 = self.fft.shape().1;
        let view = input.slice(ndarray::s![
            ..self.rows.min(input.nrows()),
            ..self.cols.min(input.ncols())
        ]);
        if let Some(cols) = live_columns(view, hint, MAX_SPARSE_COLUMNS, &mut self.live_cols) {
            self.fft
                .forward_columns(view, cols, &mut self.spec, &mut self.colbuf);
        } else {
            load_live_rows(
                &mut self.real,
                n1,
                input,
                hint,
                (self.rows, self.cols),
                &mut self.live,
            );
            self.fft.forward_live(
                &mut self.real,
                &mut self.tmp,
                &mut self.spec,
                Some(&self.live),
            );
        }
    }

    /// `acc = s * k` (first) or `acc += s * k`.
    fn accumulate(
        acc: &mut [Complex<f64>],
        s: &[Complex<f64>],
        k: &[Complex<f64>],
        first: bool,
        parallel: bool,
    ) {
        let mac = |((a, s), k): ((&mut Complex<f64>, &Complex<f64>), &Complex<f64>)| {
            *a = if first { s * k } else { *a + s * k };
        };
        if parallel {
            acc.par_iter_mut()
                .zip(s.par_iter())
                .zip(k.par_iter())
                .for_each(mac);
        } else {
            acc.iter_mut().zip(s.iter()).zip(k.iter()).for_each(mac);
        }
    }

    /// The inverse transform of `acc` on the window (zeros when nothing was accumulated).
    fn inverse_window(
        &mut self,
        any: bool,
        (r0, c0): (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        let n1 = self.fft.shape().1;
        let mut out = Array2::zeros(shape);
        if !any {
            return out;
        }
        self.fft
            .inverse_rows(&mut self.acc, &mut self.tmp, &mut self.real, r0 + shape.0);
        for (i, mut row) in out.rows_mut().into_iter().enumerate() {
            let start = (r0 + i) * n1 + c0;
            for (d, s) in row.iter_mut().zip(&self.real[start..start + shape.1]) {
                *d = *s;
            }
        }
        out
    }
}

/// Direct "same"-mode convolution (brute force; the reference in tests).
pub fn convolve_direct(input: ArrayView2<f64>, kernel: ArrayView2<f64>) -> Array2<f64> {
    let (r, c) = input.dim();
    let (k0, k1) = kernel.dim();
    let (c0, c1) = ((k0 / 2) as isize, (k1 / 2) as isize);
    let mut out = Array2::zeros((r, c));
    for i in 0..r as isize {
        for j in 0..c as isize {
            let mut s = 0.0;
            for a in 0..k0 as isize {
                for b in 0..k1 as isize {
                    let (ii, jj) = (i - (a - c0), j - (b - c1));
                    if ii >= 0 && jj >= 0 && ii < r as isize && jj < c as isize {
                        s += input[(ii as usize, jj as usize)] * kernel[(a as usize, b as usize)];
                    }
                }
            }
            out[(i as usize, j as usize)] = s;
        }
    }
    out
}

/// Zero-padded copy of the top-left `rows x cols` of `input` into a row-major buffer of row
/// length `n1` (the FFT grid); the rest of the buffer is zeroed.
fn load_padded(real: &mut [f64], n1: usize, input: ArrayView2<f64>, rows: usize, cols: usize) {
    let (r, c) = (rows.min(input.nrows()), cols.min(input.ncols()));
    real.iter_mut().for_each(|v| *v = 0.0);
    for i in 0..r {
        for (d, s) in real[i * n1..i * n1 + c].iter_mut().zip(input.row(i).iter()) {
            *d = *s;
        }
    }
}

/// Copies the rows of the top-left `rows x cols` of `input` that are not all zero into a
/// row-major buffer of row length `n1` (zero-padded to it), and marks them in `live` (one flag
/// per buffer row; the other rows of the buffer are left as they were and must not be read).
/// Most live columns for which [`MultiConvolver::apply_sum`] transforms an input column by
/// column ([`Fft2::forward_columns`]: per column about an eighth of a full transform's work).
const MAX_SPARSE_COLUMNS: usize = 4;

/// An (input, kernel) pair of spectra for [`MultiConvolver::apply_spectra_window`].
pub type SpectrumPair<'a> = (&'a [Complex<f64>], &'a [Complex<f64>]);

/// An input of [`MultiConvolver::apply_sum_window_hinted`]: kernel index, map, and the rows
/// that may hold anything (`None`: all).
pub type HintedInput<'a> = (usize, ArrayView2<'a, f64>, Option<&'a [bool]>);

/// The indices of the columns of `input` that are not all zero, in `out`, when there are at
/// most `max` of them (else `None`).
fn live_columns<'a>(
    input: ArrayView2<f64>,
    hint: Option<&[bool]>,
    max: usize,
    out: &'a mut Vec<usize>,
) -> Option<&'a [usize]> {
    let mut on = vec![false; input.ncols()];
    let mut n = 0;
    for (i, row) in input.rows().into_iter().enumerate() {
        if hint.is_some_and(|h| !h.get(i).copied().unwrap_or(false)) {
            continue;
        }
        for (j, v) in row.iter().enumerate() {
            if *v != 0.0 && !on[j] {
                on[j] = true;
                n += 1;
                if n > max {
                    return None;
                }
            }
        }
    }
    out.clear();
    out.extend(on.iter().enumerate().filter(|(_, o)| **o).map(|(j, _)| j));
    Some(out)
}

fn load_live_rows(
    real: &mut [f64],
    n1: usize,
    input: ArrayView2<f64>,
    hint: Option<&[bool]>,
    (rows, cols): (usize, usize),
    live: &mut Vec<bool>,
) {
    let (r, c) = (rows.min(input.nrows()), cols.min(input.ncols()));
    live.clear();
    live.resize(real.len() / n1.max(1), false);
    for i in 0..r {
        if hint.is_some_and(|h| !h.get(i).copied().unwrap_or(false)) {
            continue;
        }
        let row = input.row(i);
        if row.iter().take(c).all(|v| *v == 0.0) {
            continue;
        }
        live[i] = true;
        let dst = &mut real[i * n1..(i + 1) * n1];
        for (d, s) in dst[..c].iter_mut().zip(row.iter()) {
            *d = *s;
        }
        dst[c..].fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    fn random(r: usize, c: usize, seed: u64) -> Array2<f64> {
        let mut rng = Rng::new(seed);
        Array2::from_shape_fn((r, c), |_| rng.normal())
    }

    #[test]
    fn fast_len_is_smooth_and_not_smaller() {
        assert_eq!(fast_len(1), 1);
        assert_eq!(fast_len(11), 12);
        assert_eq!(fast_len(1201), 1215);
        assert_eq!(fast_len(97), 98);
    }

    #[test]
    fn fft_convolution_matches_direct_sum() {
        for &(r, c, k0, k1) in &[(13, 17, 5, 3), (20, 9, 7, 7), (1, 30, 1, 5)] {
            let x = random(r, c, 1);
            let k = random(k0, k1, 2);
            let mut conv = Convolver::new(r, c, k.view());
            let fast = conv.apply(x.view());
            let slow = convolve_direct(x.view(), k.view());
            let err = (&fast - &slow).iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(err < 1e-10, "max error {err}");
        }
    }

    #[test]
    fn multi_convolver_sums_direct_convolutions() {
        let (r, c) = (21, 18);
        let (x, y) = (random(r, c, 6), random(r, c, 7));
        let (k, l) = (random(5, 3, 8), random(3, 7, 9));
        let mut m = MultiConvolver::with_fft_size(r, c, &[k.view(), l.view()], r + 7, c + 7);
        let got = m.apply_sum(&[Some(x.view()), Some(y.view())]);
        let want = convolve_direct(x.view(), k.view()) + convolve_direct(y.view(), l.view());
        let err = (&got - &want).iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(err < 1e-10, "{err}");
        let only_y = m.apply_sum(&[None, Some(y.view())]);
        let want_y = convolve_direct(y.view(), l.view());
        assert!((&only_y - &want_y).iter().all(|v| v.abs() < 1e-10));
        // Two kernel spectra and one input: one forward and one inverse more.
        let before = m.fft().transforms();
        let _ = m.apply_sum(&[None, Some(y.view())]);
        assert_eq!(m.fft().transforms() - before, 2);
        // A window of the output is that window of the whole.
        let win = m.apply_sum_window(&[Some(x.view()), Some(y.view())], (3, 5), (r - 7, c - 9));
        let d = (&win - &want.slice(ndarray::s![3..r - 4, 5..c - 4]))
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(d < 1e-10, "{d}");
    }

    #[test]
    fn sparse_columns_are_transformed_column_by_column() {
        // Step-over maps: dwell in two columns only (one of them the last), next to a dense
        // map; the sum equals the direct convolution, and the sparse transform the full one.
        let (r, c) = (21, 26);
        let mut x = Array2::zeros((r, c));
        let z = random(r, c, 20);
        for j in [3, c - 1] {
            x.column_mut(j).assign(&z.column(j));
        }
        let y = random(r, c, 21);
        let (k, l) = (random(5, 7, 22), random(3, 5, 23));
        let mut m = MultiConvolver::with_fft_size(r, c, &[k.view(), l.view()], r + 9, c + 10);
        let got = m.apply_sum(&[Some(x.view()), Some(y.view())]);
        let want = convolve_direct(x.view(), k.view()) + convolve_direct(y.view(), l.view());
        let peak = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let err = (&got - &want).iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(err < 1e-12 * peak, "{err} vs {peak}");
        let fft = Fft2::new(r + 9, c + 10);
        let (n0, n1) = fft.shape();
        let mut real = vec![0.0; n0 * n1];
        load_padded(&mut real, n1, x.view(), r, c);
        let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
        let mut full = tmp.clone();
        fft.forward(&mut real, &mut tmp, &mut full);
        let mut sparse = tmp.clone();
        fft.forward_columns(x.view(), &[3, c - 1], &mut sparse, &mut Vec::new());
        let d = full
            .iter()
            .zip(&sparse)
            .fold(0.0f64, |a, (p, q)| a.max((p - q).norm()));
        assert!(
            d < 1e-12 * full.iter().fold(0.0f64, |a, p| a.max(p.norm())),
            "{d}"
        );
    }

    #[test]
    fn sparse_rows_give_the_same_sum_bit_for_bit() {
        // A line map: one row in five carries dwell; rows skipped by the row transforms. The
        // larger size runs the parallel transforms (at least PARALLEL_MIN_LEN samples).
        for (r, c) in [(23, 19), (500, 531)] {
            sparse_rows_case(r, c);
        }
    }

    fn sparse_rows_case(r: usize, c: usize) {
        let mut x = random(r, c, 10);
        for i in 0..r {
            if i % 5 != 2 {
                x.row_mut(i).fill(0.0);
            }
        }
        let y = random(r, c, 11);
        let (k, l) = (random(5, 3, 12), random(3, 7, 13));
        let mut m = MultiConvolver::with_fft_size(r, c, &[k.view(), l.view()], r + 9, c + 8);
        let got = m.apply_sum(&[Some(x.view()), Some(y.view())]);
        // The reference: full transforms of zero-padded copies.
        let fft = Fft2::new(r + 9, c + 8);
        let (n0, n1) = fft.shape();
        let spec_of = |a: &Array2<f64>, kern: &Array2<f64>| {
            let mut real = vec![0.0; n0 * n1];
            load_padded(&mut real, n1, a.view(), r, c);
            let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
            let mut spec = tmp.clone();
            fft.forward(&mut real, &mut tmp, &mut spec);
            let kh = kernel_hat(&fft, kern.view());
            spec.iter().zip(&kh).map(|(s, k)| s * k).collect::<Vec<_>>()
        };
        let sx = spec_of(&x, &k);
        let mut acc: Vec<Complex<f64>> = spec_of(&y, &l)
            .iter()
            .zip(&sx)
            .map(|(b, a)| *a + *b)
            .collect();
        let mut tmp = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
        let mut real = vec![0.0; n0 * n1];
        fft.inverse(&mut acc, &mut tmp, &mut real);
        for i in 0..r {
            for j in 0..c {
                assert_eq!(got[(i, j)].to_bits(), real[i * n1 + j].to_bits());
            }
        }
        if r * c < 1000 {
            let want = convolve_direct(x.view(), k.view()) + convolve_direct(y.view(), l.view());
            let err = (&got - &want).iter().fold(0.0f64, |a, v| a.max(v.abs()));
            assert!(err < 1e-10, "{err}");
        }
    }

    #[test]
    fn adjoint_is_the_transpose() {
        let (r, c) = (12, 15);
        let x = random(r, c, 3);
        let y = random(r, c, 4);
        let k = random(5, 7, 5);
        let mut conv = Convolver::new(r, c, k.view());
        let ax = conv.apply(x.view());
        let aty = conv.apply_adjoint(y.view());
        let lhs: f64 = ax.iter().zip(y.iter()).map(|(a, b)| a * b).sum();
        let rhs: f64 = x.iter().zip(aty.iter()).map(|(a, b)| a * b).sum();
        assert!((lhs - rhs).abs() < 1e-9 * lhs.abs().max(1.0));
    }
}
