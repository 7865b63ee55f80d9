//! Perturbation channels of the removal model: what a small displacement of the tool does to
//! the removal, for the vibration coupling (and any caller that perturbs the tool around its
//! commanded state).
//!
//! - [`OffsetTif`]: the instantaneous TIF at an offset change δ (mm, at the contact). The
//!   contact radius is a(h) = sqrt(2 R h − h²); the footprint keeps its shape scaled by
//!   a(h0 + δ) / a0 and the peak rate scales as ((h0 + δ) / h0)^γ:
//!   T(q; δ) = ((h0 + δ) / h0)^γ · T0(q · a0 / a(h0 + δ)), T0 any [`RateField`]. A lateral
//!   displacement u along a map axis e moves it: T(q − u e; δ).
//! - [`DerivativeKernels`]: the derivative kernels of T for an expansion in (u, δ), second
//!   order and δ to fourth: K_l = ∂T/∂l, K_ll = ∂²T/∂l², K_h = ∂T/∂δ, K_hh = ∂²T/∂δ²,
//!   K_lh = ∂²T/∂l∂δ, K_hhh = ∂³T/∂δ³, K_hhhh = ∂⁴T/∂δ⁴ (the footprint's width enters the
//!   transfer at f as exp(−2π²σ²s²f²): in the spindle imprint band of the sample run, 0.3-0.46
//!   per mm, a 5 N forcing moves it far beyond second order, and a second-order expansion put
//!   the imprint's power 7-36 % below the exact deposition's there), sampled on the map pitch
//!   (finite differences of the continuous model: lateral ones over one pixel, offset ones over
//!   5 % of h0 on pixel-area means, because a footprint with a hard edge has an offset
//!   derivative concentrated on its rim; the means taken back to point values to second order
//!   in the pixel).
//! - [`WeightedDwell`]: weighted dwell maps, N channels at once: every sample's dwell dt times a
//!   weight per channel (u, u², δ, ...), Keys cubic splat (mass, centroid and second moment
//!   kept). Convolved with the derivative kernels they give the perturbation's removal (see
//!   [`convolve_channels`]); the unperturbed removal is [`crate::removal::FastRemoval`]'s.
//!
//! The exact reference, independent of the expansion, is the process crate's one exact
//! time-domain deposition, [`crate::modulated::deposit_exact_modulated`]: T(q − u e; δ) is the
//! [`Modulation`] of [`OffsetTif::modulation`] with the displacement u e.
//!
//! Units: mm, s, nm/s; dwell in s per pixel; removal in nm.

use ndarray::{Array2, ArrayView2, CowArray, Ix2};
use rayon::prelude::*;

use crate::fft::{fast_len, MultiConvolver};
use crate::grid::Grid;
use crate::modulated::Modulation;
use crate::pixel::PixelResponse;
use crate::removal::keys_weights;
use crate::tif::RateField;

/// A map axis (the direction of a lateral displacement).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
}

impl Axis {
    /// Unit vector (x, y).
    pub fn unit(self) -> (f64, f64) {
        match self {
            Axis::X => (1.0, 0.0),
            Axis::Y => (0.0, 1.0),
        }
    }
}

/// The offset- and position-dependent removal rate of a bonnet whose offset changes by δ.
#[derive(Clone, Copy)]
pub struct OffsetTif<'a> {
    base: &'a dyn RateField,
    h0_mm: f64,
    radius_mm: f64,
    gamma: f64,
    a0_mm: f64,
}

