//! Band-limited RMS from the map itself: the band values every report shows (`stats --bands`,
//! `compare`, and the lead's simulate / calibrate through [`band_split`]).
//!
//! Bands (edges F1 <= F2 in cycles/mm, default [`BAND_EDGES_DEFAULT_PER_MM`]): *figure* below
//! F1, *MSF* from F1 to F2, *fine* above F2, by radial frequency |f| = sqrt(fx^2 + fy^2).
//!
//! Method: brick-wall bands of an orthonormal 2-D transform, no window, after the joint removal
//! of the requested form terms and of the valid-pixel mean (z is that residual, V its valid
//! pixels, n = |V|):
//! 1. holes: invalid pixels are filled by the project's one hole fill
//!    (`bonnetlab_surface::fill`: front by front, each pixel the mean of its known
//!    8-neighbours; a small dropout takes the local mean, the corners outside a round aperture
//!    continue the rim). The fill only carries the transform across holes; it is never counted;
//! 2. the border: along each axis the map is continued mirrored (DCT-II), or periodically
//!    (DFT) when it is periodic along that axis: both border lines measured, the join across
//!    them no rougher than its neighbour steps, and the spectrum along the axis more
//!    concentrated that way (`transform`). A sinusoid with whole periods along an axis then
//!    stays in its own band exactly, as in `psd --window none`, while a trend or a figure term
//!    (a jump at the join) keeps the mirrored border, which does not spread it;
//! 3. components: L1, L2 = the filled map's low-passes below F1 and below F2 (coefficients with
//!    |f| under the edge kept); the band components are c_fig = L1, c_msf = L2 - L1,
//!    c_fine = z - L2, which add up to z on every valid pixel;
//! 4. band powers, over the valid pixels: the sequential least-squares projection of z, low
//!    band first. Figure = the best multiple of L1 (power <z, L1>^2 / <L1, L1>); MSF = what the
//!    part of L2 orthogonal to L1 adds; fine = the rest of z. The three parts are orthogonal on
//!    V, so each power is >= 0, none exceeds Sq^2, and they add up to Sq^2 exactly on any
//!    aperture. On a complete map the components are already orthogonal, the projection changes
//!    nothing, and the powers are the coefficient sums in each band (Parseval).
//!
//! Why the projection (it replaced a covariance, P_b = <c_b, z>_V / n): on a masked map the
//! components are not orthogonal over V, and the covariance hands each band its own power plus
//! its cross terms with the others, which can be large and of either sign: a figure band that
//! holds a handful of coefficients cannot follow a bowl that ends at a steep rim, so L1 and
//! L2 - L1 both carry a large, opposite correction near the rim (pykat CVI1-S1-BC, piston and
//! tilt removed, edges 0.05, 0.5: components of 118 and 61 nm RMS beside an Sq of 92 nm, and an
//! MSF power of -931 nm^2). The projection keeps exactly what each band explains. How far the
//! components were from orthogonal is reported: `cross_term_fraction` (sum over band pairs of
//! |2 <c_a, c_b>_V| / <z, z>_V, 0 on a complete map), `component_rms_nm` (each component's own
//! RMS over V), and an `ambiguity` sentence when the cross terms exceed
//! [`AMBIGUOUS_CROSS_FRACTION`]: there the split depends on how the aperture is continued and a
//! band narrower than the aperture can resolve moves power to its neighbour.
//!
//! Limits: a finite record of a sinusoid without whole periods along an axis is not a pure
//! frequency under any windowless orthogonal split (the DFT leaks it as much as the DCT, and a
//! trend far more): on a full rectangle the mirrored border puts 0.1 to 0.6 % of an
//! axis-aligned sinusoid's power in the other bands (a few periods from an edge), an oblique
//! one, whose leaks along X and Y multiply, typically 0.01 % (at most 0.2 % in our trials).
//! Only a window removes that, at the cost of the exact sum on maps whose content is not
//! uniform (a figure term rising to the border).
//!
//! A band the map cannot resolve is `None` with a reason: no pixel size, the band lies
//! below the lowest measured frequency 1 / (the valid field's longest side), or above the
//! Nyquist frequency of the coarser axis. An edge outside the measured range makes no cut:
//! the content on its side belongs to the neighbouring band (e.g. with F2 above Nyquist, MSF
//! runs from F1 to Nyquist and fine is absent).
//!
//! The PSD-integrated band RMS (bin sums of a windowed PSD, `band`) is a different, labelled
//! quantity: its window loss on non-stationary maps makes it disagree with Sq.

