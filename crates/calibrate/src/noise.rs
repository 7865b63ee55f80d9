//! Noise floor from the data itself: the white measurement noise in the measured removal.
//!
//! The operator is the fourth difference along one axis, `D z = z[-2] - 4 z[-1] + 6 z[0] -
//! 4 z[1] + z[2]` over five consecutive valid pixels. It annihilates cubics along the axis, so
//! smooth structure (the removal, whose scale is the TIF's, and a raster ripple along the other
//! axis) contributes almost nothing, while white noise of RMS sigma gives RMS
//! `sigma * sqrt(1 + 16 + 36 + 16 + 1) = sqrt(70) sigma`. sigma is estimated robustly:
//! `1.4826 * median |D z| / sqrt(70)` (defects and edges do not inflate it), along X and along Y,
//! and the smaller is kept (a ripple or scratch along one axis inflates only that one).
//!
//! A polished surface carries its own texture down to the pixel scale, which no operator can
//! tell from noise in one map: measured on either map alone, that texture counts as noise (49-61
//! nm on runs whose true floor is 0.7-2.8 nm). In the measured removal `before - after`, on a
//! common grid after registration, the texture cancels and what is left at the pixel scale is the
//! two maps' noise in quadrature: that is the floor ([`removal_noise_floor`]). Until the maps are
//! registered, a misregistration leaves texture in the difference too, so the smaller of the
//! difference's floor and the two maps' own floors in quadrature is the estimate
//! ([`initial_noise_floor`]); each is an upper bound of the truth.

use ndarray::{Array2, Zip};

use crate::band::ProcessBand;
use crate::grid::MapGrid;
use bonnetlab_spectrum::psd1d::{psd_x, psd_y, PsdOptions};
use bonnetlab_surface::Surface;

/// White-noise gain of the fourth difference.
const GAIN: f64 = 70.0;
/// Fewest five-pixel runs for an estimate along an axis.
const MIN_RUNS: usize = 64;

/// Robust white-noise RMS (nm) of one map (see the module docs), or `None` with too few
/// complete five-pixel runs.
pub fn white_noise_rms(h: &Array2<f64>, valid: &Array2<bool>) -> Option<f64> {
    let (r, c) = h.dim();
    let mut best: Option<f64> = None;
    for along_x in [true, false] {
        let mut v = Vec::new();
        let (nl, n) = if along_x { (r, c) } else { (c, r) };
        for l in 0..nl {
            let at = |k: usize| if along_x { (l, k) } else { (k, l) };
            for k in 2..n.saturating_sub(2) {
                if (k - 2..=k + 2).all(|m| valid[at(m)]) {
                    let d = h[at(k - 2)] - 4.0 * h[at(k - 1)] + 6.0 * h[at(k)] - 4.0 * h[at(k + 1)]
                        + h[at(k + 2)];
                    v.push(d.abs());
                }
            }
        }
        if v.len() < MIN_RUNS {
            continue;
        }
        let mid = v.len() / 2;
        v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        let s = 1.4826 * v[mid] / GAIN.sqrt();
        best = Some(best.map_or(s, |b: f64| b.min(s)));
    }
    best
}

/// Noise floor (nm RMS) of the measured removal `before - after` on the pixels valid in both,
/// `after` already registered onto the before map's grid.
pub fn removal_noise_floor(
    before: &Array2<f64>,
    bv: &Array2<bool>,
    after: &Array2<f64>,
    av: &Array2<bool>,
) -> Option<f64> {
    let d = before - after;
    let mut m = bv.clone();
    Zip::from(&mut m).and(av).for_each(|a, &b| *a &= b);
    white_noise_rms(&d, &m)
}

