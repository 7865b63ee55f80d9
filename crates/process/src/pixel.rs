//! How a map's pixels sample the surface: at their centres (point samples) or as the mean over
//! their area, as a camera pixel integrates the fringe over its square.
//!
//! The forward model predicts removal at pixel centres. An interferometer's camera pixel
//! reports the mean over its area instead: the removal convolved with a box of one pixel. Since
//! the removal is a sum of the TIF at the tool's positions, the pixel means are the same sum of
//! the TIF's own box means: [`PixelMean`] is that field (the box given in mm, so a removal on
//! another grid, a coarse screening grid, still sees the map's pixel), and every kernel built
//! from it (motion kernels, line phases, derivative channels, matched filters) sees the pixel
//! as the camera does, above the map's Nyquist too. [`PixelResponse::mean_of`] averages a model
//! over a pixel where a fit compares it with pixel values (the measured spot's shape fit).
//!
//! The box mean is a 5 x 5 Gauss-Legendre rule: exact for polynomials of degree 9 in each
//! axis; across a square-root rim it is the part of the error that remains (test
//! `area_pixels_match_the_pixel_means_of_exact_deposition`).

use crate::tif::RateField;

/// How a map's pixels sample the surface.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum PixelResponse {
    /// Each pixel is the value at its centre (the model's own sampling).
    #[default]
    Point,
    /// Each pixel is the mean over a `dx_mm` x `dy_mm` box centred on it.
    Area { dx_mm: f64, dy_mm: f64 },
}

/// How an instrument's pixels sample a surface, whatever their size: a recipe's
/// `[measurement] pixels`, and a measured spot's ([`crate::tif::measured::SpotOptions`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PixelSampling {
    /// Values at the pixel centres.
    #[default]
    Point,
    /// Means over the pixel's area (a camera pixel).
    Area,
}

impl PixelSampling {
    /// The response of pixels of (`dx_mm`, `dy_mm`) sampled this way.
    pub fn response(self, dx_mm: f64, dy_mm: f64) -> PixelResponse {
        match self {
            PixelSampling::Point => PixelResponse::Point,
            PixelSampling::Area => PixelResponse::area(dx_mm, dy_mm),
        }
    }

    /// The name a recipe uses (`point`, `area`).
    pub fn name(self) -> &'static str {
        match self {
            PixelSampling::Point => "point",
            PixelSampling::Area => "area",
        }
    }

    /// From a recipe's name; `None` for any other.
    pub fn from_name(name: &str) -> Option<PixelSampling> {
        match name {
            "point" => Some(PixelSampling::Point),
            "area" => Some(PixelSampling::Area),
            _ => None,
        }
    }
}

/// Gauss-Legendre nodes (on [-1/2, 1/2]) and weights (summing to 1) of [`PixelResponse::mean_of`]:
/// five per axis, exact for polynomials of degree 9.
const GL_NODES: [f64; 5] = [
    -0.453_089_922_969_332_2,
    -0.269_234_655_052_841_4,
    0.0,
    0.269_234_655_052_841_4,
    0.453_089_922_969_332_2,
];
const GL_WEIGHTS: [f64; 5] = [
    0.118_463_442_528_094_5,
    0.239_314_335_249_683_2,
    0.284_444_444_444_444_4,
    0.239_314_335_249_683_2,
    0.118_463_442_528_094_5,
];

/// Cells per side of the box where a footprint's edge crosses it. A footprint ends in a
/// square-root rim (a Hertz bonnet's pressure), which five nodes integrate badly: fitting an
/// off-centre bonnet spot's pixel means put its centre 2-8e-4 mm off with 5 x 5 nodes, under
/// 7e-5 mm with 4 x 4 cells of them on the boxes the rim crosses (spot-fit test
/// `a_camera_spot_off_the_pixels_is_centred_to_1e_4_mm`).
const EDGE_CELLS: usize = 4;

impl PixelResponse {
    /// The area response of a map with pixel (`dx_mm`, `dy_mm`).
    pub fn area(dx_mm: f64, dy_mm: f64) -> PixelResponse {
        PixelResponse::Area { dx_mm, dy_mm }
    }

