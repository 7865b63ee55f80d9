//! `stats` and `batch`: height parameters of a map after form removal (PV, RMS, Sa, Ssk, Sku,
//! optionally PVr and the figure / MSF / fine band RMS), and a batch map's JSON object with its
//! ripple at the grating spacing.

use std::path::Path;

use bonnetlab_spectrum::{
    band_split, psd_xy, ripple_from_psds, ArealBands, PsdOptions, RippleOptions, SpectrumError,
    Window,
};
use bonnetlab_surface::{
    height_stats, pvr, remove_terms, HeightStats, Surface, SurfaceError, Term, PVR_SET,
};
use serde::Serialize;
use serde_json::{json, Value};

use super::{read_map, Error};

/// The JSON object printed by `stats --json` (field names are the CLI contract).
#[derive(Debug, Clone, Serialize)]
pub struct StatsReport {
    pub file: String,
    pub format: String,
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: Option<f64>,
    pub dy_mm: Option<f64>,
    pub valid: usize,
    pub removed: Vec<Term>,
    /// `pv_nm`, `rms_nm`, `sa_nm`, `sp_nm`, `sv_nm`, `sz_nm`, `ssk`, `sku`: the height
    /// parameters as the surface crate computes and names them.
    #[serde(flatten)]
    pub heights: HeightStats,
    /// Why `ssk` and `sku` are null (a flat map); absent when they are numbers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub moments_reason: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pvr_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pvr_set: Option<&'static str>,
    /// With `--bands`: the band RMS object of shared/spec/interfaces.md.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bands: Option<ArealBands>,
    /// With `--minus`: the map subtracted from `file` pixel by pixel before the terms were
    /// removed (the statistics are of `file - minus` on the pixels valid in both).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub minus: Option<String>,
}

/// `file - minus` pixel by pixel on the pixels valid in both, for `stats --minus`: with two
/// measurements of an unchanged part and piston and tilt removed, its RMS is the instrument's
/// repeatability (a recipe's `[measurement] repeatability_nm`). The maps must share their grid
/// (rows, columns and pixel size); a mismatch is the subtracted map's fault (exit 2).
pub fn difference_of(
    file: &Path,
    s: &Surface,
    minus_file: &Path,
    m: &Surface,
) -> Result<Surface, Error> {
    let same_pixel = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) => (a - b).abs() <= 1e-6 * a.abs().max(b.abs()),
        (None, None) => true,
        _ => false,
    };
    let mm = |v: Option<f64>| {
        v.map_or("unknown".to_string(), |v| {
            format!("{} mm", bonnetlab_surface::format::sig(v, 7))
        })
    };
    if s.dim() != m.dim() || !same_pixel(s.dx_mm, m.dx_mm) || !same_pixel(s.dy_mm, m.dy_mm) {
        return Err(Error::input(
            minus_file,
            format!(
                "its grid ({} x {}, pixel {} x {}) differs from {}'s ({} x {}, pixel {} x {}); \
                 --minus needs two maps of one grid",
                m.rows(),
                m.cols(),
                mm(m.dx_mm),
                mm(m.dy_mm),
                file.display(),
                s.rows(),
                s.cols(),
                mm(s.dx_mm),
                mm(s.dy_mm)
            ),
        ));
    }
    let mut d = s.difference(m).map_err(|e| Error::input(minus_file, e))?;
    d.provenance.format = s.provenance.format.clone();
    if d.valid_count() == 0 {
        return Err(Error::processing(
            file,
            format!("no pixel is valid in both it and {}", minus_file.display()),
        ));
    }
    Ok(d)
}

/// Maps a library error on a readable map to the CLI's exit codes: a map with too few valid
/// pixels is valid but unusable (1); anything else about the request is bad input (2).
fn surface_error(file: &Path, e: SurfaceError) -> Error {
    match e {
        SurfaceError::NoValidPixel | SurfaceError::TooFewPixels { .. } => {
            Error::processing(file, e)
        }
        _ => Error::input(file, e),
    }
}

/// Computes the report for a map already read.
pub fn stats_report(
    file: &Path,
    s: &Surface,
    terms: &[Term],
    with_pvr: bool,
) -> Result<StatsReport, Error> {
    stats_report_with_bands(file, s, terms, with_pvr, None)
}