/// The floor before the maps are registered: the smaller of the difference's floor and the two
/// maps' own floors in quadrature (0 when neither can be estimated).
pub fn initial_noise_floor(
    before: &Array2<f64>,
    bv: &Array2<bool>,
    after: &Array2<f64>,
    av: &Array2<bool>,
) -> f64 {
    let own = match (white_noise_rms(before, bv), white_noise_rms(after, av)) {
        (Some(a), Some(b)) => Some(a.hypot(b)),
        _ => None,
    };
    match (removal_noise_floor(before, bv, after, av), own) {
        (Some(a), Some(b)) => a.min(b),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => 0.0,
    }
}

/// Where the band-aware floor starts, in multiples of the process band's cutoff (the TIF's
/// |MTF| keeps falling beyond its 1e-2 point: little removal is left there).
pub const FLOOR_BAND_START: f64 = 1.5;
/// Fewest PSD bins a floor block averages.
const FLOOR_BLOCK_BINS: usize = 8;

/// A noise floor with the band it was read in.
#[derive(Debug, Clone, Copy)]
pub struct BandFloor {
    /// White-noise RMS (nm) of the whole band up to Nyquist implied by the level read.
    pub rms_nm: f64,
    /// The PSD bins (cycles/mm) the level was read over.
    pub band_per_mm: [f64; 2],
    /// "x" or "y": the direction of the one-sided 1-D PSD.
    pub axis: &'static str,
}

