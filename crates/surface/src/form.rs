//! Form removal: one joint least-squares fit of all requested terms over the valid pixels.
//!
//! Coordinates are centred on the valid pixels' bounding box and scaled to [-1, 1] along its
//! longer side (physical mm when the pixel size is known, pixel units otherwise), so the normal
//! equations stay well conditioned. All terms are fitted together, never one after another.

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::SurfaceError;
use crate::surface::Surface;

/// A form term that can be removed from a map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Term {
    /// Constant offset.
    Piston,
    /// Linear in x and y (two basis functions).
    Tilt,
    /// Defocus-like x^2 + y^2.
    Power,
}

impl Term {
    /// Name as used on the command line and in JSON.
    pub fn name(&self) -> &'static str {
        match self {
            Term::Piston => "piston",
            Term::Tilt => "tilt",
            Term::Power => "power",
        }
    }

    /// Parses a comma list such as `piston,tilt`; an empty string or `none` gives no term.
    pub fn parse_list(s: &str) -> Result<Vec<Term>, SurfaceError> {
        let mut out = Vec::new();
        for tok in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
            let t = match tok.to_ascii_lowercase().as_str() {
                "piston" => Term::Piston,
                "tilt" => Term::Tilt,
                "power" => Term::Power,
                "none" => continue,
                other => {
                    return Err(SurfaceError::InvalidArgument(format!(
                        "unknown form term '{other}' (expected piston, tilt, power)"
                    )))
                }
            };
            if !out.contains(&t) {
                out.push(t);
            }
        }
        Ok(out)
    }

    /// Number of basis functions this term contributes.
    fn n_basis(&self) -> usize {
        match self {
            Term::Piston | Term::Power => 1,
            Term::Tilt => 2,
        }
    }

    /// Writes this term's basis values at normalised (u, v) into `out`.
    fn eval(&self, u: f64, v: f64, out: &mut Vec<f64>) {
        match self {
            Term::Piston => out.push(1.0),
            Term::Tilt => {
                out.push(u);
                out.push(v);
            }
            Term::Power => out.push(u * u + v * v),
        }
    }
}

/// The result of a form fit: the coefficients in the normalised basis and the mapping used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FormFit {
    pub terms: Vec<Term>,
    /// Coefficients (nm) in the order of the basis functions of `terms`.
    pub coefficients_nm: Vec<f64>,
    /// Centre of the normalised coordinates (x, y) in the fit's length unit.
    pub centre: (f64, f64),
    /// Half-extent used to scale the coordinates.
    pub half_extent: f64,
}

/// Normalised coordinate mapping for a surface (centre and half-extent of the valid pixels).
fn normaliser(s: &Surface) -> Result<((f64, f64), f64, f64, f64), SurfaceError> {
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let (mut r0, mut r1, mut c0, mut c1) = (usize::MAX, 0usize, usize::MAX, 0usize);
    for ((i, j), &v) in s.valid().indexed_iter() {
        if v {
            r0 = r0.min(i);
            r1 = r1.max(i);
            c0 = c0.min(j);
            c1 = c1.max(j);
        }
    }
    if r0 == usize::MAX {
        return Err(SurfaceError::NoValidPixel);
    }
    let cx = 0.5 * (c0 + c1) as f64 * sx;
    let cy = 0.5 * (r0 + r1) as f64 * sy;
    let half = (0.5 * ((c1 - c0) as f64 * sx).max((r1 - r0) as f64 * sy)).max(f64::MIN_POSITIVE);
    let half = if half > 0.0 && half.is_finite() { half } else { 1.0 };
    Ok(((cx, cy), half, sx, sy))
}