impl<'a> OffsetTif<'a> {
    /// `base` is the TIF at the nominal offset `h0_mm` of a bonnet of radius `radius_mm`;
    /// `pressure_exponent` is γ.
    pub fn new(
        base: &'a dyn RateField,
        h0_mm: f64,
        radius_mm: f64,
        pressure_exponent: f64,
    ) -> OffsetTif<'a> {
        let a0 = (2.0 * radius_mm * h0_mm - h0_mm * h0_mm).max(1e-18).sqrt();
        OffsetTif {
            base,
            h0_mm,
            radius_mm,
            gamma: pressure_exponent,
            a0_mm: a0,
        }
    }

    /// Nominal offset h0, mm.
    pub fn h0_mm(&self) -> f64 {
        self.h0_mm
    }

    /// Footprint scale a(h0 + δ) / a0 and rate factor at offset change δ.
    fn scale(&self, delta_mm: f64) -> (f64, f64) {
        let h = (self.h0_mm + delta_mm).max(1e-9);
        let a = (2.0 * self.radius_mm * h - h * h).max(1e-18).sqrt();
        (a / self.a0_mm, (h / self.h0_mm).powf(self.gamma))
    }

    /// The instantaneous TIF at offset change δ and lateral displacement `u_mm` along
    /// `lateral` as a modulation of the nominal one (rate factor, widening, displacement),
    /// for the exact deposition.
    pub fn modulation(&self, u_mm: f64, lateral: Axis, delta_mm: f64) -> Modulation {
        let (sc, f) = self.scale(delta_mm);
        let (lx, ly) = lateral.unit();
        Modulation {
            dx_mm: u_mm * lx,
            dy_mm: u_mm * ly,
            rate: f,
            scale: sc,
        }
    }

    /// Rate (nm/s) at offset (dx, dy) mm from the nominal tool centre, with offset change δ.
    pub fn rate(&self, dx_mm: f64, dy_mm: f64, delta_mm: f64) -> f64 {
        let (sc, f) = self.scale(delta_mm);
        f * self.base.rate_at_mm(dx_mm / sc, dy_mm / sc)
    }

    /// The rate (nm/s) at offset change δ as a function of (dx, dy) mm (the scale factors
    /// computed once).
    pub fn at_offset(&self, delta_mm: f64) -> impl Fn(f64, f64) -> f64 + '_ {
        let (sc, f) = self.scale(delta_mm);
        let inv = 1.0 / sc;
        move |dx, dy| f * self.base.rate_at_mm(dx * inv, dy * inv)
    }

    /// Half-extent (x, y) in mm for offset changes up to |δ| = `delta_max_mm`.
    pub fn half_extent_mm(&self, delta_max_mm: f64) -> (f64, f64) {
        let (ex, ey) = self.base.half_extent_mm();
        let (sc, _) = self.scale(delta_max_mm.abs());
        (ex * sc, ey * sc)
    }
}

/// Offset step of the finite differences, as a fraction of h0 (the second-difference error is
/// O(step²) relative: 0.25 % at 5 %).
const OFFSET_STEP: f64 = 0.05;
/// Sub-samples per pixel side for the offset kernels.
const SUPERSAMPLE: usize = 6;

/// The derivative kernels on a common (2 hy + 1) x (2 hx + 1) grid of pitch (dx, dy), centre
/// at the middle pixel.
#[derive(Debug, Clone)]
pub struct DerivativeKernels {
    pub kl: Array2<f64>,
    pub kll: Array2<f64>,
    pub kh: Array2<f64>,
    pub khh: Array2<f64>,
    pub klh: Array2<f64>,
    pub khhh: Array2<f64>,
    pub khhhh: Array2<f64>,
    /// Half widths in pixels (rows, cols).
    pub half: (usize, usize),
}

impl DerivativeKernels {
    /// The kernels of maps whose pixels are point samples.
    pub fn sample(t: &OffsetTif<'_>, dx_mm: f64, dy_mm: f64, lateral: Axis) -> DerivativeKernels {
        Self::sample_seen(t, dx_mm, dy_mm, lateral, PixelResponse::Point)
    }