    /// Whether pixels are point samples (nothing to apply).
    pub fn is_point(&self) -> bool {
        matches!(self, PixelResponse::Point)
    }

    /// The value a pixel centred on (`x`, `y`) mm reports of `f`: `f(x, y)` for point samples,
    /// its mean over the box (5 x 5 Gauss-Legendre nodes; where some nodes are 0 and others
    /// not, a footprint's edge crosses the box and it takes [`EDGE_CELLS`]^2 cells of them) for
    /// area pixels.
    pub fn mean_of(&self, x: f64, y: f64, f: impl Fn(f64, f64) -> f64) -> f64 {
        self.mean_of_n(x, y, |u, v| [f(u, v)])[0]
    }

    /// [`Self::mean_of`] of a vector-valued `f` (its `N` components averaged alike).
    pub fn mean_of_n<const N: usize>(
        &self,
        x: f64,
        y: f64,
        f: impl Fn(f64, f64) -> [f64; N],
    ) -> [f64; N] {
        match *self {
            PixelResponse::Point => f(x, y),
            PixelResponse::Area { dx_mm, dy_mm } => {
                let (s, edge) = gauss_legendre(x, y, dx_mm, dy_mm, 1, &f);
                if edge {
                    gauss_legendre(x, y, dx_mm, dy_mm, EDGE_CELLS, &f).0
                } else {
                    s
                }
            }
        }
    }
}

/// The mean of `f` over the dx x dy box centred on (x, y) by `k` x `k` cells of 5 x 5
/// Gauss-Legendre nodes, and whether the footprint's edge crosses the box (some nodes where
/// every component is 0, some where one is not).
fn gauss_legendre<const N: usize>(
    x: f64,
    y: f64,
    dx_mm: f64,
    dy_mm: f64,
    k: usize,
    f: &impl Fn(f64, f64) -> [f64; N],
) -> ([f64; N], bool) {
    let kf = k as f64;
    let mut s = [0.0; N];
    let (mut zero, mut some) = (false, false);
    for ca in 0..k {
        let oa = (ca as f64 + 0.5) / kf - 0.5;
        for cb in 0..k {
            let ob = (cb as f64 + 0.5) / kf - 0.5;
            for (a, wa) in GL_NODES.iter().zip(GL_WEIGHTS) {
                for (b, wb) in GL_NODES.iter().zip(GL_WEIGHTS) {
                    let v = f(x + (ob + b / kf) * dx_mm, y + (oa + a / kf) * dy_mm);
                    if v.iter().all(|c| *c == 0.0) {
                        zero = true;
                    } else {
                        some = true;
                    }
                    for (sk, vk) in s.iter_mut().zip(v) {
                        *sk += wa * wb * vk;
                    }
                }
            }
        }
    }
    if k > 1 {
        let w = 1.0 / (kf * kf);
        for sk in s.iter_mut() {
            *sk *= w;
        }
    }
    (s, zero && some)
}

/// A rate field as pixels of a [`PixelResponse`] see it: its mean over the pixel's box around
/// each point (the field itself for point samples). Preserves the volume; reaches half a pixel
/// further.
#[derive(Debug, Clone)]
pub struct PixelMean<F> {
    inner: F,
    response: PixelResponse,
}

impl<F: RateField> PixelMean<F> {
    /// `inner` seen through `response`.
    pub fn new(inner: F, response: PixelResponse) -> PixelMean<F> {
        PixelMean { inner, response }
    }
}

