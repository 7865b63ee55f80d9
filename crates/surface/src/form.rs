//! Form removal: one joint least-squares fit of all requested terms over the valid pixels.
//!
//! Lengths are physical mm when the pixel size is known, pixel units otherwise. Three
//! normalised frames, all centred on the centre of the valid pixels' bounding box:
//! - piston / tilt / power: isotropic, scaled by half the longer side of the bounding box;
//! - Zernike (`zernikeN`, Fringe terms 1..=N, N <= 37): the unit circle with that centre and
//!   the largest distance from it to a valid pixel centre as radius (so a circular aperture
//!   maps onto the unit disc);
//! - Legendre (`legendreD`, products P_a(u) P_b(v), a + b <= D, D <= 12): the bounding box
//!   mapped onto [-1, 1]^2, each axis scaled separately.
//!
//! All basis functions of all terms are fitted together (never term by term) by a streaming
//! Householder QR (see `lsq`). Functions that several terms share (piston inside `zernike37`,
//! tilt inside `legendre1`, ...) are detected as linearly dependent and fitted once, so any
//! combination is accepted and the residual is the projection onto their joint span.

use std::fmt;

use ndarray::{Array2, Axis};
use rayon::prelude::*;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::basis::{self, legendre_count, MAX_LEGENDRE_DEGREE, MAX_ZERNIKE};
use crate::error::SurfaceError;
use crate::lsq::{solve_from_r, StreamingQr};
use crate::surface::{mask_bounds, Surface};

/// A form term that can be removed from a map. Serialised as its command-line name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Term {
    /// Constant offset.
    Piston,
    /// Linear in x and y (two basis functions).
    Tilt,
    /// Defocus-like x^2 + y^2.
    Power,
    /// Fringe Zernike terms 1..=N (N in 1..=37) on the aperture's unit circle.
    Zernike(u8),
    /// Legendre products of total degree <= D (D in 0..=12) on the bounding rectangle.
    Legendre(u8),
}

#[rustfmt::skip]
const ZERNIKE_NAMES: [&str; MAX_ZERNIKE] = [
    "zernike1", "zernike2", "zernike3", "zernike4", "zernike5", "zernike6", "zernike7",
    "zernike8", "zernike9", "zernike10", "zernike11", "zernike12", "zernike13", "zernike14",
    "zernike15", "zernike16", "zernike17", "zernike18", "zernike19", "zernike20", "zernike21",
    "zernike22", "zernike23", "zernike24", "zernike25", "zernike26", "zernike27", "zernike28",
    "zernike29", "zernike30", "zernike31", "zernike32", "zernike33", "zernike34", "zernike35",
    "zernike36", "zernike37",
];
#[rustfmt::skip]
const LEGENDRE_NAMES: [&str; MAX_LEGENDRE_DEGREE + 1] = [
    "legendre0", "legendre1", "legendre2", "legendre3", "legendre4", "legendre5", "legendre6",
    "legendre7", "legendre8", "legendre9", "legendre10", "legendre11", "legendre12",
];