mod transform;

use std::borrow::Cow;

use bonnetlab_surface::fill::fill_invalid;
use bonnetlab_surface::surface::mask_bounds;
use bonnetlab_surface::{remove_terms, Surface, Term};
use ndarray::Array2;
use rayon::prelude::*;
use serde::Serialize;

use crate::error::SpectrumError;
use transform::{forward_chosen, radial_freq, radial_lowpass, transform2, Border};

/// Why a frequency-domain quantity of a map without a pixel size is absent (band RMS, ripple).
pub const UNKNOWN_PIXEL_REASON: &str =
    "not resolvable: the pixel size is unknown, so no spatial frequency can be assigned";

/// Default band edges, mm^-1: figure above 33 mm periods, MSF 33 mm to 0.12 mm, fine below
/// 0.12 mm. Source: shared/spec/metrology.md ("1/33 mm to 1/0.12 mm"), the large-optics
/// (NIF / LLNL) convention for mid-spatial frequencies.
pub const BAND_EDGES_DEFAULT_PER_MM: (f64, f64) = (1.0 / 33.0, 1.0 / 0.12);

/// Cross terms (`cross_term_fraction`) above which the split of a masked map is reported as
/// ambiguous: the band components then overlap by more than 5 % of Sq^2 over the valid pixels.
pub const AMBIGUOUS_CROSS_FRACTION: f64 = 0.05;

/// The three band RMS values of one map (field names as `stats --bands` writes them).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArealBands {
    /// Requested edges [F1, F2], mm^-1.
    pub edges_per_mm: [f64; 2],
    /// RMS below F1, nm; `None` when not resolvable (see `figure_reason`).
    pub figure_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub figure_reason: Option<String>,
    /// RMS from F1 to F2, nm.
    pub msf_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub msf_reason: Option<String>,
    /// RMS above F2, nm.
    pub fine_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fine_reason: Option<String>,
    /// Sq of the same residual, nm: the quadrature sum of the resolvable bands.
    pub total_rms_nm: f64,
    /// [lowest, highest] frequency the map measures, mm^-1 (1 / longest side of the valid
    /// field, Nyquist of the coarser axis); `None` without a pixel size.
    pub measured_range_per_mm: Option<[f64; 2]>,
    /// Sum over band pairs of |2 <c_a, c_b>| / <z, z> over the valid pixels, for the band
    /// components before the projection: 0 for an orthogonal split (a complete map).
    pub cross_term_fraction: f64,
    /// RMS over the valid pixels of each band component alone (figure, MSF, fine), nm, before
    /// the projection; equal to the band values when `cross_term_fraction` is 0. A component
    /// may exceed Sq when the components overlap.
    pub component_rms_nm: [Option<f64>; 3],
    /// Present when `cross_term_fraction` exceeds [`AMBIGUOUS_CROSS_FRACTION`]: why the values
    /// depend on the method there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ambiguity: Option<String>,
    pub removed: Vec<Term>,
    pub method: String,
}

