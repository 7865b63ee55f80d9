//! Coarse registration of the after map against the before map, for shifts of several
//! millimetres and rotations of a degree or more, where the linearised registration (the after
//! map's gradient, `effects::registration`) cannot reach: on a surface textured down to the
//! pixel scale the gradient decorrelates within a pixel.
//!
//! Polishing removes a smooth function (its scale is the TIF's), so the fine texture of the
//! before map survives into the after map: both maps are high-passed (minus a masked Gaussian
//! smoothing of `HP_SIGMA_PX` pixels, which takes the figure and most of the removal with it),
//! windowed inside their valid region, and block-averaged by 2 to halve the work. For each
//! rotation of a grid of `2 * ANGLE_STEPS + 1` angles over +-`MAX_ANGLE_DEG`, the rotated after
//! map is phase-correlated with the before map (every fourth angle first, then every angle near
//! the best of those); the angle whose correlation peak is highest wins,
//! refined by a parabola through its neighbours' peaks, and the shift by a parabola through the
//! peak's neighbours. The result follows the registration's convention (`resample`):
//! `out(x) = after(R(theta) (x - c) + c + d)` matches the before map.
//!
//! It only seeds the registration effect: the effect is still accepted on held-out data and
//! refined on the full-resolution maps.

use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex64;

use bonnetlab_process::fft::{fast_len, Fft2};

use crate::grid::{smooth_masked, MapGrid};

/// High-pass scale (pixels).
const HP_SIGMA_PX: f64 = 3.0;
/// Largest rotation searched (degrees).
pub const MAX_ANGLE_DEG: f64 = 2.0;
/// Correlation peak ratio below which the maps are taken not to match.
pub const MIN_PEAK_RATIO: f64 = 10.0;
/// Angles each side of 0.
const ANGLE_STEPS: usize = 20;

/// A coarse estimate and its quality.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coarse {
    /// (dx_mm, dy_mm, rotation_rad) in the registration's convention.
    pub reg: [f64; 3],
    /// Height of the phase-correlation peak over the mean of the correlation surface's
    /// magnitude (a peak below about 10 is not a match).
    pub peak_ratio: f64,
    /// Correlation coefficient of the high-passed maps at this registration (whole pixels of
    /// the half-resolution maps) and with no registration at all.
    pub match_corr: f64,
    pub identity_corr: f64,
}

impl Coarse {
    /// Whether the estimate is a real match that beats no registration: peak ratio at least
    /// [`MIN_PEAK_RATIO`], the texture correlated by at least 0.3 and by 0.1 more than
    /// unregistered (a map without fine texture has nothing to match).
    pub fn is_match(&self) -> bool {
        self.peak_ratio >= MIN_PEAK_RATIO
            && self.match_corr >= 0.3
            && self.match_corr >= self.identity_corr + 0.1
    }
}

/// Correlation coefficient of `b` and `a(x + s)` (s whole pixels: rows, columns) over the pixels
/// valid in both.
fn corr_at(
    b: &Array2<f64>,
    bv: &Array2<bool>,
    a: &Array2<f64>,
    av: &Array2<bool>,
    s: (isize, isize),
) -> f64 {
    let (r, c) = b.dim();
    let (mut sab, mut saa, mut sbb, mut sa, mut sb, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..r {
        let ii = i as isize + s.0;
        if ii < 0 || ii >= r as isize {
            continue;
        }
        for j in 0..c {
            let jj = j as isize + s.1;
            if jj < 0 || jj >= c as isize {
                continue;
            }
            let q = (ii as usize, jj as usize);
            if bv[(i, j)] && av[q] {
                let (x, y) = (b[(i, j)], a[q]);
                sab += x * y;
                saa += y * y;
                sbb += x * x;
                sa += y;
                sb += x;
                n += 1.0;
            }
        }
    }
    if n < 16.0 {
        return 0.0;
    }
    let cov = sab / n - sa * sb / (n * n);
    let va = saa / n - sa * sa / (n * n);
    let vb = sbb / n - sb * sb / (n * n);
    if va > 0.0 && vb > 0.0 {
        cov / (va * vb).sqrt()
    } else {
        0.0
    }
}

/// High-passed, windowed, 2x block-averaged map and its mask.
fn prepare(a: &Array2<f64>, valid: &Array2<bool>) -> (Array2<f64>, Array2<bool>) {
    // Window: a smooth taper of the mask (its own Gaussian smoothing), so the aperture edge
    // does not dominate the correlation. Both smoothings side by side.
    let m = valid.mapv(|v| if v { 1.0 } else { 0.0 });
    let all = Array2::from_elem(valid.dim(), true);
    let (sm, taper) = rayon::join(
        || smooth_masked(a, valid, HP_SIGMA_PX),
        || smooth_masked(&m, &all, 4.0 * HP_SIGMA_PX),
    );
    let taper = taper.mapv(|t| ((t - 0.5) * 2.0).clamp(0.0, 1.0));
    let (r, c) = a.dim();
    let (r2, c2) = (r / 2, c / 2);
    let mut out = Array2::zeros((r2, c2));
    let mut ok = Array2::from_elem((r2, c2), false);
    for i in 0..r2 {
        for j in 0..c2 {
            let (mut s, mut n) = (0.0, 0.0);
            for (di, dj) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let p = (2 * i + di, 2 * j + dj);
                if valid[p] {
                    s += (a[p] - sm[p]) * taper[p];
                    n += 1.0;
                }
            }
            if n > 0.0 {
                out[(i, j)] = s / n;
                ok[(i, j)] = true;
            }
        }
    }
    (out, ok)
}

