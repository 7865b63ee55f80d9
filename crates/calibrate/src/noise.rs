//! Noise floor from the data itself.
//!
//! For each map, the pixel-scale operator `L z = z - (z_N + z_S + z_E + z_W) / 4` (applied where
//! all five pixels are valid) turns white noise of RMS sigma into a variable of RMS
//! `sigma * sqrt(1 + 4/16) = 1.118 sigma`, while a smooth surface (curvature times dx^2) barely
//! contributes. sigma is estimated robustly: 1.4826 * median |L z| / 1.118 (defects and edges do
//! not inflate it). The floor of a removal residual (before - after) is the two maps' sigmas in
//! quadrature: structure at the pixel scale that no smooth polishing model can explain.

use ndarray::Array2;

/// Robust white-noise RMS (nm) of one map from its pixel-scale Laplacian.
pub fn pixel_noise_rms(h: &Array2<f64>, valid: &Array2<bool>) -> Option<f64> {
    let (r, c) = h.dim();
    let mut v = Vec::new();
    for i in 1..r.saturating_sub(1) {
        for j in 1..c.saturating_sub(1) {
            if valid[(i, j)]
                && valid[(i - 1, j)]
                && valid[(i + 1, j)]
                && valid[(i, j - 1)]
                && valid[(i, j + 1)]
            {
                let l = h[(i, j)]
                    - 0.25 * (h[(i - 1, j)] + h[(i + 1, j)] + h[(i, j - 1)] + h[(i, j + 1)]);
                v.push(l.abs());
            }
        }
    }
    if v.len() < 16 {
        return None;
    }
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Some(1.4826 * v[mid] / 1.25f64.sqrt())
}

/// Noise floor of before - after (nm RMS).
pub fn removal_noise_floor(
    before: &Array2<f64>,
    bv: &Array2<bool>,
    after: &Array2<f64>,
    av: &Array2<bool>,
) -> f64 {
    let a = pixel_noise_rms(before, bv).unwrap_or(0.0);
    let b = pixel_noise_rms(after, av).unwrap_or(0.0);
    a.hypot(b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    #[test]
    fn recovers_white_noise_on_a_smooth_surface() {
        let mut rng = Rng::new(5);
        let h = Array2::from_shape_fn((200, 200), |(i, j)| {
            30.0 * ((i as f64) / 40.0).sin() * ((j as f64) / 55.0).cos() + 0.7 * rng.normal()
        });
        let v = Array2::from_elem((200, 200), true);
        let s = pixel_noise_rms(&h, &v).unwrap();
        assert!((s - 0.7).abs() < 0.02, "{s}");
    }
}