impl Term {
    /// Name as used on the command line and in JSON (`piston`, `zernike37`, `legendre3`, ...).
    pub fn name(&self) -> &'static str {
        match *self {
            Term::Piston => "piston",
            Term::Tilt => "tilt",
            Term::Power => "power",
            Term::Zernike(n) => ZERNIKE_NAMES
                .get((n as usize).wrapping_sub(1))
                .copied()
                .unwrap_or("zernike?"),
            Term::Legendre(d) => LEGENDRE_NAMES
                .get(d as usize)
                .copied()
                .unwrap_or("legendre?"),
        }
    }

    /// Parses one term name; `zernike` alone means all 37 Fringe terms.
    pub fn parse(tok: &str) -> Result<Term, SurfaceError> {
        let t = tok.trim().to_ascii_lowercase();
        let bad = || {
            SurfaceError::InvalidArgument(format!(
                "unknown form term '{t}' (expected piston, tilt, power, zernikeN with N in 1..=37, \
                 legendreD with D in 0..=12)"
            ))
        };
        Ok(match t.as_str() {
            "piston" => Term::Piston,
            "tilt" => Term::Tilt,
            "power" => Term::Power,
            "zernike" => Term::Zernike(MAX_ZERNIKE as u8),
            _ => {
                if let Some(n) = t.strip_prefix("zernike") {
                    match n.parse::<usize>() {
                        Ok(n) if (1..=MAX_ZERNIKE).contains(&n) => Term::Zernike(n as u8),
                        _ => return Err(bad()),
                    }
                } else if let Some(d) = t.strip_prefix("legendre") {
                    match d.parse::<usize>() {
                        Ok(d) if d <= MAX_LEGENDRE_DEGREE => Term::Legendre(d as u8),
                        _ => return Err(bad()),
                    }
                } else {
                    return Err(bad());
                }
            }
        })
    }

    /// Parses a comma list such as `piston,tilt`; `none` gives no term, an empty term is an error.
    pub fn parse_list(s: &str) -> Result<Vec<Term>, SurfaceError> {
        let mut out = Vec::new();
        // An empty term ("piston,,tilt", a trailing comma, or nothing at all) is refused: it is
        // a typo more often than a wish, and "none" says "no terms" explicitly.
        for tok in s.split(',').map(str::trim) {
            if tok.is_empty() {
                return Err(SurfaceError::InvalidArgument(format!(
                    "'{s}' has an empty term (a comma list of piston, tilt, power, zernikeN, \
                     legendreD, or none)"
                )));
            }
            if tok.eq_ignore_ascii_case("none") {
                continue;
            }
            let t = Term::parse(tok)?;
            if !out.contains(&t) {
                out.push(t);
            }
        }
        Ok(out)
    }

    /// Number of basis functions this term contributes.
    pub fn n_basis(&self) -> usize {
        match *self {
            Term::Piston | Term::Power => 1,
            Term::Tilt => 2,
            Term::Zernike(n) => (n as usize).min(MAX_ZERNIKE),
            Term::Legendre(d) => legendre_count((d as usize).min(MAX_LEGENDRE_DEGREE)),
        }
    }

    fn check(&self) -> Result<(), SurfaceError> {
        match *self {
            Term::Zernike(n) if n == 0 || n as usize > MAX_ZERNIKE => Err(
                SurfaceError::InvalidArgument(format!("zernike{n}: N must be in 1..=37")),
            ),
            Term::Legendre(d) if d as usize > MAX_LEGENDRE_DEGREE => Err(
                SurfaceError::InvalidArgument(format!("legendre{d}: D must be in 0..=12")),
            ),
            _ => Ok(()),
        }
    }

    /// Writes this term's basis values at a point into `out`.
    fn eval(&self, c: &Coords, out: &mut Vec<f64>) {
        match *self {
            Term::Piston => out.push(1.0),
            Term::Tilt => {
                out.push(c.u);
                out.push(c.v);
            }
            Term::Power => out.push(c.u * c.u + c.v * c.v),
            Term::Zernike(n) => basis::push_zernike(n as usize, c.zx, c.zy, out),
            Term::Legendre(d) => basis::push_legendre(d as usize, c.lx, c.ly, out),
        }
    }
}

impl fmt::Display for Term {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for Term {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Term {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Term::parse(&s).map_err(serde::de::Error::custom)
    }
}

/// The point in each normalised frame.
struct Coords {
    u: f64,
    v: f64,
    zx: f64,
    zy: f64,
    lx: f64,
    ly: f64,
}

/// The result of a form fit: the coefficients in the normalised bases and the frames used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FormFit {
    pub terms: Vec<Term>,
    /// Coefficients (nm) in the order of the basis functions of `terms`.
    pub coefficients_nm: Vec<f64>,
    /// Centre (x, y) of every frame: the valid pixels' bounding-box centre, in mm (pixel
    /// units when the pixel size is unknown), measured from pixel (0, 0).
    pub centre: (f64, f64),
    /// Half of the bounding box's longer side (piston / tilt / power scale).
    pub half_extent: f64,
    /// Half-widths of the bounding box along x and y (Legendre scale).
    pub half_extent_xy: (f64, f64),
    /// Radius of the Zernike unit circle: largest distance from `centre` to a valid pixel.
    pub radius: f64,
    /// Basis functions (indices into `coefficients_nm`) found linearly dependent on earlier
    /// ones on these valid pixels; their coefficient is 0.
    pub dropped: Vec<usize>,
}