    /// The kernels as pixels of `response` see the removal: with area pixels every kernel
    /// value is the box mean ([`PixelResponse::mean_of`]) of the instantaneous rate, taken
    /// outermost (after the footprint's widening with the offset, so the box does not widen
    /// with it), and differenced as the point kernels are (one pixel along the lateral axis,
    /// `OFFSET_STEP` of h0 in the offset).
    pub fn sample_seen(
        t: &OffsetTif<'_>,
        dx_mm: f64,
        dy_mm: f64,
        lateral: Axis,
        response: PixelResponse,
    ) -> DerivativeKernels {
        let eh = OFFSET_STEP * t.h0_mm;
        let (ex, ey) = t.half_extent_mm(2.0 * eh);
        let (bx, by) = match response {
            PixelResponse::Area { dx_mm, dy_mm } => (0.5 * dx_mm, 0.5 * dy_mm),
            PixelResponse::Point => (0.0, 0.0),
        };
        let hx = ((ex + bx) / dx_mm).ceil() as usize + 2;
        let hy = ((ey + by) / dy_mm).ceil() as usize + 2;
        let shape = (2 * hy + 1, 2 * hx + 1);
        let (lx, ly) = lateral.unit();
        let el = match lateral {
            Axis::X => dx_mm,
            Axis::Y => dy_mm,
        };
        let n = SUPERSAMPLE;
        let rows: Vec<Vec<[f64; 7]>> = (0..shape.0)
            .into_par_iter()
            .map(|i| {
                let y = (i as f64 - hy as f64) * dy_mm;
                let mut out = vec![[0.0; 7]; shape.1];
                for (j, o) in out.iter_mut().enumerate() {
                    let x = (j as f64 - hx as f64) * dx_mm;
                    // The rate with the tool moved s pixels along the lateral axis and the
                    // offset changed by d, as the map's pixel reads it.
                    let seen = |s: f64, d: f64| {
                        let (px, py) = (x + s * lx * el, y + s * ly * el);
                        response.mean_of(px, py, |a, b| t.rate(a, b, d))
                    };
                    // Point samples: the lateral kernels at the point; the offset kernels as
                    // pixel-area means (the footprint edge moves continuously with δ, so the
                    // offset derivatives of a footprint with a hard edge stay bounded), taken
                    // back to point values below.
                    let avg = |s: f64, d: f64| {
                        let mut acc = 0.0;
                        for a in 0..n {
                            let oy = ((a as f64 + 0.5) / n as f64 - 0.5) * dy_mm;
                            for b in 0..n {
                                let ox = ((b as f64 + 0.5) / n as f64 - 0.5) * dx_mm;
                                acc += t.rate(x + ox + s * lx * el, y + oy + s * ly * el, d);
                            }
                        }
                        acc / (n * n) as f64
                    };
                    let off = |s: f64, d: f64| {
                        if response.is_point() {
                            avg(s, d)
                        } else {
                            seen(s, d)
                        }
                    };
                    let (c, p, m) = (seen(0.0, 0.0), seen(1.0, 0.0), seen(-1.0, 0.0));
                    o[0] = (p - m) / (2.0 * el);
                    o[1] = (p - 2.0 * c + m) / (el * el);
                    let (ac, hp, hm) = (off(0.0, 0.0), off(0.0, eh), off(0.0, -eh));
                    o[2] = (hp - hm) / (2.0 * eh);
                    o[3] = (hp - 2.0 * ac + hm) / (eh * eh);
                    let dh = |s: f64| (off(s, eh) - off(s, -eh)) / (2.0 * eh);
                    o[4] = (dh(1.0) - dh(-1.0)) / (2.0 * el);
                    let (hp2, hm2) = (off(0.0, 2.0 * eh), off(0.0, -2.0 * eh));
                    o[5] = (hp2 - 2.0 * hp + 2.0 * hm - hm2) / (2.0 * eh * eh * eh);
                    o[6] = (hp2 - 4.0 * hp + 6.0 * ac - 4.0 * hm + hm2) / (eh * eh * eh * eh);
                }
                out
            })
            .collect();
        let pick = |c: usize| Array2::from_shape_fn(shape, |(i, j)| rows[i][j][c]);
        // The offset kernels of point samples are pixel-area means: the mean over a dx x dy
        // pixel is the point value plus (dx² ∂xx + dy² ∂yy) / 24, a low-pass of
        // 1 − (π f dx)² / 6 that took 2-4 % of the imprint's power at 0.30-0.46 per mm on
        // 0.25 mm pixels (the exact deposition evaluates the rate at pixel centres). Taken back
        // to second order in the pixel; area pixels keep their means.
        let point = |c: usize| {
            let a = pick(c);
            if !response.is_point() {
                return a;
            }
            let at = |i: isize, j: isize| {
                if i < 0 || j < 0 || i as usize >= shape.0 || j as usize >= shape.1 {
                    0.0
                } else {
                    a[(i as usize, j as usize)]
                }
            };
            Array2::from_shape_fn(shape, |(i, j)| {
                let (i, j) = (i as isize, j as isize);
                let c0 = at(i, j);
                let lx = at(i, j - 1) - 2.0 * c0 + at(i, j + 1);
                let ly = at(i - 1, j) - 2.0 * c0 + at(i + 1, j);
                c0 - (lx + ly) / 24.0
            })
        };
        DerivativeKernels {
            kl: pick(0),
            kll: pick(1),
            kh: point(2),
            khh: point(3),
            klh: point(4),
            khhh: point(5),
            khhhh: point(6),
            half: (hy, hx),
        }
    }

