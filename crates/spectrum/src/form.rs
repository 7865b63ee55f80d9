//! Global form removal before any spectrum.
//!
//! Term lists made only of piston, tilt and power are fitted here by normal equations over
//! the valid pixels, in the same normalised frame as `bonnetlab_surface::fit_terms` (centre of
//! the valid pixels' bounding box, scaled by half its longer side). Those three bases are
//! nearly orthogonal in that frame, so the 4 x 4 normal equations are well conditioned, and
//! one streaming pass costs a few ms on a 4096^2 map where the general QR path of
//! `remove_terms` (built for 37 Zernike terms) takes about a second. Any other term list goes
//! to `bonnetlab_surface::remove_terms`. Both paths are tested to agree.

use ndarray::Array2;
use rayon::prelude::*;

use bonnetlab_surface::{remove_terms, Surface, SurfaceError, Term};

use crate::error::SpectrumError;
use crate::scan::{HeightSums, MaskSummary};

/// Rows per band of the parallel reduction: fixed, so the sum order is thread-independent.
const BAND_ROWS: usize = 64;

/// A fitted piston / tilt / power model, evaluated on demand so that the 1-D and 2-D paths can
/// subtract it while they copy lines, without materialising a residual map.
///
/// In the normalised frame (u along x, v along y) every requested basis is a polynomial of
/// degree <= 2 in u whose coefficients depend on v: piston = 1, tilt = (u, v), power = u^2 + v^2.
/// The fit therefore needs, per row, only the moments sum(m u^k) (k <= 4, m the mask) and
/// sum(z u^a) (a <= 2): three multiply-adds per pixel instead of a 4 x 4 outer product.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PlaneModel {
    piston: bool,
    tilt: bool,
    power: bool,
    coef: [f64; 4],
    /// Normalised x coordinate u of every column.
    us: Vec<f64>,
    cy: f64,
    sy: f64,
    half: f64,
    /// Mean of the residual over the valid pixels (0 up to rounding when piston is fitted).
    pub residual_mean: f64,
}

impl PlaneModel {
    fn n_basis(&self) -> usize {
        self.piston as usize + 2 * self.tilt as usize + self.power as usize
    }

    /// Basis k as coefficients of (1, u, u^2) at normalised row coordinate v.
    fn basis_poly(&self, v: f64) -> [[f64; 3]; 4] {
        let mut out = [[0.0; 3]; 4];
        let mut k = 0;
        if self.piston {
            out[k] = [1.0, 0.0, 0.0];
            k += 1;
        }
        if self.tilt {
            out[k] = [0.0, 1.0, 0.0];
            out[k + 1] = [v, 0.0, 0.0];
            k += 2;
        }
        if self.power {
            out[k] = [v * v, 0.0, 1.0];
        }
        out
    }

    pub fn v_of(&self, i: usize) -> f64 {
        (i as f64 * self.sy - self.cy) / self.half
    }

    /// The model along row i as q0 + q1 u + q2 u^2.
    pub fn row_poly(&self, i: usize) -> [f64; 3] {
        let b = self.basis_poly(self.v_of(i));
        let mut q = [0.0; 3];
        for (c, bk) in self.coef.iter().zip(&b).take(self.n_basis()) {
            for (qa, ba) in q.iter_mut().zip(bk) {
                *qa += c * ba;
            }
        }
        q
    }

    /// Coefficients of 1, u, v and u^2 + v^2 (0 for terms not fitted).
    fn plain_coefficients(&self) -> [f64; 4] {
        let mut c = [0.0; 4];
        let mut k = 0;
        if self.piston {
            c[0] = self.coef[k];
            k += 1;
        }
        if self.tilt {
            c[1] = self.coef[k];
            c[2] = self.coef[k + 1];
            k += 2;
        }
        if self.power {
            c[3] = self.coef[k];
        }
        c
    }