impl FormFit {
    fn coords(&self, x: f64, y: f64) -> Coords {
        let (dx, dy) = (x - self.centre.0, y - self.centre.1);
        Coords {
            u: dx / self.half_extent,
            v: dy / self.half_extent,
            zx: dx / self.radius,
            zy: dy / self.radius,
            lx: dx / self.half_extent_xy.0,
            ly: dy / self.half_extent_xy.1,
        }
    }
}

fn positive_or_one(v: f64) -> f64 {
    if v > 0.0 && v.is_finite() {
        v
    } else {
        1.0
    }
}

/// The frames of a surface's valid pixels (coefficients left empty).
fn frame(s: &Surface, terms: &[Term]) -> Result<FormFit, SurfaceError> {
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let (r0, r1, c0, c1) = mask_bounds(s.valid()).ok_or(SurfaceError::NoValidPixel)?;
    let cx = 0.5 * (c0 + c1) as f64 * sx;
    let cy = 0.5 * (r0 + r1) as f64 * sy;
    let hx = 0.5 * (c1 - c0) as f64 * sx;
    let hy = 0.5 * (r1 - r0) as f64 * sy;
    let mut r2max = 0.0f64;
    if terms.iter().any(|t| matches!(t, Term::Zernike(_))) {
        for ((i, j), &v) in s.valid().indexed_iter() {
            if v {
                let (x, y) = (j as f64 * sx - cx, i as f64 * sy - cy);
                r2max = r2max.max(x * x + y * y);
            }
        }
    }
    Ok(FormFit {
        terms: terms.to_vec(),
        coefficients_nm: vec![],
        centre: (cx, cy),
        half_extent: positive_or_one(hx.max(hy)),
        half_extent_xy: (positive_or_one(hx), positive_or_one(hy)),
        radius: positive_or_one(r2max.sqrt()),
        dropped: vec![],
    })
}

/// Rows per band of the parallel reduction; fixed so results do not depend on thread count.
const BAND_ROWS: usize = 32;

/// Fits the terms jointly by least squares over the valid pixels.
pub fn fit_terms(s: &Surface, terms: &[Term]) -> Result<FormFit, SurfaceError> {
    for t in terms {
        t.check()?;
    }
    let mut fit = frame(s, terms)?;
    let nb: usize = terms.iter().map(Term::n_basis).sum();
    if nb == 0 {
        return Ok(fit);
    }
    let have = s.valid_count();
    let distinct = if terms
        .iter()
        .any(|t| matches!(t, Term::Zernike(_) | Term::Legendre(_)))
    {
        terms.iter().map(Term::n_basis).max().unwrap_or(0)
    } else {
        nb
    };
    if have < distinct {
        return Err(SurfaceError::TooFewPixels {
            what: "form removal".into(),
            needed: distinct,
            have,
        });
    }
    if let Some(r) = low_order_gram_r(s, &fit, terms, nb) {
        let sol = solve_from_r(&r.r, nb + 1);
        fit.coefficients_nm = sol.coefficients;
        if let Some(k) = r.piston_index {
            fit.coefficients_nm[k] += r.shift_nm;
        }
        fit.dropped = sol.dropped;
        return Ok(fit);
    }
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let p = nb + 1;
    let (rows, _) = s.dim();
    let h = s.heights_nm();
    let valid = s.valid();
    let bands: Vec<StreamingQr> = (0..rows.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|band| {
            let mut qr = StreamingQr::new(p);
            let mut row = Vec::with_capacity(p);
            for i in band * BAND_ROWS..((band + 1) * BAND_ROWS).min(rows) {
                for (j, (&z, &v)) in h.row(i).iter().zip(valid.row(i)).enumerate() {
                    if !v {
                        continue;
                    }
                    let c = fit.coords(j as f64 * sx, i as f64 * sy);
                    row.clear();
                    for t in terms {
                        t.eval(&c, &mut row);
                    }
                    row.push(z);
                    qr.push_row(&row);
                }
            }
            qr
        })
        .collect();
    let mut total = StreamingQr::new(p);
    for b in bands {
        total.merge(b);
    }
    let sol = solve_from_r(&total.finish(), p);
    fit.coefficients_nm = sol.coefficients;
    fit.dropped = sol.dropped;
    Ok(fit)
}