impl ArealBands {
    /// (name, value, reason) of the three bands, figure first.
    pub fn bands(&self) -> [(&'static str, Option<f64>, Option<&str>); 3] {
        [
            ("figure", self.figure_rms_nm, self.figure_reason.as_deref()),
            ("msf", self.msf_rms_nm, self.msf_reason.as_deref()),
            ("fine", self.fine_rms_nm, self.fine_reason.as_deref()),
        ]
    }
}

/// The method, as written beside the values (each map's `method` adds which borders it took).
pub const AREAL_METHOD: &str = "areal split of the map by radial frequency: brick-wall bands \
     of its orthonormal 2-D transform, no window; along each axis the border is mirrored \
     (DCT-II), or periodic (DFT) when the map is periodic along it (both border lines \
     measured, the join no rougher than its neighbour steps, and a more concentrated spectrum \
     that way, by entropy); invalid pixels filled front by \
     front from the mean of their known 8-neighbours (the fill carries the transform across \
     holes and is never counted); band powers = sequential least-squares projection of the map \
     over the valid pixels, low band first (figure: the best multiple of the figure component; \
     MSF: what the MSF component adds; fine: the rest), so none is negative and they add up to \
     Sq^2 exactly; on a complete map these are the coefficient sums";

/// A low-pass of z over the valid pixels: nothing passes, all of z passes, or a filtered map.
enum Low {
    Zero,
    All,
    Map(Array2<f64>),
}

impl Low {
    /// Row `i` of the low-pass (`None`: zero), `z_row` being row `i` of z.
    fn row<'a>(&'a self, i: usize, z_row: &'a [f64]) -> Option<&'a [f64]> {
        match self {
            Low::Zero => None,
            Low::All => Some(z_row),
            Low::Map(m) => m.row(i).to_slice(),
        }
    }
}

/// Where a band edge falls in the measured range [f_lo, f_hi].
#[derive(Clone, Copy)]
enum Edge {
    /// At or below the lowest measured frequency: nothing lies below it.
    Below,
    /// At or above Nyquist: everything lies below it.
    Above,
    /// Inside: a cut.
    At(f64),
}

/// Powers (sum of squares over the valid pixels, not yet divided by n) of the split.
struct Split {
    /// Figure, MSF, fine.
    power: [f64; 3],
    /// Each band component's own sum of squares.
    own: [f64; 3],
    /// Sum over band pairs of |2 <c_a, c_b>|.
    cross: f64,
}

/// Band RMS of `s` after removing `remove` jointly (and the mean), split at `edges_per_mm`.
pub fn band_split(
    s: &Surface,
    remove: &[Term],
    edges_per_mm: (f64, f64),
) -> Result<ArealBands, SpectrumError> {
    let (f1, f2) = edges_per_mm;
    crate::band::check_band(f1, f2)?;
    let (r, _) = remove_terms(s, remove)?;
    let n = r.valid_count();
    if n == 0 {
        return Err(bonnetlab_surface::SurfaceError::NoValidPixel.into());
    }
    let valid = r.valid().as_standard_layout().into_owned();
    let mean = r.valid_heights().sum::<f64>() / n as f64;
    let z = Array2::from_shape_fn(r.dim(), |ij| {
        if valid[ij] {
            r.heights_nm()[ij] - mean
        } else {
            0.0
        }
    });
    let zz: f64 = z.iter().map(|v| v * v).sum();
    let total = (zz / n as f64).sqrt();
    let mut out = ArealBands {
        edges_per_mm: [f1, f2],
        figure_rms_nm: None,
        figure_reason: None,
        msf_rms_nm: None,
        msf_reason: None,
        fine_rms_nm: None,
        fine_reason: None,
        total_rms_nm: total,
        measured_range_per_mm: None,
        cross_term_fraction: 0.0,
        component_rms_nm: [None; 3],
        ambiguity: None,
        removed: r.removed.clone(),
        method: AREAL_METHOD.into(),
    };
    let (Some(dx), Some(dy)) = (s.dx_mm, s.dy_mm) else {
        let why = UNKNOWN_PIXEL_REASON.to_string();
        out.figure_reason = Some(why.clone());
        out.msf_reason = Some(why.clone());
        out.fine_reason = Some(why);
        return Ok(out);
    };
    let (lx, ly) = valid_extent_mm(&valid, dx, dy);
    let field = lx.max(ly);
    let f_lo = 1.0 / field;
    let f_hi = 0.5 / dx.max(dy);
    out.measured_range_per_mm = Some([f_lo, f_hi]);
    let edge = |f: f64| {
        if f <= f_lo {
            Edge::Below
        } else if f >= f_hi {
            Edge::Above
        } else {
            Edge::At(f)
        }
    };
    let (e1, e2) = (edge(f1), edge(f2));
    let complete = n == valid.len();
    let (split, here) = if matches!(e1, Edge::At(_)) || matches!(e2, Edge::At(_)) {
        let filled = if complete {
            Cow::Borrowed(&z)
        } else {
            Cow::Owned(fill_invalid(&z, &valid))
        };
        let (rows, cols) = valid.dim();
        let measured_x = (0..rows).all(|i| valid[(i, 0)] && valid[(i, cols - 1)]);
        let measured_y = (0..cols).all(|j| valid[(0, j)] && valid[(rows - 1, j)]);
        let (c, bx, by) = forward_chosen(&filled, measured_x, measured_y);
        drop(filled);
        let borders = format!("X {}, Y {}", bx.name(), by.name());
        if complete {
            let power = coefficient_powers(&c, (bx, by), dx, dy, e1, e2);
            let split = Split {
                power,
                own: power,
                cross: 0.0,
            };
            (split, format!("{borders}; complete map: coefficient sums"))
        } else {
            let low = |e: Edge| match e {
                Edge::Below => Low::Zero,
                Edge::Above => Low::All,
                Edge::At(f) => Low::Map(radial_lowpass(&c, (bx, by), dx, dy, f)),
            };
            let l1 = low(e1);
            let l2 = if f2 == f1 { None } else { Some(low(e2)) };
            drop(c);
            let split = project(&z, &valid, &l1, l2.as_ref().unwrap_or(&l1));
            let pixels = format!("{borders}; {n} of {} pixels valid", valid.len());
            (split, pixels)
        }
    } else {
        // No cut: each band is all of z or nothing.
        let l = |e: Edge| {
            if matches!(e, Edge::Above) {
                Low::All
            } else {
                Low::Zero
            }
        };
        let split = project(&z, &valid, &l(e1), &l(e2));
        (
            split,
            "no edge inside the measured range, no transform".to_string(),
        )
    };
    out.method = format!("{AREAL_METHOD}; this map: {here}");
    out.cross_term_fraction = if zz > 0.0 { split.cross / zz } else { 0.0 };
    let rms = |p: f64| (p.max(0.0) / n as f64).sqrt();
    let [fig, msf, fine] = split.power.map(rms);
    let own = split.own.map(rms);
    // figure [0, F1]
    if let Edge::Below = e1 {
        out.figure_reason = Some(below_reason("the figure band", f1, f_lo, field));
    } else {
        out.figure_rms_nm = Some(fig);
        out.component_rms_nm[0] = Some(own[0]);
    }
    // MSF [F1, F2]
    if let Edge::Below = e2 {
        out.msf_reason = Some(below_reason("the MSF band", f2, f_lo, field));
    } else if let Edge::Above = e1 {
        out.msf_reason = Some(above_reason("the MSF band", f1, f_hi, dx.max(dy)));
    } else {
        out.msf_rms_nm = Some(msf);
        out.component_rms_nm[1] = Some(own[1]);
    }
    // fine [F2, inf)
    if let Edge::Above = e2 {
        out.fine_reason = Some(above_reason("the fine band", f2, f_hi, dx.max(dy)));
    } else {
        out.fine_rms_nm = Some(fine);
        out.component_rms_nm[2] = Some(own[2]);
    }
    if out.cross_term_fraction > AMBIGUOUS_CROSS_FRACTION {
        let fmt = |v: Option<f64>| v.map_or("absent".to_string(), crate::band::fmt_short);
        out.ambiguity = Some(format!(
            "the band components overlap over the valid pixels (cross terms {} % of Sq^2; alone \
             they have figure {}, MSF {}, fine {} nm RMS against Sq {} nm): the split depends \
             on how the aperture is continued, and a band narrower than the aperture can \
             resolve gives power to its neighbours; the values are the projection, low band \
             first",
            crate::band::fmt_short(100.0 * out.cross_term_fraction),
            fmt(out.component_rms_nm[0]),
            fmt(out.component_rms_nm[1]),
            fmt(out.component_rms_nm[2]),
            crate::band::fmt_short(total),
        ));
    }
    Ok(out)
}

fn below_reason(what: &str, edge: f64, f_lo: f64, field: f64) -> String {
    let fmt = crate::band::fmt_short;
    format!(
        "not resolvable: {what} (periods longer than {} mm) lies below the lowest measured \
         frequency {} 1/mm (the valid field is {} mm long)",
        fmt(1.0 / edge),
        fmt(f_lo),
        fmt(field)
    )
}

fn above_reason(what: &str, edge: f64, f_hi: f64, pixel: f64) -> String {
    let fmt = crate::band::fmt_short;
    format!(
        "not resolvable: {what} (periods shorter than {} mm) lies above the Nyquist \
         frequency {} 1/mm (pixel {} mm)",
        fmt(1.0 / edge),
        fmt(f_hi),
        fmt(pixel)
    )
}

/// Band powers of a complete map: the sums of its squared coefficients by radial frequency
/// (Parseval), figure below `e1`, MSF from `e1` to `e2`, fine above `e2`.
fn coefficient_powers(
    c: &Array2<f64>,
    borders: (Border, Border),
    dx: f64,
    dy: f64,
    e1: Edge,
    e2: Edge,
) -> [f64; 3] {
    let cut = |e: Edge| match e {
        Edge::Below => 0.0,
        Edge::Above => f64::INFINITY,
        Edge::At(f) => f,
    };
    let (c1, c2) = (cut(e1), cut(e2));
    let freq = radial_freq(c.dim(), borders, dx, dy);
    let rows: Vec<[f64; 3]> = (0..c.nrows())
        .into_par_iter()
        .map(|l| {
            let mut p = [0.0; 3];
            for (k, v) in c.row(l).iter().enumerate() {
                let f = freq(l, k);
                let b = if f < c1 {
                    0
                } else if f < c2 {
                    1
                } else {
                    2
                };
                p[b] += v * v;
            }
            p
        })
        .collect();
    sum_rows(&rows)
}

/// Row-by-row sums over the valid pixels of `f(z, L1, L2)`, added in row order (so the result
/// does not depend on the thread count).
fn valid_sums<const K: usize>(
    z: &Array2<f64>,
    valid: &Array2<bool>,
    l1: &Low,
    l2: &Low,
    f: impl Fn(f64, f64, f64) -> [f64; K] + Sync,
) -> [f64; K] {
    // Rows are read as slices: every array here is built in standard layout (`band_split`,
    // the transforms); anything else would be a programming error, not bad input.
    assert!(
        z.is_standard_layout()
            && valid.is_standard_layout()
            && [l1, l2]
                .iter()
                .all(|l| !matches!(l, Low::Map(m) if !m.is_standard_layout())),
        "valid_sums: arrays must be in standard layout"
    );
    let rows: Vec<[f64; K]> = (0..z.nrows())
        .into_par_iter()
        .map(|i| {
            let mut s = [0.0; K];
            let (Some(zr), Some(vr)) = (z.row(i).to_slice(), valid.row(i).to_slice()) else {
                return s;
            };
            let (a, b) = (l1.row(i, zr), l2.row(i, zr));
            for (j, (&zv, _)) in zr.iter().zip(vr).enumerate().filter(|(_, (_, v))| **v) {
                let t = f(zv, a.map_or(0.0, |r| r[j]), b.map_or(0.0, |r| r[j]));
                for (acc, x) in s.iter_mut().zip(t) {
                    *acc += x;
                }
            }
            s
        })
        .collect();
    sum_rows(&rows)
}

fn sum_rows<const K: usize>(rows: &[[f64; K]]) -> [f64; K] {
    let mut s = [0.0; K];
    for r in rows {
        for (a, b) in s.iter_mut().zip(r) {
            *a += b;
        }
    }
    s
}

/// The sequential least-squares projection of z over the valid pixels onto the low-passes L1
/// (below F1) and L2 (below F2), low band first: g1 = alpha L1, u = L2 - beta L1 (the part of
/// L2 orthogonal to L1), g2 = gamma u, e = z - g1 - g2; powers ||g1||^2, ||g2||^2, ||e||^2,
/// each summed directly (not by difference) so that a small band keeps its accuracy.
fn project(z: &Array2<f64>, valid: &Array2<bool>, l1: &Low, l2: &Low) -> Split {
    // a11 = <L1, L1>, b1 = <z, L1>, a12 = <L1, L2>, then the components' own sums and cross
    // terms (c1 = L1, c2 = L2 - L1, c3 = z - L2).
    let [a11, b1, a12, o1, o2, o3, x12, x13, x23] = valid_sums(z, valid, l1, l2, |zv, a, b| {
        let (c1, c2, c3) = (a, b - a, zv - b);
        [
            a * a,
            zv * a,
            a * b,
            c1 * c1,
            c2 * c2,
            c3 * c3,
            c1 * c2,
            c1 * c3,
            c2 * c3,
        ]
    });
    let alpha = if a11 > 0.0 { b1 / a11 } else { 0.0 };
    let beta = if a11 > 0.0 { a12 / a11 } else { 0.0 };
    let [uu, zu, a22] = valid_sums(z, valid, l1, l2, |zv, a, b| {
        let u = b - beta * a;
        [u * u, zv * u, b * b]
    });
    // A u left by rounding only (L2 = L1) carries no band.
    let gamma = if uu > 1e-24 * a22 { zu / uu } else { 0.0 };
    let [ee] = valid_sums(z, valid, l1, l2, |zv, a, b| {
        let e = zv - alpha * a - gamma * (b - beta * a);
        [e * e]
    });
    Split {
        power: [alpha * b1, gamma * zu, ee],
        own: [o1, o2, o3],
        cross: 2.0 * (x12.abs() + x13.abs() + x23.abs()),
    }
}

/// The low-pass component of a masked map with mirrored borders: holes filled by the
/// project's hole fill, 2-D DCT, coefficients with radial frequency below `f_per_mm` kept,
/// returned as a map on the full grid. `z - lowpass` is the component at and above
/// `f_per_mm`; both add up to `z` on every valid pixel. These are [`band_split`]'s components
/// on a map with an incomplete border; its band values are their projection (on a complete map
/// it may continue an axis periodically instead). No mean or form is removed (the caller's map
/// is taken as it is); invalid pixels carry the fill's low-pass.
pub fn lowpass(
    z: &Array2<f64>,
    valid: &Array2<bool>,
    dx_mm: f64,
    dy_mm: f64,
    f_per_mm: f64,
) -> Array2<f64> {
    let filled = if valid.iter().all(|v| *v) {
        z.clone()
    } else {
        fill_invalid(z, valid)
    };
    let m = (Border::Mirrored, Border::Mirrored);
    let c = transform2(&filled, m.0, m.1, false);
    radial_lowpass(&c, m, dx_mm, dy_mm, f_per_mm)
}

/// Lengths (mm) of the bounding box of the valid pixels along X and Y (pixel counts times
/// the pixel size: a field of N pixels measures periods up to N d).
fn valid_extent_mm(valid: &Array2<bool>, dx: f64, dy: f64) -> (f64, f64) {
    match mask_bounds(valid) {
        Some((r0, r1, c0, c1)) => ((c1 - c0 + 1) as f64 * dx, (r1 - r0 + 1) as f64 * dy),
        None => (0.0, 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    /// The low-pass keeps a wave below the edge and drops one above it, across a hole.
    #[test]
    fn lowpass_separates_waves_across_a_hole() {
        let (n, d) = (128, 0.25);
        let lo =
            |i: usize, j: usize| 5.0 * (std::f64::consts::TAU * 0.1 * (i + j) as f64 * d).cos();
        let hi = |j: usize| 2.0 * (std::f64::consts::TAU * 1.2 * j as f64 * d).sin();
        let z = Array2::from_shape_fn((n, n), |(i, j)| lo(i, j) + hi(j));
        let valid = Array2::from_shape_fn((n, n), |(i, j)| {
            (i as f64 - 60.0).hypot(j as f64 - 70.0) > 6.0
        });
        let l = lowpass(&z, &valid, d, d, 0.5);
        // Away from the border and the hole (the brick wall rings over a few pixels there).
        let mut worst: f64 = 0.0;
        for i in 20..n - 20 {
            for j in 20..n - 20 {
                if (i as f64 - 60.0).hypot(j as f64 - 70.0) > 16.0 {
                    worst = worst.max((l[(i, j)] - lo(i, j)).abs());
                }
            }
        }
        assert!(worst < 0.25, "low-pass off by {worst} nm");
    }

    /// On a complete map the projection changes nothing: it gives the coefficient sums (the
    /// shortcut `band_split` takes there), for either border.
    #[test]
    fn projection_on_a_complete_map_equals_the_coefficient_sums() {
        let mut r = Rng::new(8);
        let (ny, nx, d) = (40, 52, 0.1);
        let z = Array2::from_shape_fn((ny, nx), |(i, j)| {
            3.0 * (0.21 * i as f64).sin() + 0.05 * (j as f64 - 20.0).powi(2) + r.normal()
        });
        let mean = z.mean().unwrap_or(0.0);
        let z = z.mapv(|v| v - mean);
        let valid = Array2::from_elem((ny, nx), true);
        for borders in [
            (Border::Mirrored, Border::Mirrored),
            (Border::Periodic, Border::Mirrored),
        ] {
            let c = transform2(&z, borders.0, borders.1, false);
            let (f1, f2) = (0.4, 2.0);
            let sums = coefficient_powers(&c, borders, d, d, Edge::At(f1), Edge::At(f2));
            let l1 = Low::Map(radial_lowpass(&c, borders, d, d, f1));
            let l2 = Low::Map(radial_lowpass(&c, borders, d, d, f2));
            let p = project(&z, &valid, &l1, &l2);
            let zz: f64 = z.iter().map(|v| v * v).sum();
            for (k, want) in sums.iter().enumerate() {
                assert!(*want > 1e-3 * zz, "{borders:?} band {k} is empty");
                assert!(
                    (p.power[k] - want).abs() < 1e-9 * zz,
                    "{borders:?} band {k}"
                );
                assert!((p.own[k] - want).abs() < 1e-9 * zz, "{borders:?} own {k}");
            }
            assert!(p.cross < 1e-9 * zz);
        }
    }
}