    /// The model along column j as p0 + p1 v + p2 v^2.
    pub fn col_poly(&self, j: usize) -> [f64; 3] {
        let [c0, cu, cv, cp] = self.plain_coefficients();
        let u = self.us.get(j).copied().unwrap_or(0.0);
        [c0 + cu * u + cp * u * u, cv, cp]
    }

    /// Normalised x coordinate u of every column.
    pub fn us(&self) -> &[f64] {
        &self.us
    }

    /// Writes the model along row i into `out` (one value per column).
    pub fn row(&self, i: usize, out: &mut [f64]) {
        self.row_from(i, 0, out)
    }

    /// Writes the model at row i, columns j0..j0 + out.len(), into `out`.
    pub fn row_from(&self, i: usize, j0: usize, out: &mut [f64]) {
        let [q0, q1, q2] = self.row_poly(i);
        for (o, &u) in out.iter_mut().zip(&self.us[j0.min(self.us.len())..]) {
            *o = q0 + u * (q1 + q2 * u);
        }
    }
}

/// True when `terms` is a non-empty list of piston / tilt / power only.
fn low_order(terms: &[Term]) -> bool {
    !terms.is_empty()
        && terms
            .iter()
            .all(|t| matches!(t, Term::Piston | Term::Tilt | Term::Power))
}

/// Fits piston / tilt / power jointly; `None` when `terms` holds anything else (or nothing).
pub(crate) fn fit_plane_model(
    s: &Surface,
    terms: &[Term],
) -> Result<Option<PlaneModel>, SpectrumError> {
    if !low_order(terms) {
        return Ok(None);
    }
    let mask = MaskSummary::of(s.valid().view());
    Ok(Some(fit_with_scan(s, terms, &mask)?.0))
}

/// The joint fit from one pass over the heights (`HeightSums`), which it also returns.
fn fit_with_scan(
    s: &Surface,
    terms: &[Term],
    mask: &MaskSummary,
) -> Result<(PlaneModel, HeightSums), SpectrumError> {
    let sx = s.dx_mm.unwrap_or(1.0);
    let sy = s.dy_mm.unwrap_or(1.0);
    let Some((r0, r1, c0, c1)) = mask.bounding_box() else {
        return Err(SurfaceError::NoValidPixel.into());
    };
    let cx = 0.5 * (c0 + c1) as f64 * sx;
    let cy = 0.5 * (r0 + r1) as f64 * sy;
    let half = 0.5 * ((c1 - c0) as f64 * sx).max((r1 - r0) as f64 * sy);
    let half = if half > 0.0 && half.is_finite() {
        half
    } else {
        1.0
    };
    let has = |t: Term| terms.contains(&t);
    let (rows, cols) = s.dim();
    let mut m = PlaneModel {
        piston: has(Term::Piston),
        tilt: has(Term::Tilt),
        power: has(Term::Power),
        coef: [0.0; 4],
        us: (0..cols).map(|j| (j as f64 * sx - cx) / half).collect(),
        cy,
        sy,
        half,
        residual_mean: 0.0,
    };
    let sums = HeightSums::of(s.heights_nm().view(), &m.us, m.power);
    let nb = m.n_basis();
    let mut full_moments = [0.0; 5];
    for &u in &m.us {
        let mut p = 1.0;
        for fm in full_moments.iter_mut() {
            *fm += p;
            p *= u;
        }
    }
    let valid = s.valid();
    let model = &m;
    let sums_ref = &sums;
    // Per band: A^T A (4 x 4, full), A^T z, sum of each basis, sum z, count.
    type Acc = ([f64; 16], [f64; 4], [f64; 4], f64, f64);
    let partial: Vec<Acc> = (0..rows.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|b| {
            let mut acc: Acc = ([0.0; 16], [0.0; 4], [0.0; 4], 0.0, 0.0);
            for i in b * BAND_ROWS..((b + 1) * BAND_ROWS).min(rows) {
                if mask.row_valid[i] == 0 {
                    continue;
                }
                let mm = if mask.row_full(i) {
                    full_moments
                } else {
                    let mut mm = [0.0; 5];
                    for (&ok, &u) in valid.row(i).iter().zip(&model.us) {
                        if ok {
                            let uu = u * u;
                            mm[0] += 1.0;
                            mm[1] += u;
                            mm[2] += uu;
                            mm[3] += uu * u;
                            mm[4] += uu * uu;
                        }
                    }
                    mm
                };
                let zm = sums_ref.row[i];
                let bp = model.basis_poly(model.v_of(i));
                for k in 0..nb {
                    for a in 0..3 {
                        if bp[k][a] == 0.0 {
                            continue;
                        }
                        acc.1[k] += bp[k][a] * zm[a];
                        acc.2[k] += bp[k][a] * mm[a];
                        for l in 0..nb {
                            for c in 0..3 {
                                acc.0[k * 4 + l] += bp[k][a] * bp[l][c] * mm[a + c];
                            }
                        }
                    }
                }
                acc.3 += zm[0];
                acc.4 += mm[0];
            }
            acc
        })
        .collect();
    let mut t: Acc = ([0.0; 16], [0.0; 4], [0.0; 4], 0.0, 0.0);
    for p in &partial {
        for k in 0..16 {
            t.0[k] += p.0[k];
        }
        for k in 0..4 {
            t.1[k] += p.1[k];
            t.2[k] += p.2[k];
        }
        t.3 += p.3;
        t.4 += p.4;
    }
    if (t.4 as usize) < nb {
        return Err(SurfaceError::TooFewPixels {
            what: "form removal".into(),
            needed: nb,
            have: t.4 as usize,
        }
        .into());
    }
    m.coef = solve_spd(&mut t.0, &mut t.1, nb)?;
    m.residual_mean = (t.3 - (0..nb).map(|k| m.coef[k] * t.2[k]).sum::<f64>()) / t.4;
    Ok((m, sums))
}