/// The triangular factor of [A | z - shift] for piston / tilt / power fits, from the Gram
/// matrix (see `low_order_gram_r`).
struct GramR {
    r: Vec<f64>,
    shift_nm: f64,
    piston_index: Option<usize>,
}

/// Fast path for the everyday fits (piston, tilt, power: at most 4 functions of the
/// normalised coordinates). These are near-orthogonal on [-1, 1]^2 (condition number of A a
/// few units), so the Gram matrix G = [A | z]^T [A | z] loses nothing that matters for the
/// coefficients, and accumulating it is a few multiply-adds per pixel instead of a Householder
/// update. The heights are shifted by a reference value first (undone on the piston
/// coefficient) so a large piston does not cancel. R comes from a Cholesky factorisation of G;
/// a vanishing pivot leaves a zero row, which `solve_from_r` reports as a dependent column.
/// Bands are summed in a fixed order, so the result does not depend on the thread count.
fn low_order_gram_r(s: &Surface, fit: &FormFit, terms: &[Term], nb: usize) -> Option<GramR> {
    if !terms
        .iter()
        .all(|t| matches!(t, Term::Piston | Term::Tilt | Term::Power))
    {
        return None;
    }
    let p = nb + 1;
    let piston_index = terms
        .iter()
        .position(|t| *t == Term::Piston)
        .map(|pos| terms[..pos].iter().map(Term::n_basis).sum::<usize>());
    let shift_nm = if piston_index.is_some() {
        s.valid_heights().next().unwrap_or(0.0)
    } else {
        0.0
    };
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let (rows, _) = s.dim();
    let h = s.heights_nm();
    let valid = s.valid();
    let bands: Vec<Vec<f64>> = (0..rows.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|band| {
            let mut g = vec![0.0; p * p];
            let mut row = [0.0f64; 5];
            for i in band * BAND_ROWS..((band + 1) * BAND_ROWS).min(rows) {
                let v = (i as f64 * sy - fit.centre.1) / fit.half_extent;
                for (j, (&z, &ok)) in h.row(i).iter().zip(valid.row(i)).enumerate() {
                    if !ok {
                        continue;
                    }
                    let u = (j as f64 * sx - fit.centre.0) / fit.half_extent;
                    let mut k = 0;
                    for t in terms {
                        match t {
                            Term::Piston => {
                                row[k] = 1.0;
                                k += 1;
                            }
                            Term::Tilt => {
                                row[k] = u;
                                row[k + 1] = v;
                                k += 2;
                            }
                            _ => {
                                row[k] = u * u + v * v;
                                k += 1;
                            }
                        }
                    }
                    row[k] = z - shift_nm;
                    for a in 0..p {
                        let ra = row[a];
                        for b in a..p {
                            g[a * p + b] += ra * row[b];
                        }
                    }
                }
            }
            g
        })
        .collect();
    let mut g = vec![0.0; p * p];
    for b in &bands {
        for (acc, v) in g.iter_mut().zip(b) {
            *acc += v;
        }
    }
    // Upper Cholesky: G = R^T R, R row-major upper triangular.
    let mut r = vec![0.0; p * p];
    for j in 0..p {
        let mut d = g[j * p + j];
        for k in 0..j {
            d -= r[k * p + j] * r[k * p + j];
        }
        if d <= g[j * p + j].abs() * 1e-10 || d <= 0.0 {
            continue; // dependent column (or an exact fit of z): row j stays zero
        }
        let d = d.sqrt();
        r[j * p + j] = d;
        for c in j + 1..p {
            let mut v = g[j * p + c];
            for k in 0..j {
                v -= r[k * p + j] * r[k * p + c];
            }
            r[j * p + c] = v / d;
        }
    }
    Some(GramR {
        r,
        shift_nm,
        piston_index,
    })
}