/// `a` rotated about the centre of its grid: `out(x) = a(R(theta) (x - c) + c)` (bilinear, 0
/// outside), pixels square of side `d` (the ratio of the pixel sides is kept by `aspect`).
fn rotate(a: &Array2<f64>, theta: f64, aspect: f64) -> Array2<f64> {
    let (r, c) = a.dim();
    let (ci, cj) = ((r as f64 - 1.0) / 2.0, (c as f64 - 1.0) / 2.0);
    let (ct, st) = (theta.cos(), theta.sin());
    Array2::from_shape_fn((r, c), |(i, j)| {
        // In units of the x pixel: y offsets scaled by dy / dx.
        let (x, y) = (j as f64 - cj, (i as f64 - ci) * aspect);
        let (xr, yr) = (ct * x - st * y, st * x + ct * y);
        let (u, v) = (ci + yr / aspect, cj + xr);
        if u < 0.0 || v < 0.0 || u > (r - 1) as f64 || v > (c - 1) as f64 {
            return 0.0;
        }
        bonnetlab_process::interp::bilinear(a, u, v)
    })
}

/// Phase-correlation workspace at one size.
struct Correlator {
    fft: Fft2,
    n: (usize, usize),
    before_hat: Vec<Complex64>,
}

impl Correlator {
    fn spectrum(fft: &Fft2, n: (usize, usize), a: &Array2<f64>) -> Vec<Complex64> {
        let mut real = vec![0.0; n.0 * n.1];
        for ((i, j), v) in a.indexed_iter() {
            real[i * n.1 + j] = *v;
        }
        let mut tmp = vec![Complex64::new(0.0, 0.0); fft.spectrum_len()];
        let mut out = tmp.clone();
        fft.forward(&mut real, &mut tmp, &mut out);
        out
    }

    fn new(before: &Array2<f64>) -> Correlator {
        let (r, c) = before.dim();
        // Zero-padded by half, so shifts up to a quarter of the map do not wrap onto others.
        let n = (fast_len(r + r / 2), fast_len(c + c / 2));
        let fft = Fft2::new(n.0, n.1);
        let before_hat = Self::spectrum(&fft, n, before);
        Correlator { fft, n, before_hat }
    }