/// The surface with `terms` removed jointly (its `removed` list extended). Piston / tilt /
/// power go through the fast normal-equation path, anything else through `remove_terms`.
pub fn remove_form(s: &Surface, terms: &[Term]) -> Result<Surface, SpectrumError> {
    if s.valid_count() == 0 {
        return Err(SurfaceError::NoValidPixel.into());
    }
    let Some(m) = fit_plane_model(s, terms)? else {
        if terms.is_empty() {
            return Ok(s.clone());
        }
        return Ok(remove_terms(s, terms)?.0);
    };
    let (rows, cols) = s.dim();
    let h = s.heights_nm();
    let mut buf = vec![0.0f64; rows * cols];
    buf.par_chunks_mut(cols.max(1))
        .enumerate()
        .for_each(|(i, o)| {
            m.row(i, o);
            for (o, &z) in o.iter_mut().zip(h.row(i)) {
                *o = z - *o;
            }
        });
    let out = Array2::from_shape_vec((rows, cols), buf)
        .map_err(|e| SpectrumError::TooSmall(e.to_string()))?;
    Ok(with_removed(s.with_heights(out)?, terms))
}

/// A surface ready for line analyses: either the original with a model to subtract on the
/// fly, or a residual computed by `remove_terms`; with the mask summary and height sums of
/// `surface` (as stored, before any model is subtracted).
pub(crate) struct Prepared<'a> {
    pub surface: std::borrow::Cow<'a, Surface>,
    pub model: Option<PlaneModel>,
    pub removed: Vec<Term>,
    pub mask: MaskSummary,
    pub sums: HeightSums,
    /// Mean of the residual (surface minus model) over the valid pixels, nm.
    pub mean_nm: f64,
}

