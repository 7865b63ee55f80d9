//! PVr, the robust peak-to-valley of Evans (2008):
//! PVr = PV(Zernike fit) + 3 RMS(residual of that fit).
//!
//! Zernike set: the 37 Fringe terms including piston (Z1..Z37, as prysm fits although its
//! comment says 36), on the unit circle centred on the valid pixels' bounding-box centre with
//! the largest distance to a valid pixel as radius (see `form`). PV(fit) is taken over the
//! valid pixels only; the residual RMS is about its mean (which is 0, piston being fitted).

use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::form::{evaluate_fit, fit_terms, Term};
use crate::surface::Surface;

/// Number of Fringe Zernike terms in the PVr fit.
pub const PVR_ZERNIKE_TERMS: u8 = 37;
/// How the PVr Zernike set is described in reports.
pub const PVR_SET: &str = "Fringe Zernike Z1-Z37 incl. piston on the aperture's unit circle";

/// PVr and its parts (nm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pvr {
    pub pvr_nm: f64,
    /// PV of the 37-term Zernike fit over the valid pixels.
    pub pv_fit_nm: f64,
    /// RMS of the map minus the fit.
    pub rms_residual_nm: f64,
}

/// PVr of a map as it is (remove form first if the report says so).
pub fn pvr(s: &Surface) -> Result<Pvr, SurfaceError> {
    let fit = fit_terms(s, &[Term::Zernike(PVR_ZERNIKE_TERMS)])?;
    let model = evaluate_fit(s, &fit);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut n, mut sum, mut sum2) = (0usize, 0.0, 0.0);
    for ((&m, &z), &v) in model.iter().zip(s.heights_nm()).zip(s.valid()) {
        if v {
            lo = lo.min(m);
            hi = hi.max(m);
            let r = z - m;
            n += 1;
            sum += r;
            sum2 += r * r;
        }
    }
    if n == 0 {
        return Err(SurfaceError::NoValidPixel);
    }
    let mean = sum / n as f64;
    let rms = (sum2 / n as f64 - mean * mean).max(0.0).sqrt();
    Ok(Pvr {
        pvr_nm: hi - lo + 3.0 * rms,
        pv_fit_nm: hi - lo,
        rms_residual_nm: rms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use ndarray::Array2;

    #[test]
    fn pvr_of_low_order_form_plus_noise() {
        // Exact Z4 + Z9 form (within the 37 terms) plus white noise of known sigma on a disc.
        let n = 161;
        let c = 80.0;
        let mut rng = Rng::new(21);
        let sigma = 2.0;
        let mut mask = Array2::from_elem((n, n), false);
        let z = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = ((j as f64 - c) / 80.0, (i as f64 - c) / 80.0);
            let r2 = x * x + y * y;
            if r2 <= 1.0 {
                mask[(i, j)] = true;
            }
            30.0 * (2.0 * r2 - 1.0) + 10.0 * (6.0 * r2 * r2 - 6.0 * r2 + 1.0) + sigma * rng.normal()
        });
        let s = Surface::with_mask(z, mask, None, None).unwrap();
        let p = pvr(&s).unwrap();
        // Brute force PV of 30 Z4 + 10 Z9 over the valid radii: f(s) = 60 s^2 ... with s = r^2.
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for (i, j) in (0..n).flat_map(|i| (0..n).map(move |j| (i, j))) {
            let (x, y) = ((j as f64 - c) / 80.0, (i as f64 - c) / 80.0);
            let r2 = x * x + y * y;
            if r2 <= 1.0 {
                let f = 30.0 * (2.0 * r2 - 1.0) + 10.0 * (6.0 * r2 * r2 - 6.0 * r2 + 1.0);
                lo = lo.min(f);
                hi = hi.max(f);
            }
        }
        let nvalid = s.valid_count() as f64;
        // The fit absorbs 37 of the noise's degrees of freedom.
        let rms_expected = sigma * ((nvalid - 37.0) / nvalid).sqrt();
        let tol_rms = 4.0 * sigma / (2.0 * nvalid).sqrt();
        assert!((p.rms_residual_nm - rms_expected).abs() < tol_rms, "{p:?}");
        // The fitted form differs from the true one by the noise's projection: ~ sigma
        // * sqrt(37 / n) per pixel, a few hundredths of a nm here.
        assert!(
            (p.pv_fit_nm - (hi - lo)).abs() < 0.5,
            "{} vs {}",
            p.pv_fit_nm,
            hi - lo
        );
        assert!((p.pvr_nm - (p.pv_fit_nm + 3.0 * p.rms_residual_nm)).abs() < 1e-12);
    }
}