/// Band-aware noise floor of the measured removal `before - after` (after registered onto the
/// before grid), on the pixels valid in both.
///
/// Above the process band the removal has no content, so the one-sided 1-D PSDs (X and Y, the
/// spectrum crate's, Hann window, nm^2 mm) of the difference hold only the two maps' white
/// noise (level `2 sigma^2 d`) and whatever texture the registration did not cancel. That
/// texture is coloured: a residual misregistration leaves it where the texture is strong and
/// a sub-pixel resampling of a surface sampled at points leaves it towards Nyquist, while the
/// noise is flat. The floor is the lowest mean level over blocks of at least
/// `FLOOR_BLOCK_BINS` bins between `FLOOR_BAND_START` times the cutoff and Nyquist, along
/// either axis, and it is reported with that block's band. `None` when no such block exists
/// (a TIF that passes almost everything the map resolves).
pub fn band_noise_floor(
    g: &MapGrid,
    band: &ProcessBand,
    before: &Array2<f64>,
    bv: &Array2<bool>,
    after: &Array2<f64>,
    av: &Array2<bool>,
) -> Option<BandFloor> {
    let d = before - after;
    let mut m = bv.clone();
    Zip::from(&mut m).and(av).for_each(|a, &b| *a &= b);
    let d = Array2::from_shape_fn(d.dim(), |ij| if m[ij] { d[ij] } else { 0.0 });
    let s = Surface::with_mask(d, m, Some(g.dx_mm), Some(g.dy_mm)).ok()?;
    let opts = PsdOptions::default();
    let f_lo = FLOOR_BAND_START * band.cutoff_per_mm;
    let mut best: Option<(f64, BandFloor)> = None;
    for (axis, psd) in [("x", psd_x(&s, &opts)), ("y", psd_y(&s, &opts))] {
        let Ok(p) = psd else { continue };
        let Some(first) = p.freq_per_mm.iter().position(|f| *f >= f_lo) else {
            continue;
        };
        let last = p.psd_nm2_mm.len();
        if last < first + FLOOR_BLOCK_BINS {
            continue;
        }
        let width = FLOOR_BLOCK_BINS.max((last - first) / 16);
        let mut a = first;
        while a + width <= last {
            let level = p.psd_nm2_mm[a..a + width].iter().sum::<f64>() / width as f64;
            let sigma = (level / (2.0 * p.spacing_mm)).sqrt();
            if best.is_none_or(|(b, _)| sigma < b) {
                let band_per_mm = [p.freq_per_mm[a], p.freq_per_mm[a + width - 1]];
                best = Some((
                    sigma,
                    BandFloor {
                        rms_nm: sigma,
                        band_per_mm,
                        axis,
                    },
                ));
            }
            a += width;
        }
    }
    best.map(|b| b.1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    /// A random field with a power-law PSD (exponent `beta`) down to the pixel scale, `rms` nm,
    /// by spectral synthesis (a direct sum over a random set of waves is too smooth).
    fn texture(n: usize, beta: f64, rms: f64, seed: u64) -> Array2<f64> {
        let mut rng = Rng::new(seed);
        let mut h = Array2::<f64>::zeros((n, n));
        // Sum of many waves with power-law amplitudes up to Nyquist, random phases.
        let waves = 600;
        let mut ks = Vec::new();
        for _ in 0..waves {
            let f = (rng.uniform() * (0.5f64.ln() - (1.0 / n as f64).ln()) + (1.0 / n as f64).ln())
                .exp();
            let th = rng.uniform() * std::f64::consts::TAU;
            let ph = rng.uniform() * std::f64::consts::TAU;
            // Log-uniform frequencies: amplitude^2 ~ f^(2 - beta) per log-bin in 2-D.
            let a = f.powf(1.0 - beta / 2.0);
            ks.push((f * th.cos(), f * th.sin(), ph, a));
        }
        for ((i, j), v) in h.indexed_iter_mut() {
            let mut s = 0.0;
            for &(fx, fy, ph, a) in &ks {
                s += a * (std::f64::consts::TAU * (fx * j as f64 + fy * i as f64) + ph).cos();
            }
            *v = s;
        }
        let m = h.mean().unwrap_or(0.0);
        let sd = h.mapv(|v| (v - m) * (v - m)).mean().unwrap_or(1.0).sqrt();
        h.mapv(|v| (v - m) * rms / sd)
    }

    #[test]
    fn floor_of_textured_maps_is_the_noise_not_the_texture() {
        let n = 160;
        let tex = texture(n, 2.2, 140.0, 3);
        let mut rng = Rng::new(9);
        let (sb, sa) = (1.0, 0.7);
        // A smooth removal with a raster ripple along Y (2.5 mm pitch at 0.2 mm pixels).
        let removal = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = (j as f64 * 0.2, i as f64 * 0.2);
            60.0 + 20.0 * (x / 9.0).sin() * (y / 13.0).cos()
                + 3.0 * (std::f64::consts::TAU * y / 2.5).cos()
        });
        let before = tex.mapv(|v| v + sb * rng.normal());
        let after = Array2::from_shape_fn((n, n), |p| tex[p] - removal[p] + sa * rng.normal());
        // A round aperture with a dropout in the after map.
        let c = n as f64 / 2.0;
        let bv = Array2::from_shape_fn((n, n), |(i, j)| {
            (i as f64 - c).hypot(j as f64 - c) < 0.48 * n as f64
        });
        let av = Array2::from_shape_fn((n, n), |(i, j)| {
            bv[(i, j)] && (i as f64 - 50.0).hypot(j as f64 - 60.0) > 9.0
        });
        let truth = sb.hypot(sa);
        // Either map alone: the texture is taken for noise.
        let own = white_noise_rms(&before, &bv).unwrap();
        assert!(own > 3.0 * sb, "texture should dominate one map: {own}");
        let f = removal_noise_floor(&before, &bv, &after, &av).unwrap();
        assert!((f / truth - 1.0).abs() < 0.05, "floor {f} vs truth {truth}");
        let f0 = initial_noise_floor(&before, &bv, &after, &av);
        assert!(
            (f0 / truth - 1.0).abs() < 0.05,
            "initial {f0} vs truth {truth}"
        );
    }

    #[test]
    fn recovers_white_noise_on_a_smooth_surface() {
        let mut rng = Rng::new(5);
        let h = Array2::from_shape_fn((200, 200), |(i, j)| {
            30.0 * ((i as f64) / 40.0).sin() * ((j as f64) / 55.0).cos() + 0.7 * rng.normal()
        });
        let v = Array2::from_elem((200, 200), true);
        let s = white_noise_rms(&h, &v).unwrap();
        assert!((s - 0.7).abs() < 0.03, "{s}");
    }
}