/// [`stats_report`] with, when `bands` gives edges (mm^-1), the band RMS object.
pub fn stats_report_with_bands(
    file: &Path,
    s: &Surface,
    terms: &[Term],
    with_pvr: bool,
    bands: Option<(f64, f64)>,
) -> Result<StatsReport, Error> {
    if s.valid_count() == 0 {
        return Err(Error::processing(file, SurfaceError::NoValidPixel));
    }
    let (r, _) = remove_terms(s, terms).map_err(|e| surface_error(file, e))?;
    let st: HeightStats = height_stats(&r).map_err(|e| surface_error(file, e))?;
    let p = if with_pvr {
        Some(pvr(&r).map_err(|e| surface_error(file, e))?)
    } else {
        None
    };
    // The split removes the same terms from the original map (one joint fit, as above).
    let bands = bands
        .map(|edges| band_split(s, terms, edges))
        .transpose()
        .map_err(|e| Error::processing(file, e))?;
    Ok(StatsReport {
        file: file.display().to_string(),
        format: s.provenance.format.clone(),
        rows: s.rows(),
        cols: s.cols(),
        dx_mm: s.dx_mm,
        dy_mm: s.dy_mm,
        valid: st.valid,
        removed: r.removed.clone(),
        heights: st,
        moments_reason: st
            .ssk
            .is_none()
            .then_some("the map is flat after the removed terms (RMS 0): skewness and kurtosis are 0 / 0, undefined"),
        pvr_nm: p.map(|p| p.pvr_nm),
        pvr_set: p.map(|_| PVR_SET),
        bands,
        minus: None,
    })
}

/// One map of a batch as its JSON object: the `stats --json` object of the map (read, the
/// pixel size filled in where the file lacks it, `terms` removed) and, with a pitch, the
/// `window` and the `ripple` object (as `psd`); beside it, the note of a `--pixel-mm` that the
/// file's own pixel size overrides ([`super::fill_pixel_size`]).
pub fn batch_value(
    file: &Path,
    terms: &[Term],
    pitch_mm: Option<f64>,
    window: Window,
    pixel_mm: Option<(f64, f64)>,
) -> Result<(Value, Option<String>), Error> {
    let mut s = read_map(file)?;
    let note = super::fill_pixel_size(&mut s, pixel_mm, file);
    let report = stats_report(file, &s, terms, false)?;
    let mut v = serde_json::to_value(&report).map_err(|e| Error::processing(file, e))?;
    if pitch_mm.is_some() && (s.dx_mm.is_none() || s.dy_mm.is_none()) {
        // No pixel size, no spatial frequency: the statistics stand, the ripple is absent
        // with its reason (as for a pitch the map cannot resolve).
        if let Value::Object(m) = &mut v {
            m.insert("window".into(), json!(window.name()));
            m.insert(
                "ripple_reason".into(),
                json!(format!(
                    "{}; give --pixel-mm",
                    bonnetlab_spectrum::areal::UNKNOWN_PIXEL_REASON
                )),
            );
        }
        return Ok((v, note));
    }
    if let Some(p) = pitch_mm {
        let opts = PsdOptions {
            window,
            remove: terms.to_vec(),
            ..PsdOptions::default()
        };
        let (x, y) = psd_xy(&s, &opts).map_err(|e| Error::input(file, e))?;
        // A pitch the map cannot resolve (longer than the field, or f0 beyond Nyquist) is
        // not a failed map: the ripple is absent with its reason, as `psd` reports it.
        let (key, value) = match ripple_from_psds(&x, &y, p, &RippleOptions::default()) {
            Ok(r) => (
                "ripple",
                serde_json::to_value(&r).map_err(|e| Error::processing(file, e))?,
            ),
            Err(e @ SpectrumError::NotResolvable(_)) => ("ripple_reason", json!(e.to_string())),
            Err(e) => return Err(Error::input(file, e)),
        };
        if let Value::Object(m) = &mut v {
            m.insert("window".into(), json!(window.name()));
            m.insert(key.into(), value);
        }
    }
    Ok((v, note))
}