/// Fits the terms jointly by least squares over the valid pixels.
pub fn fit_terms(s: &Surface, terms: &[Term]) -> Result<FormFit, SurfaceError> {
    let ((cx, cy), half, sx, sy) = normaliser(s)?;
    let nb: usize = terms.iter().map(Term::n_basis).sum();
    if nb == 0 {
        return Ok(FormFit { terms: vec![], coefficients_nm: vec![], centre: (cx, cy), half_extent: half });
    }
    let have = s.valid_count();
    if have < nb {
        return Err(SurfaceError::TooFewPixels { what: "form removal".into(), needed: nb, have });
    }
    // Normal equations accumulated row by row; the basis is near-orthogonal on normalised
    // coordinates so this is accurate for the low orders fitted here.
    let mut ata = vec![0.0f64; nb * nb];
    let mut atb = vec![0.0f64; nb];
    let mut basis = Vec::with_capacity(nb);
    let h = s.heights_nm();
    for ((i, j), &v) in s.valid().indexed_iter() {
        if !v {
            continue;
        }
        let u = (j as f64 * sx - cx) / half;
        let w = (i as f64 * sy - cy) / half;
        basis.clear();
        for t in terms {
            t.eval(u, w, &mut basis);
        }
        let z = h[(i, j)];
        for a in 0..nb {
            atb[a] += basis[a] * z;
            for b in a..nb {
                ata[a * nb + b] += basis[a] * basis[b];
            }
        }
    }
    for a in 0..nb {
        for b in 0..a {
            ata[a * nb + b] = ata[b * nb + a];
        }
    }
    let coef = solve_spd(&mut ata, &mut atb, nb)?;
    Ok(FormFit { terms: terms.to_vec(), coefficients_nm: coef, centre: (cx, cy), half_extent: half })
}

/// Evaluates a fit on the surface's grid (all pixels).
pub fn evaluate_fit(s: &Surface, fit: &FormFit) -> Array2<f64> {
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let mut basis = Vec::new();
    Array2::from_shape_fn(s.dim(), |(i, j)| {
        let u = (j as f64 * sx - fit.centre.0) / fit.half_extent;
        let w = (i as f64 * sy - fit.centre.1) / fit.half_extent;
        basis.clear();
        for t in &fit.terms {
            t.eval(u, w, &mut basis);
        }
        basis.iter().zip(&fit.coefficients_nm).map(|(b, c)| b * c).sum()
    })
}

/// Removes the terms jointly and returns the residual surface (its `removed` list extended).
pub fn remove_terms(s: &Surface, terms: &[Term]) -> Result<(Surface, FormFit), SurfaceError> {
    let fit = fit_terms(s, terms)?;
    let model = evaluate_fit(s, &fit);
    let mut out = s.with_heights(s.heights_nm() - &model)?;
    for t in terms {
        if !out.removed.contains(t) {
            out.removed.push(*t);
        }
    }
    Ok((out, fit))
}

/// Solves a symmetric positive-definite system by Cholesky; errors when it is singular.
fn solve_spd(a: &mut [f64], b: &mut [f64], n: usize) -> Result<Vec<f64>, SurfaceError> {
    let scale = (0..n).map(|i| a[i * n + i].abs()).fold(0.0, f64::max).max(f64::MIN_POSITIVE);
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if d <= scale * 1e-13 {
            return Err(SurfaceError::Singular(
                "the requested terms are not independent on the valid pixels".into(),
            ));
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i * n + k] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= a[k * n + i] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    Ok(b.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn removes_an_exact_plane_and_power_jointly() {
        let z = Array2::from_shape_fn((40, 60), |(i, j)| {
            let x = j as f64 * 0.5;
            let y = i as f64 * 0.25;
            3.0 + 0.7 * x - 1.1 * y + 0.02 * (x * x + y * y)
        });
        let s = Surface::new(z, Some(0.5), Some(0.25)).unwrap();
        let (r, _) = remove_terms(&s, &[Term::Piston, Term::Tilt, Term::Power]).unwrap();
        let max = r.valid_heights().map(f64::abs).fold(0.0, f64::max);
        assert!(max < 1e-9, "residual {max}");
        assert_eq!(r.removed, vec![Term::Piston, Term::Tilt, Term::Power]);
    }

    #[test]
    fn parse_list_and_errors() {
        assert_eq!(Term::parse_list("piston, tilt").unwrap(), vec![Term::Piston, Term::Tilt]);
        assert!(Term::parse_list("coma").is_err());
        let s = Surface::new(Array2::from_elem((1, 1), 1.0), None, None).unwrap();
        assert!(remove_terms(&s, &[Term::Piston, Term::Tilt]).is_err());
    }
}