impl<F: RateField> RateField for PixelMean<F> {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.response
            .mean_of(dx_mm, dy_mm, |x, y| self.inner.rate_at_mm(x, y))
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        let (ex, ey) = self.inner.half_extent_mm();
        match self.response {
            PixelResponse::Point => (ex, ey),
            PixelResponse::Area { dx_mm, dy_mm } => (ex + 0.5 * dx_mm, ey + 0.5 * dy_mm),
        }
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        self.inner.volume_rate_nm_mm2_per_s()
    }

    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        let PixelResponse::Area { dx_mm, dy_mm } = self.response else {
            return self.inner.rates_along(along_x, c, t, out);
        };
        let (h_along, h_across) = if along_x {
            (dx_mm, dy_mm)
        } else {
            (dy_mm, dx_mm)
        };
        out.fill(0.0);
        // The kernel builds ask for a pixel's midpoints, evenly spaced: the box along the line
        // is then the mean of m midpoints of the same spacing shifted by half of it, shared
        // between neighbouring points (one field value per point and node across, not five).
        // Across, the five nodes without `mean_of`'s edge cells: refining them too moved the
        // bonnet's area removal by 1e-5 nm of a 0.01 nm model error (session 26), while the
        // spot fit's centre needs them.
        if let Some((m, step)) = even_division(t, h_along) {
            let u: Vec<f64> = (0..t.len() + m - 1)
                .map(|i| t[0] - 0.5 * h_along + (i as f64 + 0.5) * step)
                .collect();
            let mut v = vec![0.0; u.len()];
            for (a, wa) in GL_NODES.iter().zip(GL_WEIGHTS) {
                self.inner
                    .rates_along(along_x, c + a * h_across, &u, &mut v);
                let mut sum: f64 = v[..m].iter().sum();
                for (k, o) in out.iter_mut().enumerate() {
                    if k > 0 {
                        sum += v[k + m - 1] - v[k - 1];
                    }
                    *o += wa * sum / m as f64;
                }
            }
            return;
        }
        let mut ts = vec![0.0; t.len()];
        let mut v = vec![0.0; t.len()];
        for (a, wa) in GL_NODES.iter().zip(GL_WEIGHTS) {
            for (b, wb) in GL_NODES.iter().zip(GL_WEIGHTS) {
                for (s, &x) in ts.iter_mut().zip(t) {
                    *s = x + b * h_along;
                }
                self.inner
                    .rates_along(along_x, c + a * h_across, &ts, &mut v);
                let w = wa * wb;
                for (o, &x) in out.iter_mut().zip(&v) {
                    *o += w * x;
                }
            }
        }
    }
}

/// When `t` is evenly spaced (within 1e-9 of `h`) at `h / m` for an integer m of at least 8:
/// (m, the spacing).
fn even_division(t: &[f64], h: f64) -> Option<(usize, f64)> {
    if t.len() < 2 {
        return None;
    }
    let step = t[1] - t[0];
    if step.is_nan() || step <= 0.0 {
        return None;
    }
    let m = h / step;
    let mr = m.round();
    if mr < 8.0 || (m - mr).abs() > 1e-6 * mr {
        return None;
    }
    t.windows(2)
        .all(|w| ((w[1] - w[0]) - step).abs() <= 1e-9 * h)
        .then_some((mr as usize, step))
}