pub(crate) fn prepare<'a>(s: &'a Surface, terms: &[Term]) -> Result<Prepared<'a>, SpectrumError> {
    use std::borrow::Cow;
    let removed = with_removed_list(&s.removed, terms);
    let mask = MaskSummary::of(s.valid().view());
    if mask.valid_count() == 0 {
        return Err(SurfaceError::NoValidPixel.into());
    }
    if low_order(terms) {
        let (m, sums) = fit_with_scan(s, terms, &mask)?;
        return Ok(Prepared {
            surface: Cow::Borrowed(s),
            mean_nm: m.residual_mean,
            model: Some(m),
            removed,
            mask,
            sums,
        });
    }
    let surface = if terms.is_empty() {
        Cow::Borrowed(s)
    } else {
        Cow::Owned(remove_terms(s, terms)?.0)
    };
    let sums = HeightSums::of(surface.heights_nm().view(), &[], false);
    let mean_nm = sums.row.iter().map(|r| r[0]).sum::<f64>() / mask.valid_count() as f64;
    Ok(Prepared {
        surface,
        model: None,
        removed,
        mask,
        sums,
        mean_nm,
    })
}

fn with_removed_list(already: &[Term], terms: &[Term]) -> Vec<Term> {
    let mut r = already.to_vec();
    for t in terms {
        if !r.contains(t) {
            r.push(*t);
        }
    }
    r
}

/// Appends `terms` to the surface's removed list.
pub(crate) fn with_removed(mut r: Surface, terms: &[Term]) -> Surface {
    for t in terms {
        if !r.removed.contains(t) {
            r.removed.push(*t);
        }
    }
    r
}

/// Cholesky solve of the packed upper-triangular 4 x 4 normal equations (size n).
fn solve_spd(ata: &mut [f64; 16], atb: &mut [f64; 4], n: usize) -> Result<[f64; 4], SpectrumError> {
    let scale = (0..n)
        .map(|i| ata[i * 4 + i].abs())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let mut l = [0.0; 16];
    for j in 0..n {
        let mut d = ata[j * 4 + j];
        for k in 0..j {
            d -= l[j * 4 + k] * l[j * 4 + k];
        }
        if d <= scale * 1e-13 {
            return Err(SurfaceError::Singular(
                "the requested terms are not independent on the valid pixels".into(),
            )
            .into());
        }
        let d = d.sqrt();
        l[j * 4 + j] = d;
        for i in j + 1..n {
            let mut s = ata[i * 4 + j];
            for k in 0..j {
                s -= l[i * 4 + k] * l[j * 4 + k];
            }
            l[i * 4 + j] = s / d;
        }
    }
    let mut y = [0.0; 4];
    for i in 0..n {
        let mut s = atb[i];
        for k in 0..i {
            s -= l[i * 4 + k] * y[k];
        }
        y[i] = s / l[i * 4 + i];
    }
    let mut x = [0.0; 4];
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in i + 1..n {
            s -= l[k * 4 + i] * x[k];
        }
        x[i] = s / l[i * 4 + i];
    }
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    #[test]
    fn agrees_with_remove_terms_on_a_masked_noisy_map() {
        let mut r = Rng::new(9);
        let z = Array2::from_shape_fn((70, 90), |(i, j)| {
            let (x, y) = (j as f64 * 0.2, i as f64 * 0.3);
            if r.uniform() < 0.1 || (x - 9.0).powi(2) + (y - 10.0).powi(2) > 100.0 {
                f64::NAN
            } else {
                40.0 + 0.5 * x - 0.8 * y + 0.03 * (x * x + y * y) + r.normal()
            }
        });
        let s = Surface::new(z, Some(0.2), Some(0.3)).unwrap();
        for terms in [
            vec![Term::Piston],
            vec![Term::Piston, Term::Tilt],
            vec![Term::Tilt, Term::Piston, Term::Power],
            vec![Term::Power],
        ] {
            let fast = remove_form(&s, &terms).unwrap();
            let slow = remove_terms(&s, &terms).unwrap().0;
            assert_eq!(fast.valid(), slow.valid());
            for (a, b) in fast.heights_nm().iter().zip(slow.heights_nm()) {
                assert!((a - b).abs() < 1e-9, "{terms:?}: {a} vs {b}");
            }
            assert_eq!(fast.removed, slow.removed);
        }
    }
}