    /// The kernels in the order of [`Derivative`].
    pub fn views(&self) -> [ArrayView2<'_, f64>; 7] {
        [
            self.kl.view(),
            self.kll.view(),
            self.kh.view(),
            self.khh.view(),
            self.klh.view(),
            self.khhh.view(),
            self.khhhh.view(),
        ]
    }
}

/// Which derivative kernel a weighted dwell channel is convolved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Derivative {
    L = 0,
    Ll = 1,
    H = 2,
    Hh = 3,
    Lh = 4,
    Hhh = 5,
    Hhhh = 6,
}

/// `N` weighted dwell maps (s per pixel) on one grid, filled in one pass over the samples; each
/// channel is a contiguous map (read in place by [`WeightedDwell::channel_view`]).
///
/// Consecutive samples on one raster line share their row (an X scan) or column (a Y scan)
/// and so one of the two cubic weight vectors; while they also share the base pixel, their
/// other-axis taps are summed first and spread over the shared axis once (4 N multiply-adds a
/// sample instead of 16 N). [`WeightedDwell::finish`] spreads the last such run; the readers
/// require it.
#[derive(Debug, Clone)]
pub struct WeightedDwell<const N: usize> {
    pub grid: Grid,
    /// Channel-major: channel c is `data[c * cells..(c + 1) * cells]`.
    data: Vec<f64>,
    /// Channels that received a non-zero weight.
    touched: [bool; N],
    pending: Option<Pending<N>>,
    /// Fractional (row, col) index of the previous sample, bit for bit.
    last: (u64, u64),
}

/// Samples sharing base pixel (i0, j0) and, bit for bit, their fraction on `shared`: their
/// dwell times weight times the taps along the other axis, summed.
#[derive(Debug, Clone)]
struct Pending<const N: usize> {
    i0: isize,
    j0: isize,
    shared: Shared,
    frac: f64,
    acc: [[f64; N]; 4],
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shared {
    Row,
    Col,
}

impl<const N: usize> WeightedDwell<N> {
    pub fn new(grid: Grid) -> Self {
        WeightedDwell {
            grid,
            data: crate::memory::zeroed(N * grid.rows * grid.cols),
            touched: [false; N],
            pending: None,
            last: (u64::MAX, u64::MAX),
        }
    }

    /// Adds dt · w[c] at (x, y) mm to every channel c, 4 x 4 Keys cubic weights (mass, centroid
    /// and second moment kept). The bilinear splat low-passes the weighted dwell along the path
    /// by sinc²(f dx): on the sample run's 0.25 mm pixels 8 % of the imprint's power at
    /// 0.46 per mm (the spindle imprint band).
    pub fn add(&mut self, x_mm: f64, y_mm: f64, dt_s: f64, w: &[f64; N]) {
        let g = &self.grid;
        let (u, v) = g.frac_index(x_mm, y_mm);
        if !(u > -2.0 && v > -2.0 && u < g.rows as f64 + 1.0 && v < g.cols as f64 + 1.0) {
            return;
        }
        let (i0, j0) = (u.floor() as isize, v.floor() as isize);
        let (fu, fv) = (u - i0 as f64, v - j0 as f64);
        let last = std::mem::replace(&mut self.last, (fu.to_bits(), fv.to_bits()));
        let fits = |p: &Pending<N>| {
            p.i0 == i0
                && p.j0 == j0
                && match p.shared {
                    Shared::Row => p.frac.to_bits() == fu.to_bits(),
                    Shared::Col => p.frac.to_bits() == fv.to_bits(),
                }
        };
        if !self.pending.as_ref().is_some_and(fits) {
            self.flush();
            let (shared, frac) = if last.1 == fv.to_bits() && last.0 != fu.to_bits() {
                (Shared::Col, fv)
            } else {
                (Shared::Row, fu)
            };
            self.pending = Some(Pending {
                i0,
                j0,
                shared,
                frac,
                acc: [[0.0; N]; 4],
            });
        }
        for (t, wc) in self.touched.iter_mut().zip(w) {
            *t |= *wc != 0.0 && dt_s != 0.0;
        }
        let p = self.pending.as_mut().expect("set above");
        let taps = keys_weights(if p.shared == Shared::Row { fv } else { fu });
        for (row, t) in p.acc.iter_mut().zip(taps) {
            let k = t * dt_s;
            for c in 0..N {
                row[c] += k * w[c];
            }
        }
    }