impl<T: RateField + ?Sized> RateField for &T {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        (**self).rate_at_mm(dx_mm, dy_mm)
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        (**self).half_extent_mm()
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        (**self).volume_rate_nm_mm2_per_s()
    }

    fn rates_along(&self, along_x: bool, c: f64, t: &[f64], out: &mut [f64]) {
        (**self).rates_along(along_x, c, t, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_square_root_edge_across_the_box_takes_the_finer_cells() {
        // f = sqrt(x - x0) for x > x0, 0 before: a rim crossing a 0.25 mm box at 39 places.
        // Analytic mean (2/3) (x1 - x0)^1.5 / dx, x1 the box's right edge; errors over
        // sqrt(dx), the field's size across the box.
        let dx = 0.25;
        let r = PixelResponse::area(dx, dx);
        let (mut five_worst, mut worst): (f64, f64) = (0.0, 0.0);
        for k in 1..40 {
            let x0 = -0.5 * dx + dx * k as f64 / 40.0;
            let f = |x: f64, _y: f64| (x - x0).max(0.0).sqrt();
            let exact = 2.0 / 3.0 * (0.5 * dx - x0).powf(1.5) / dx;
            let (five, _) = gauss_legendre(0.0, 0.0, dx, dx, 1, &|x, y| [f(x, y)]);
            five_worst = five_worst.max((five[0] - exact).abs() / dx.sqrt());
            worst = worst.max((r.mean_of(0.0, 0.0, f) - exact).abs() / dx.sqrt());
        }
        // Measured: 5 x 5 nodes 3.2e-2, with the edge's cells 4.0e-3.
        assert!(
            worst < 0.25 * five_worst,
            "{worst} vs five nodes {five_worst}"
        );
        // A box the edge does not cross keeps the five nodes.
        let g = |x: f64, y: f64| 1.0 + x * x * y;
        let (five, edge) = gauss_legendre(0.1, 0.2, dx, dx, 1, &|x, y| [g(x, y)]);
        assert!(!edge);
        assert_eq!(r.mean_of(0.1, 0.2, g), five[0]);
    }

    #[test]
    fn gauss_legendre_weights_integrate_polynomials_over_the_pixel() {
        let w: f64 = GL_WEIGHTS.iter().sum();
        assert!((w - 1.0).abs() < 1e-15);
        // Mean of x^8 over [-1/2, 1/2] is (1/2)^8 / 9.
        let m: f64 = GL_NODES
            .iter()
            .zip(GL_WEIGHTS)
            .map(|(x, w)| w * x.powi(8))
            .sum();
        assert!((m - 0.5f64.powi(8) / 9.0).abs() < 1e-15, "{m}");
    }

    #[test]
    fn a_line_of_midpoints_takes_the_shared_box_and_agrees_with_the_nodes() {
        // A kernel build's line: 32 midpoints per 0.25 mm pixel over 12 pixels, across the
        // paper's bonnet (its square-root rim included). The shared midpoint box along the line
        // and the 5 x 5 nodes of `rate_at_mm` agree to 5e-6 of the peak (measured: 2-5e-7); an
        // uneven line takes the nodes.
        let b =
            crate::tif::bonnet::BonnetTif::new(&crate::tif::BonnetTifParams::paper(10.0)).unwrap();
        let f = PixelMean::new(&b, PixelResponse::area(0.25, 0.25));
        let t: Vec<f64> = (0..12 * 32)
            .map(|k| -3.0 + (k as f64 + 0.5) * 0.25 / 32.0)
            .collect();
        assert_eq!(even_division(&t, 0.25).map(|(m, _)| m), Some(32));
        let mut out = vec![0.0; t.len()];
        for c in [0.0, 1.3, 2.7] {
            f.rates_along(true, c, &t, &mut out);
            let peak = f.rate_at_mm(0.0, 0.0);
            let worst = t
                .iter()
                .zip(&out)
                .map(|(&x, &o)| (o - f.rate_at_mm(x, c)).abs())
                .fold(0.0f64, f64::max);
            assert!(worst < 5e-6 * peak, "line at {c}: {worst} of {peak}");
            assert!(out.iter().any(|&o| o > 0.01 * peak));
        }
        let mut uneven = t.clone();
        uneven[5] += 1e-3;
        assert!(even_division(&uneven, 0.25).is_none());
    }

    #[test]
    fn the_mean_of_a_gaussian_over_a_pixel_is_the_erf_difference() {
        // Mean over [x - h/2, x + h/2] of exp(-x^2 / (2 s^2)) is
        // s sqrt(pi / 2) (erf((x + h/2) / (s sqrt 2)) - erf((x - h/2) / (s sqrt 2))) / h; erf by
        // its series (independent of the quadrature).
        fn erf(z: f64) -> f64 {
            let mut term = z;
            let mut s = z;
            for n in 1..80 {
                term *= -z * z / n as f64;
                s += term / (2 * n + 1) as f64;
            }
            s * 2.0 / std::f64::consts::PI.sqrt()
        }
        let (sig, h) = (1.3, 0.25);
        let r = PixelResponse::area(h, h);
        for &(x, y) in &[(0.0, 0.0), (0.7, -1.1), (2.9, 3.3)] {
            let one = |t: f64| {
                let c = sig * std::f64::consts::SQRT_2;
                sig * (std::f64::consts::PI / 2.0).sqrt()
                    * (erf((t + h / 2.0) / c) - erf((t - h / 2.0) / c))
                    / h
            };
            let want = one(x) * one(y);
            let got = r.mean_of(x, y, |u, v| (-(u * u + v * v) / (2.0 * sig * sig)).exp());
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
            let p = PixelResponse::Point
                .mean_of(x, y, |u, v| (-(u * u + v * v) / (2.0 * sig * sig)).exp());
            assert!((p - want).abs() > 1e-3 * want, "the box must matter here");
        }
    }
}