/// Evaluates a fit on the surface's grid (all pixels).
pub fn evaluate_fit(s: &Surface, fit: &FormFit) -> Array2<f64> {
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let mut out = Array2::zeros(s.dim());
    if fit.coefficients_nm.is_empty() {
        return out;
    }
    let low_order = fit
        .terms
        .iter()
        .all(|t| matches!(t, Term::Piston | Term::Tilt | Term::Power));
    if low_order {
        // Same basis as `Term::eval` on the `u, v` frame, without the per-pixel dispatch.
        let mut c = [0.0f64; 4]; // piston, tilt u, tilt v, power
        let mut k = 0;
        for t in &fit.terms {
            match t {
                Term::Piston => c[0] = fit.coefficients_nm[k],
                Term::Tilt => {
                    c[1] = fit.coefficients_nm[k];
                    c[2] = fit.coefficients_nm[k + 1];
                }
                _ => c[3] = fit.coefficients_nm[k],
            }
            k += t.n_basis();
        }
        out.axis_iter_mut(Axis(0))
            .into_par_iter()
            .enumerate()
            .for_each(|(i, mut row)| {
                let v = (i as f64 * sy - fit.centre.1) / fit.half_extent;
                for (j, o) in row.iter_mut().enumerate() {
                    let u = (j as f64 * sx - fit.centre.0) / fit.half_extent;
                    *o = c[0] + c[1] * u + c[2] * v + c[3] * (u * u + v * v);
                }
            });
        return out;
    }
    out.axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(i, mut row)| {
            let mut basis = Vec::with_capacity(fit.coefficients_nm.len());
            for (j, o) in row.iter_mut().enumerate() {
                let c = fit.coords(j as f64 * sx, i as f64 * sy);
                basis.clear();
                for t in &fit.terms {
                    t.eval(&c, &mut basis);
                }
                *o = basis
                    .iter()
                    .zip(&fit.coefficients_nm)
                    .map(|(b, c)| b * c)
                    .sum();
            }
        });
    out
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
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
    fn parse_list_names_and_errors() {
        assert_eq!(
            Term::parse_list("piston, tilt").unwrap(),
            vec![Term::Piston, Term::Tilt]
        );
        assert_eq!(
            Term::parse_list("Zernike37,legendre3,none").unwrap(),
            vec![Term::Zernike(37), Term::Legendre(3)]
        );
        assert_eq!(Term::parse("zernike").unwrap(), Term::Zernike(37));
        for bad in [
            "coma",
            "zernike0",
            "zernike38",
            "legendre13",
            "legendre-1",
            "zernikeX",
            "",
            "piston,,tilt",
            "piston,",
        ] {
            assert!(Term::parse_list(bad).is_err(), "{bad}");
        }
        for t in [
            Term::Piston,
            Term::Zernike(12),
            Term::Legendre(0),
            Term::Legendre(12),
        ] {
            assert_eq!(Term::parse(t.name()).unwrap(), t);
        }
        assert!(fit_terms(
            &Surface::new(Array2::zeros((3, 3)), None, None).unwrap(),
            &[Term::Zernike(40)]
        )
        .is_err());
        let s = Surface::new(Array2::from_elem((1, 1), 1.0), None, None).unwrap();
        assert!(remove_terms(&s, &[Term::Piston, Term::Tilt]).is_err());
    }

    /// A circular aperture of radius `rad` pixels in an n x n grid.
    fn disc(n: usize, rad: f64) -> Array2<bool> {
        let c = (n - 1) as f64 / 2.0;
        Array2::from_shape_fn((n, n), |(i, j)| {
            (i as f64 - c).powi(2) + (j as f64 - c).powi(2) <= rad * rad
        })
    }

    #[test]
    fn zernike37_fit_is_exact_on_an_exact_zernike_surface() {
        let n = 121;
        let mask = disc(n, 60.0);
        let c = (n - 1) as f64 / 2.0;
        // The unit circle the fit builds: centre c, radius = max distance of a valid pixel (60).
        let mut rng = Rng::new(11);
        let coef: Vec<f64> = (0..37).map(|_| 50.0 * rng.normal()).collect();
        let z = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = ((j as f64 - c) / 60.0, (i as f64 - c) / 60.0);
            (0..37)
                .map(|k| coef[k] * basis::fringe_zernike(k + 1, x, y))
                .sum::<f64>()
        });
        let s = Surface::with_mask(z, mask, Some(0.2), Some(0.2)).unwrap();
        let (r, fit) = remove_terms(&s, &[Term::Piston, Term::Zernike(37)]).unwrap();
        assert!(
            (fit.radius - 12.0).abs() < 1e-12,
            "radius {} mm",
            fit.radius
        );
        assert_eq!(fit.dropped, vec![1], "piston is Z1 and is fitted once");
        let max = r.valid_heights().map(f64::abs).fold(0.0, f64::max);
        assert!(max < 1e-8, "residual {max} nm");
        for (k, want) in coef.iter().enumerate() {
            let piston = if k == 0 { fit.coefficients_nm[0] } else { 0.0 };
            let got = fit.coefficients_nm[1 + k] + piston;
            assert!((got - want).abs() < 1e-8, "Z{}: {got} vs {want}", k + 1);
        }
    }

    #[test]
    fn legendre_fit_is_exact_on_a_polynomial_over_a_rectangle_with_holes() {
        let (rows, cols) = (50, 90);
        let mut rng = Rng::new(5);
        // Any polynomial of total degree <= 4 in x, y, in physical units far from the origin.
        let a: Vec<f64> = (0..15).map(|_| rng.normal()).collect();
        let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let x = j as f64 * 0.3 / 10.0 + 1.0;
            let y = i as f64 * 0.7 / 10.0 - 2.0;
            let mut k = 0;
            let mut v = 0.0;
            for d in 0..=4 {
                for p in 0..=d {
                    v += a[k] * x.powi(p) * y.powi(d - p) * 100.0;
                    k += 1;
                }
            }
            v
        });
        let mask = Array2::from_shape_fn((rows, cols), |_| rng.uniform() > 0.1);
        let s = Surface::with_mask(z, mask, Some(0.3), Some(0.7)).unwrap();
        let (r, fit) = remove_terms(&s, &[Term::Legendre(4)]).unwrap();
        assert!(fit.dropped.is_empty());
        let scale = s.valid_heights().map(f64::abs).fold(0.0, f64::max);
        let max = r.valid_heights().map(f64::abs).fold(0.0, f64::max);
        assert!(max < 1e-10 * scale, "residual {max} of {scale}");
        // Degree 3 leaves the quartic part; that residual must be orthogonal to all cubics.
        let (r3, _) = remove_terms(&s, &[Term::Legendre(3)]).unwrap();
        let (r33, _) = remove_terms(&r3, &[Term::Legendre(3)]).unwrap();
        let d = r33
            .valid_heights()
            .zip(r3.valid_heights())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
        assert!(d < 1e-8 * scale, "refit moved the residual by {d}");
    }

    #[test]
    fn fit_does_not_depend_on_thread_count() {
        let mut rng = Rng::new(9);
        let z = Array2::from_shape_fn((200, 150), |_| rng.normal());
        let s = Surface::new(z, Some(0.1), Some(0.1)).unwrap();
        let terms = [Term::Zernike(15)];
        let a = fit_terms(&s, &terms).unwrap();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let b = pool.install(|| fit_terms(&s, &terms).unwrap());
        assert_eq!(a, b, "bit-identical coefficients");
    }
}