    /// Spreads the samples summed last (see the type's docs); call after the last `add`.
    pub fn finish(&mut self) {
        self.flush();
    }

    fn flush(&mut self) {
        let Some(p) = self.pending.take() else { return };
        let g = &self.grid;
        let cells = g.rows * g.cols;
        let shared = keys_weights(p.frac);
        for (a, &ws) in shared.iter().enumerate() {
            for (b, other) in p.acc.iter().enumerate() {
                let (i, j) = match p.shared {
                    Shared::Row => (p.i0 - 1 + a as isize, p.j0 - 1 + b as isize),
                    Shared::Col => (p.i0 - 1 + b as isize, p.j0 - 1 + a as isize),
                };
                if i < 0 || j < 0 || i as usize >= g.rows || j as usize >= g.cols {
                    continue;
                }
                let at = i as usize * g.cols + j as usize;
                for (c, o) in other.iter().enumerate() {
                    self.data[c * cells + at] += ws * o;
                }
            }
        }
    }

    /// Channel `c` as a map on the grid.
    pub fn channel(&self, c: usize) -> Array2<f64> {
        self.channel_view(c).to_owned()
    }

    /// Channel `c` as a view of its map (no copy).
    pub fn channel_view(&self, c: usize) -> ArrayView2<'_, f64> {
        assert!(c < N, "channel {c} of {N}");
        assert!(self.pending.is_none(), "WeightedDwell read before finish()");
        let g = &self.grid;
        let cells = g.rows * g.cols;
        ArrayView2::from_shape((g.rows, g.cols), &self.data[c * cells..(c + 1) * cells])
            .expect("each channel holds rows x cols values")
    }

    /// True when channel `c` received no non-zero weight.
    pub fn is_zero(&self, c: usize) -> bool {
        assert!(self.pending.is_none(), "WeightedDwell read before finish()");
        !self.touched[c]
    }
}

/// Convolution workspace of the derivative kernels on a dwell grid: `apply` sums channels, each
/// with its kernel, through one inverse FFT ("same" mode on the dwell grid).
pub struct KernelConvolver {
    conv: MultiConvolver,
}

impl std::fmt::Debug for KernelConvolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "KernelConvolver({:?})", self.conv)
    }
}

impl KernelConvolver {
    /// For dwell maps on `dwell_grid` (the map grid grown by at least the kernels' half widths:
    /// the transform is the dwell grid's size, so outputs inside the map grid are exact).
    pub fn new(kernels: &DerivativeKernels, dwell_grid: &Grid) -> KernelConvolver {
        let views = kernels.views();
        KernelConvolver {
            conv: MultiConvolver::with_fft_size(
                dwell_grid.rows,
                dwell_grid.cols,
                &views,
                fast_len(dwell_grid.rows),
                fast_len(dwell_grid.cols),
            ),
        }
    }

