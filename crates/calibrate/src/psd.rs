//! Minimal masked 1-D PSDs for the diagnosis (the spectrum crate's conventions: one-sided
//! density in nm^2 mm, periodic Hann window, per-line mean removed, lines averaged weighted by
//! their valid count; invalid pixels are set to the line mean, which is enough to locate bands).

use ndarray::Array2;
use realfft::RealFftPlanner;

pub struct Psd1 {
    pub freq_per_mm: Vec<f64>,
    /// One-sided PSD (nm^2 mm).
    pub psd_nm2_mm: Vec<f64>,
    pub df_per_mm: f64,
}

/// PSD along X (each row a line) when `along_x`, else along Y (each column a line).
pub fn psd_1d(h: &Array2<f64>, valid: &Array2<bool>, d_mm: f64, along_x: bool) -> Psd1 {
    let (r, c) = h.dim();
    let (nl, n) = if along_x { (r, c) } else { (c, r) };
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let w: Vec<f64> = (0..n)
        .map(|k| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos())
        .collect();
    let u: f64 = w.iter().map(|v| v * v).sum::<f64>() / n as f64;
    let mut acc = vec![0.0; n / 2 + 1];
    let mut wsum = 0.0;
    let mut buf = vec![0.0; n];
    let mut out = fft.make_output_vec();
    for l in 0..nl {
        let at = |k: usize| if along_x { (l, k) } else { (k, l) };
        let (mut s, mut cnt) = (0.0, 0usize);
        for k in 0..n {
            if valid[at(k)] {
                s += h[at(k)];
                cnt += 1;
            }
        }
        if cnt < n / 2 {
            continue;
        }
        let mean = s / cnt as f64;
        for k in 0..n {
            buf[k] = if valid[at(k)] {
                (h[at(k)] - mean) * w[k]
            } else {
                0.0
            };
        }
        if fft.process(&mut buf, &mut out).is_err() {
            continue;
        }
        for (a, z) in acc.iter_mut().zip(&out) {
            *a += cnt as f64 * z.norm_sqr();
        }
        wsum += cnt as f64;
    }
    let norm = d_mm / (n as f64 * u) / wsum.max(1.0);
    let psd: Vec<f64> = acc
        .iter()
        .enumerate()
        .map(|(k, v)| {
            v * norm
                * if k == 0 || (n % 2 == 0 && k == n / 2) {
                    1.0
                } else {
                    2.0
                }
        })
        .collect();
    let df = 1.0 / (n as f64 * d_mm);
    Psd1 {
        freq_per_mm: (0..psd.len()).map(|k| k as f64 * df).collect(),
        psd_nm2_mm: psd,
        df_per_mm: df,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_rms_of_a_sine_is_amplitude_over_root_two() {
        // metrology.md self-check: A = 10 nm, p = 3 mm, N = 600, dx = 0.1 mm
        let h = Array2::from_shape_fn((4, 600), |(_, j)| {
            10.0 * (2.0 * std::f64::consts::PI * j as f64 * 0.1 / 3.0).sin()
        });
        let v = Array2::from_elem((4, 600), true);
        let p = psd_1d(&h, &v, 0.1, true);
        let band: f64 = p
            .freq_per_mm
            .iter()
            .zip(&p.psd_nm2_mm)
            .filter(|(f, _)| **f >= 0.8 / 3.0 && **f <= 1.2 / 3.0)
            .map(|(_, s)| s * p.df_per_mm)
            .sum();
        assert!((band.sqrt() - 7.0711).abs() < 1e-3, "{}", band.sqrt());
    }
}
