//! An analytic test surface (figure + mid-spatial-frequency content): a seeded sum of plane
//! waves that can be evaluated, with its gradient, at any point. Evaluating the truth exactly at
//! shifted or rotated points is what lets the generator misregister a map without interpolation.

use bonnetlab_surface::rng::Rng;

#[derive(Debug, Clone)]
pub struct SurfaceFn {
    /// (amplitude nm, fx per mm, fy per mm, phase rad)
    waves: Vec<(f64, f64, f64, f64)>,
}

impl SurfaceFn {
    /// `n` waves per band; figure band 0.5/L..3/L, MSF band `msf_band_per_mm`; amplitudes set so
    /// each band's RMS is as asked (random phases: RMS = sqrt(sum a^2 / 2)).
    pub fn random(
        rng: &mut Rng,
        size_mm: f64,
        figure_rms_nm: f64,
        msf_rms_nm: f64,
        msf_band_per_mm: (f64, f64),
    ) -> Self {
        let mut waves = Vec::new();
        let mut band =
            |n: usize, f1: f64, f2: f64, rms: f64, waves: &mut Vec<(f64, f64, f64, f64)>| {
                if rms <= 0.0 {
                    return;
                }
                let start = waves.len();
                for _ in 0..n {
                    let f = f1 * (f2 / f1).powf(rng.uniform());
                    let ang = std::f64::consts::PI * rng.uniform();
                    let a = 1.0 / f.sqrt();
                    waves.push((
                        a,
                        f * ang.cos(),
                        f * ang.sin(),
                        2.0 * std::f64::consts::PI * rng.uniform(),
                    ));
                }
                let ms: f64 = waves[start..].iter().map(|w| w.0 * w.0 / 2.0).sum();
                let k = rms / ms.sqrt();
                for w in &mut waves[start..] {
                    w.0 *= k;
                }
            };
        band(10, 0.5 / size_mm, 3.0 / size_mm, figure_rms_nm, &mut waves);
        band(
            30,
            msf_band_per_mm.0,
            msf_band_per_mm.1,
            msf_rms_nm,
            &mut waves,
        );
        SurfaceFn { waves }
    }

    pub fn value(&self, x: f64, y: f64) -> f64 {
        let tau = 2.0 * std::f64::consts::PI;
        self.waves
            .iter()
            .map(|&(a, fx, fy, p)| a * (tau * (fx * x + fy * y) + p).cos())
            .sum()
    }

    /// Gradient (nm/mm).
    pub fn gradient(&self, x: f64, y: f64) -> (f64, f64) {
        let tau = 2.0 * std::f64::consts::PI;
        let mut g = (0.0, 0.0);
        for &(a, fx, fy, p) in &self.waves {
            let s = -a * tau * (tau * (fx * x + fy * y) + p).sin();
            g.0 += s * fx;
            g.1 += s * fy;
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_difference_and_rms_is_right() {
        let mut rng = Rng::new(3);
        let s = SurfaceFn::random(&mut rng, 100.0, 50.0, 0.0, (0.05, 0.3));
        let (gx, gy) = s.gradient(12.0, 34.0);
        let h = 1e-4;
        let fx = (s.value(12.0 + h, 34.0) - s.value(12.0 - h, 34.0)) / (2.0 * h);
        let fy = (s.value(12.0, 34.0 + h) - s.value(12.0, 34.0 - h)) / (2.0 * h);
        assert!((gx - fx).abs() < 1e-5 && (gy - fy).abs() < 1e-5);
        let ms: f64 = s.waves.iter().map(|w| w.0 * w.0 / 2.0).sum();
        assert!((ms.sqrt() - 50.0).abs() < 1e-9);
    }
}