    /// `sum (channel ⊛ kernel)` on the dwell grid.
    pub fn apply(&mut self, terms: &[(ArrayView2<'_, f64>, Derivative)]) -> Array2<f64> {
        self.apply_window(terms, (0, 0), self.conv.input_dim())
    }

    /// [`KernelConvolver::apply`] on the window of `shape` at `origin` of the dwell grid only
    /// (the map grid inside its grown dwell grid, with no full-size output formed).
    pub fn apply_window(
        &mut self,
        terms: &[(ArrayView2<'_, f64>, Derivative)],
        origin: (usize, usize),
        shape: (usize, usize),
    ) -> Array2<f64> {
        // Channels sharing a kernel are added first (one transform each kernel).
        let mut by_kernel: [Vec<ArrayView2<'_, f64>>; 7] = Default::default();
        for (map, k) in terms {
            by_kernel[*k as usize].push(map.view());
        }
        let sums: Vec<Option<CowArray<'_, f64, Ix2>>> = by_kernel
            .iter()
            .map(|maps| match maps.as_slice() {
                [] => None,
                [one] => Some(CowArray::from(one.view())),
                [first, rest @ ..] => {
                    let mut sum = first.to_owned();
                    for m in rest {
                        sum += m;
                    }
                    Some(CowArray::from(sum))
                }
            })
            .collect();
        let inputs: Vec<Option<ArrayView2<f64>>> =
            sums.iter().map(|s| s.as_ref().map(|c| c.view())).collect();
        self.conv.apply_sum_window(&inputs, origin, shape)
    }
}

/// Convolves weighted dwell channels with the derivative kernels: `terms` lists (channel,
/// kernel); the result is on the dwell grid. Convenience over [`KernelConvolver`].
pub fn convolve_channels(
    kernels: &DerivativeKernels,
    dwell_grid: &Grid,
    terms: &[(&Array2<f64>, Derivative)],
) -> Array2<f64> {
    let views: Vec<(ArrayView2<f64>, Derivative)> =
        terms.iter().map(|(m, k)| (m.view(), *k)).collect();
    KernelConvolver::new(kernels, dwell_grid).apply(&views)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::GaussianTif;

    #[test]
    fn offset_scaling_changes_volume_as_h_to_gamma_times_area() {
        let g = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
        let (h0, r) = (0.6, 20.0);
        let t = OffsetTif::new(&g, h0, r, 0.5);
        let vol = |d: f64| {
            let mut s = 0.0;
            for i in -200..=200 {
                for j in -200..=200 {
                    s += t.rate(i as f64 * 0.025, j as f64 * 0.025, d) * 0.025 * 0.025;
                }
            }
            s
        };
        let (v0, v1) = (vol(0.0), vol(0.03));
        let a2 = |h: f64| 2.0 * r * h - h * h;
        let expected = ((h0 + 0.03) / h0).powf(0.5) * a2(h0 + 0.03) / a2(h0);
        assert!(
            (v1 / v0 - expected).abs() < 1e-4,
            "{} vs {expected}",
            v1 / v0
        );
    }

    #[test]
    fn exact_deposition_of_the_modulation_is_the_instantaneous_tif() {
        // A tool resting at one point with a constant offset change and lateral displacement:
        // the one exact deposition, modulated, removes dt times T(q − u e; δ) at every pixel.
        use crate::modulated::deposit_exact_modulated;
        use crate::path::PathLog;
        use crate::removal::ExactOptions;
        let g = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
        let t = OffsetTif::new(&g, 0.6, 20.0, 0.5);
        let grid = Grid::new(41, 41, 0.25, 0.25, -5.0, -5.0).unwrap();
        let p = PathLog::new(vec![0.0, 2.0], vec![0.1, 0.1], vec![-0.2, -0.2]).unwrap();
        let (u, d) = (0.3, 0.05);
        let m = t.modulation(u, Axis::Y, d);
        let r = deposit_exact_modulated(&p, &g, &grid, &ExactOptions::default(), |_| m).unwrap();
        let mut worst = 0.0f64;
        for ((i, j), v) in r.indexed_iter() {
            let want = 2.0 * t.rate(grid.x_mm(j) - 0.1, grid.y_mm(i) + 0.2 - u, d);
            worst = worst.max((v - want).abs());
        }
        assert!(worst < 1e-9, "{worst}");
        assert!(r.sum() > 1.0);
    }

    #[test]
    fn kernels_match_analytic_derivatives_of_a_gaussian() {
        // Pure shift derivatives of a Gaussian: ∂x T = −x/σ² T, ∂²x T = (x²/σ⁴ − 1/σ²) T.
        let sigma = 1.0;
        let g = GaussianTif::new(sigma, 12.0, 5.0).unwrap();
        let (h0, r) = (0.6, 20.0);
        let t = OffsetTif::new(&g, h0, r, 0.5);
        let dx = 0.05;
        let k = DerivativeKernels::sample(&t, dx, dx, Axis::X);
        let (hy, hx) = k.half;
        for &(i, j) in &[(0isize, 10isize), (5, -20), (-7, 3)] {
            let (x, y) = (j as f64 * dx, i as f64 * dx);
            let tv = 5.0 * (-(x * x + y * y) / (2.0 * sigma * sigma)).exp();
            let idx = ((hy as isize + i) as usize, (hx as isize + j) as usize);
            assert!(
                (k.kl[idx] - (-x * tv)).abs() < 2e-3 * 5.0,
                "{} vs {}",
                k.kl[idx],
                -x * tv
            );
            assert!((k.kll[idx] - (x * x - 1.0) * tv).abs() < 5e-3 * 5.0);
            // Offset derivative from the chain rule: T(q; δ) = f(δ) T0(q / s(δ)).
            let ds = (r - h0) / (2.0 * r * h0 - h0 * h0); // d ln a / dh
            let df = 0.5 / h0; // d ln f / dh
            let dlnt = df + (x * x + y * y) / (sigma * sigma) * ds;
            assert!(
                (k.kh[idx] - dlnt * tv).abs() < 1e-2 * (dlnt * tv).abs().max(1e-2),
                "{} vs {}",
                k.kh[idx],
                dlnt * tv
            );
        }
    }

    #[test]
    fn weighted_dwell_keeps_mass_and_centroid_per_channel() {
        let g = Grid::new(20, 20, 0.5, 0.25, 1.0, -2.0).unwrap();
        let mut d = WeightedDwell::<2>::new(g);
        d.add(4.37, 0.113, 2.0, &[1.0, -3.0]);
        d.finish();
        let (c0, c1) = (d.channel(0), d.channel(1));
        let (mut m0, mut mx, mut my) = (0.0, 0.0, 0.0);
        for ((i, j), &w) in c0.indexed_iter() {
            m0 += w;
            mx += w * g.x_mm(j);
            my += w * g.y_mm(i);
        }
        assert!((m0 - 2.0).abs() < 1e-12);
        assert!((mx / m0 - 4.37).abs() < 1e-12 && (my / m0 - 0.113).abs() < 1e-12);
        assert!((c1.sum() + 6.0).abs() < 1e-12);
        assert!(!d.is_zero(1));
    }

    /// The run-summed splat against each sample's own 16 taps: samples along X lines (one row
    /// fraction), along Y lines, and scattered, with the grid's borders crossed.
    #[test]
    fn summed_runs_splat_as_every_sample_on_its_own() {
        let g = Grid::new(17, 23, 0.25, 0.5, -1.0, 2.0).unwrap();
        let mut rng = bonnetlab_surface::rng::Rng::new(11);
        let mut pts: Vec<(f64, f64)> = Vec::new();
        for k in 0..400 {
            pts.push((-2.0 + k as f64 * 0.037, 2.0 + 1.37));
        }
        for k in 0..300 {
            pts.push((1.3, 1.0 + k as f64 * 0.029));
        }
        for _ in 0..200 {
            pts.push((rng.uniform() * 13.0 - 2.5, rng.uniform() * 6.0 + 1.0));
        }
        let mut d = WeightedDwell::<3>::new(g);
        let mut want = vec![[0.0f64; 3]; g.rows * g.cols];
        for &(x, y) in &pts {
            let w = [rng.normal(), 1.0, rng.uniform()];
            let dt = 0.01 + rng.uniform();
            d.add(x, y, dt, &w);
            let (u, v) = g.frac_index(x, y);
            crate::removal::cubic_taps(g.rows, g.cols, u, v, |i, j, wi, wj| {
                for c in 0..3 {
                    want[i * g.cols + j][c] += wi * wj * dt * w[c];
                }
            });
        }
        d.finish();
        let mut worst = 0.0f64;
        for c in 0..3 {
            for ((i, j), v) in d.channel(c).indexed_iter() {
                let cell: &[f64; 3] = &want[i * g.cols + j];
                worst = worst.max((v - cell[c]).abs());
            }
        }
        assert!(worst < 1e-12, "{worst}");
        assert!(want.iter().any(|v| v[1] > 0.1));
    }

    #[test]
    fn channel_views_read_the_interleaved_splat_and_windows_match_the_full_convolution() {
        let g = GaussianTif::new(1.0, 6.0, 2.0).unwrap();
        let t = OffsetTif::new(&g, 0.6, 20.0, 0.5);
        let k = DerivativeKernels::sample(&t, 0.5, 0.5, Axis::X);
        let (hy, hx) = k.half;
        let grid = Grid::new(2 * hy + 13, 2 * hx + 9, 0.5, 0.5, 0.0, 0.0).unwrap();
        let mut d = WeightedDwell::<3>::new(grid);
        let mut rng = bonnetlab_surface::rng::Rng::new(7);
        for _ in 0..40 {
            let (x, y) = (rng.uniform() * 4.0 + 1.0, rng.uniform() * 5.0 + 1.0);
            d.add(x, y, 0.1, &[rng.normal(), rng.normal(), 1.0]);
        }
        d.finish();
        for c in 0..3 {
            let (v, owned) = (d.channel_view(c), d.channel(c));
            assert_eq!(v.dim(), (grid.rows, grid.cols));
            assert!(v.iter().zip(owned.iter()).all(|(a, b)| a == b));
        }
        let mut conv = KernelConvolver::new(&k, &grid);
        // Two channels on one kernel are summed before their transform.
        let terms = [
            (d.channel_view(0), Derivative::H),
            (d.channel_view(1), Derivative::H),
            (d.channel_view(2), Derivative::Lh),
        ];
        let full = conv.apply(&terms);
        let (o, shape) = ((3, 2), (grid.rows - 5, grid.cols - 4));
        let win = conv.apply_window(&terms, o, shape);
        let sum01 = &d.channel(0) + &d.channel(1);
        let direct = conv.apply(&[
            (sum01.view(), Derivative::H),
            (d.channel_view(2), Derivative::Lh),
        ]);
        for ((i, j), v) in win.indexed_iter() {
            assert!((v - full[(i + o.0, j + o.1)]).abs() < 1e-12);
            assert!((full[(i + o.0, j + o.1)] - direct[(i + o.0, j + o.1)]).abs() < 1e-12);
        }
        assert!(full.iter().any(|v| v.abs() > 1e-6));
    }

    #[test]
    fn kernel_convolution_of_a_point_is_the_kernel() {
        let g = GaussianTif::new(1.0, 6.0, 2.0).unwrap();
        let t = OffsetTif::new(&g, 0.6, 20.0, 0.5);
        let k = DerivativeKernels::sample(&t, 0.5, 0.5, Axis::Y);
        let (hy, hx) = k.half;
        let grid = Grid::new(2 * hy + 11, 2 * hx + 11, 0.5, 0.5, 0.0, 0.0).unwrap();
        let mut a = Array2::zeros((grid.rows, grid.cols));
        let (ci, cj) = (hy + 5, hx + 5);
        a[(ci, cj)] = 2.0;
        let mut b = Array2::zeros((grid.rows, grid.cols));
        b[(ci, cj)] = 1.0;
        let out = convolve_channels(&k, &grid, &[(&a, Derivative::H), (&b, Derivative::H)]);
        let out2 = convolve_channels(&k, &grid, &[(&a, Derivative::Lh)]);
        for di in 0..=2 * hy {
            for dj in 0..=2 * hx {
                let (i, j) = (ci + di - hy, cj + dj - hx);
                assert!((out[(i, j)] - 3.0 * k.kh[(di, dj)]).abs() < 1e-9);
                assert!((out2[(i, j)] - 2.0 * k.klh[(di, dj)]).abs() < 1e-9);
            }
        }
    }
}