    /// Correlation peak: (shift in rows, shift in columns, peak ratio), the shift s such that
    /// `a(x + s)` matches the before map.
    fn peak(&self, a: &Array2<f64>) -> Option<(f64, f64, f64)> {
        let ah = Self::spectrum(&self.fft, self.n, a);
        let mut cross: Vec<Complex64> = self
            .before_hat
            .iter()
            .zip(&ah)
            .map(|(b, a)| {
                let z = b.conj() * a;
                let m = z.norm();
                if m > 1e-300 {
                    z / m
                } else {
                    Complex64::new(0.0, 0.0)
                }
            })
            .collect();
        let (n0, n1) = self.n;
        let mut tmp = vec![Complex64::new(0.0, 0.0); self.fft.spectrum_len()];
        let mut real = vec![0.0; n0 * n1];
        self.fft.inverse(&mut cross, &mut tmp, &mut real);
        let (mut best, mut bi) = (f64::NEG_INFINITY, 0usize);
        let mut mean_abs = 0.0;
        for (k, v) in real.iter().enumerate() {
            mean_abs += v.abs();
            if *v > best {
                best = *v;
                bi = k;
            }
        }
        mean_abs /= real.len() as f64;
        if !(best.is_finite() && mean_abs > 0.0) {
            return None;
        }
        let (i, j) = (bi / n1, bi % n1);
        let at = |i: isize, j: isize| {
            real[(i.rem_euclid(n0 as isize) as usize) * n1 + j.rem_euclid(n1 as isize) as usize]
        };
        let para = |m: f64, z: f64, p: f64| {
            let den = m - 2.0 * z + p;
            if den.abs() > 1e-300 {
                (0.5 * (m - p) / den).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        };
        let (ii, jj) = (i as isize, j as isize);
        let di = para(at(ii - 1, jj), best, at(ii + 1, jj));
        let dj = para(at(ii, jj - 1), best, at(ii, jj + 1));
        let wrap = |k: usize, n: usize| {
            if k > n / 2 {
                k as f64 - n as f64
            } else {
                k as f64
            }
        };
        Some((wrap(i, n0) + di, wrap(j, n1) + dj, best / mean_abs))
    }
}

/// Stride of the first pass over the angles (see [`coarse_registration`]): 0.4 deg. Every
/// angle is within 0.2 deg of one of the first pass, which moves a point 50 mm from the centre
/// by 0.17 mm, under a pixel of the half-resolution maps for map pixels of 0.09 mm or more: the
/// correlation peak over the angles is wider than the stride, and the best angle of the first
/// pass lies within a stride of the best of all.
const COARSE_STRIDE: usize = 4;

/// An angle's correlation peak (rows, columns, peak ratio): `None` until evaluated, then the
/// peak if there is one.
type Slot = Option<Option<(f64, f64, f64)>>;

/// The angle with the highest correlation peak: (index, peak).
fn best_of(peaks: &[Option<(f64, f64, f64)>]) -> Option<(usize, (f64, f64, f64))> {
    peaks
        .iter()
        .enumerate()
        .filter_map(|(k, p)| p.map(|p| (k, p)))
        .max_by(|x, y| x.1 .2.total_cmp(&y.1 .2))
}

/// The coarse registration of `after` onto `before` (both on `grid`), or `None` when the maps
/// are too small or have nothing to correlate.
pub fn coarse_registration(
    grid: &MapGrid,
    before: &Array2<f64>,
    bv: &Array2<bool>,
    after: &Array2<f64>,
    av: &Array2<bool>,
) -> Option<Coarse> {
    if grid.rows < 32 || grid.cols < 32 {
        return None;
    }
    let ((b, bm), (a, am)) = rayon::join(|| prepare(before, bv), || prepare(after, av));
    let corr = Correlator::new(&b);
    let aspect = grid.dy_mm / grid.dx_mm;
    let step = MAX_ANGLE_DEG.to_radians() / ANGLE_STEPS as f64;
    // Coarse to fine: every COARSE_STRIDE-th angle, then every angle within a stride of the
    // best, then the neighbours of the best if not yet evaluated (for the parabola).
    let mut peaks: Vec<Slot> = vec![None; 2 * ANGLE_STEPS + 1];
    let eval = |k: usize, peaks: &mut [Slot]| {
        if k < peaks.len() && peaks[k].is_none() {
            let th = (k as f64 - ANGLE_STEPS as f64) * step;
            peaks[k] = Some(corr.peak(&rotate(&a, th, aspect)));
        }
    };
    let best = |peaks: &[Slot]| best_of(&peaks.iter().map(|p| p.flatten()).collect::<Vec<_>>());
    // The first pass's angles side by side (each peak is the one `eval` gives).
    let first: Vec<(usize, Slot)> = (0..=2 * ANGLE_STEPS)
        .step_by(COARSE_STRIDE)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|k| {
            let th = (k as f64 - ANGLE_STEPS as f64) * step;
            (k, Some(corr.peak(&rotate(&a, th, aspect))))
        })
        .collect();
    for (k, p) in first {
        peaks[k] = p;
    }
    let (k0, _) = best(&peaks)?;
    for k in k0.saturating_sub(COARSE_STRIDE - 1)..=k0 + COARSE_STRIDE - 1 {
        eval(k, &mut peaks);
    }
    let (k1, _) = best(&peaks)?;
    for k in [k1.wrapping_sub(1), k1 + 1] {
        eval(k, &mut peaks);
    }
    let peaks: Vec<Option<(f64, f64, f64)>> = peaks.into_iter().map(Option::flatten).collect();
    let (k, (si, sj, ratio)) = best_of(&peaks)?;
    let h = |k: usize| peaks.get(k).copied().flatten().map(|p| p.2);
    let dk = match (k.checked_sub(1).and_then(h), h(k + 1)) {
        (Some(m), Some(p)) => {
            let den = m - 2.0 * ratio + p;
            if den.abs() > 1e-300 {
                (0.5 * (m - p) / den).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
    };
    let th = (k as f64 + dk - ANGLE_STEPS as f64) * step;
    let th_k = (k as f64 - ANGLE_STEPS as f64) * step;
    let am_k = rotate(&am.mapv(|v| if v { 1.0 } else { 0.0 }), th_k, aspect).mapv(|v| v > 0.999);
    let match_corr = corr_at(
        &b,
        &bm,
        &rotate(&a, th_k, aspect),
        &am_k,
        (si.round() as isize, sj.round() as isize),
    );
    let identity_corr = corr_at(&b, &bm, &a, &am, (0, 0));
    // s (half-resolution pixels, rows then columns) -> mm, then d = R(theta) s.
    let (sx, sy) = (2.0 * sj * grid.dx_mm, 2.0 * si * grid.dy_mm);
    let (ct, st) = (th.cos(), th.sin());
    Some(Coarse {
        reg: [ct * sx - st * sy, st * sx + ct * sy, th],
        peak_ratio: ratio,
        match_corr,
        identity_corr,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    /// A textured field (sum of many random waves down to the pixel scale), evaluated anywhere.
    fn field(seed: u64) -> impl Fn(f64, f64) -> f64 {
        let mut rng = Rng::new(seed);
        let waves: Vec<(f64, f64, f64, f64)> = (0..400)
            .map(|_| {
                let f = (rng.uniform() * (100f64).ln() + (0.02f64).ln()).exp(); // 0.02..2 /mm
                let th = rng.uniform() * std::f64::consts::TAU;
                (
                    f * th.cos(),
                    f * th.sin(),
                    rng.uniform() * std::f64::consts::TAU,
                    f.powf(-1.1),
                )
            })
            .collect();
        move |x, y| {
            waves
                .iter()
                .map(|&(fx, fy, ph, a)| a * (std::f64::consts::TAU * (fx * x + fy * y) + ph).cos())
                .sum()
        }
    }

    #[test]
    fn finds_a_large_shift_and_rotation_on_a_textured_round_part() {
        let f = field(4);
        let (n, d) = (200, 0.25);
        let grid = MapGrid::new(n, n, d, d, 0.0, 0.0).unwrap();
        let (cx, cy) = grid.centre_mm();
        let truth = [1.3, -0.85, 0.8f64.to_radians()];
        let (ct, st) = (truth[2].cos(), truth[2].sin());
        let round =
            |i: usize, j: usize| (grid.x_mm(j) - cx).hypot(grid.y_mm(i) - cy) < 0.47 * n as f64 * d;
        let before = Array2::from_shape_fn((n, n), |(i, j)| f(grid.x_mm(j), grid.y_mm(i)));
        // after(R (p - c) + c + d) = before(p) - smooth removal: after(q) = f(R^-1 (q - c - d) + c).
        let after = Array2::from_shape_fn((n, n), |(i, j)| {
            let (qx, qy) = (grid.x_mm(j) - cx - truth[0], grid.y_mm(i) - cy - truth[1]);
            let (px, py) = (ct * qx + st * qy + cx, -st * qx + ct * qy + cy);
            f(px, py) - 30.0 * ((px - cx) / 40.0).cos()
        });
        let bv = Array2::from_shape_fn((n, n), |(i, j)| round(i, j));
        let av = bv.clone();
        let c = coarse_registration(&grid, &before, &bv, &after, &av).unwrap();
        assert!(
            (c.reg[0] - truth[0]).abs() < 0.5 * d && (c.reg[1] - truth[1]).abs() < 0.5 * d,
            "{c:?}"
        );
        assert!((c.reg[2] - truth[2]).abs() < 0.1f64.to_radians(), "{c:?}");
        assert!(c.is_match(), "{c:?}");
        // A surface without fine texture has nothing to match.
        let smooth = |x: f64, y: f64| 50.0 * (x / 17.0).sin() * (y / 23.0).cos();
        let b2 = Array2::from_shape_fn((n, n), |(i, j)| smooth(grid.x_mm(j), grid.y_mm(i)));
        let a2 = Array2::from_shape_fn((n, n), |(i, j)| smooth(grid.x_mm(j) - 1.3, grid.y_mm(i)));
        let c2 = coarse_registration(&grid, &b2, &bv, &a2, &av);
        assert!(c2.is_none_or(|c| !c.is_match()), "{c2:?}");
    }
}
