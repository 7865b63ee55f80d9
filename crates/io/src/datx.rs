//! Mx `.datx` (HDF5) reader through the pure-Rust `hdf5-reader` crate (spec zygo-formats.md §5).
//!
//! The surface dataset is found through the `/MetaData` link table (`Root -> Measurement ->
//! Surface -> Path`), never by guessing, and only that dataset is read: other datasets in real
//! files use filters (id 44440) nobody can decode. Values `>= No Data` (and non-finite values)
//! are invalid. Heights: unit `Fringes` -> `v * W * S * O` with (W, S, O) the `Z Converter`
//! `Parameters[1..3]`; `NanoMeters`, `MicroMeters`, `MilliMeters`, `Meters` are scaled directly.
//! Pixel size: `X Converter` / `Y Converter` `Parameters[1]` in m (0 -> unknown). Compound
//! members are looked up by name, since some Mx files add members (SurfaceTopography #367).
//! Every dataset read is first checked against the file size (`datx_bounds`), so a corrupt
//! dataspace gives an error instead of a huge allocation.

use hdf5_reader::{Attribute, Dataset, Datatype, Hdf5File};
use ndarray::Array2;

use bonnetlab_surface::{Provenance, Surface};

use crate::datx_bounds::{
    check_dataset_size, check_link_table, check_surface_pixels, open_options,
};
use crate::error::ParseError;
use crate::text::unix_to_iso8601;

/// The HDF5 signature (at offset 0; user blocks are not used by Zygo).
pub const HDF5_MAGIC: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

pub fn has_magic(bytes: &[u8]) -> bool {
    bytes.starts_with(HDF5_MAGIC)
}

fn h5err(what: &str, e: impl std::fmt::Display) -> ParseError {
    ParseError::invalid(format!("{what}: {e}"))
}

/// Reads a `.datx` map from its bytes.
pub fn parse(bytes: &[u8]) -> Result<Surface, ParseError> {
    if !has_magic(bytes) {
        return Err(ParseError::invalid(
            "not an HDF5 file (no HDF5 signature at byte 0)",
        ));
    }
    // hdf5-reader is hardened against malformed files; a panic inside it would still be a bug
    // on input data, so it is turned into an error rather than taking the process down.
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| parse_hdf5(bytes))) {
        Ok(r) => r,
        Err(_) => Err(ParseError::invalid(
            "malformed HDF5 structure (the HDF5 decoder gave up)",
        )),
    }
}

fn parse_hdf5(bytes: &[u8]) -> Result<Surface, ParseError> {
    let file = Hdf5File::from_bytes_with_options(bytes, open_options(bytes.len()))
        .map_err(|e| h5err("not a readable HDF5 file", e))?;
    let links = read_link_table(&file, bytes.len())?;
    let find = |src: &str, link: &str| {
        links
            .iter()
            .find(|(s, l, _)| s == src && l == link)
            .map(|(_, _, d)| d.clone())
    };
    let measurement = find("Root", "Measurement")
        .ok_or_else(|| ParseError::invalid("/MetaData has no Root -> Measurement link"))?;
    let surface_id = find(&measurement, "Surface").ok_or_else(|| {
        ParseError::invalid(format!(
            "/MetaData has no Surface link for measurement {measurement}"
        ))
    })?;
    let path = find(&surface_id, "Path").ok_or_else(|| {
        ParseError::invalid(format!("/MetaData has no Path for surface {surface_id}"))
    })?;
    let ds = file
        .dataset(&path)
        .map_err(|e| h5err(&format!("surface dataset {path}"), e))?;
    let mut s = read_surface_dataset(&ds, &path, bytes.len())?;
    let attrs_group = find(&measurement, "Attributes");
    s.provenance = provenance(&file, &ds, attrs_group.as_deref());
    Ok(s)
}

/// The rows (Source, Link, Destination) of `/MetaData`.
fn read_link_table(
    file: &Hdf5File,
    file_bytes: usize,
) -> Result<Vec<(String, String, String)>, ParseError> {
    let md = file
        .dataset("/MetaData")
        .map_err(|e| h5err("no /MetaData link table", e))?;
    let Datatype::Compound { fields, .. } = md.dtype() else {
        return Err(ParseError::invalid("/MetaData is not a compound table"));
    };
    let member = |name: &str| {
        fields
            .iter()
            .find(|f| f.name == name)
            .map(|f| f.byte_offset as usize)
            .ok_or_else(|| ParseError::invalid(format!("/MetaData has no member {name}")))
    };
    let offs = [member("Source")?, member("Link")?, member("Destination")?];
    let (records, rec) = check_dataset_size(&md, "/MetaData", file_bytes)?;
    check_link_table(records, rec, file_bytes as u64)?;
    let rec = rec as usize;
    let raw = md.read_raw_bytes().map_err(|e| h5err("/MetaData", e))?;
    let refsz = md.vlen_reference_size();
    let mut rows = Vec::new();
    for r in raw.chunks_exact(rec.max(1)) {
        let mut cols = Vec::with_capacity(3);
        for &o in &offs {
            let reference = r
                .get(o..o + refsz)
                .ok_or_else(|| ParseError::invalid("/MetaData record shorter than its members"))?;
            let b = md
                .resolve_vlen_reference_bytes(reference, 1)
                .map_err(|e| h5err("/MetaData string", e))?;
            let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
            cols.push(String::from_utf8_lossy(&b[..end]).into_owned());
        }
        if let [s, l, d] = &cols[..] {
            rows.push((s.clone(), l.clone(), d.clone()));
        }
    }
    Ok(rows)
}

fn read_surface_dataset(
    ds: &Dataset,
    path: &str,
    file_bytes: usize,
) -> Result<Surface, ParseError> {
    let shape = ds.shape().to_vec();
    let [rows, cols] = shape[..] else {
        return Err(ParseError::invalid(format!(
            "surface dataset {path} has shape {shape:?}, not 2-D"
        )));
    };
    if rows == 0 || cols == 0 {
        return Err(ParseError::invalid(format!(
            "surface dataset {path} is empty ({rows} x {cols})"
        )));
    }
    let what = format!("surface dataset {path}");
    check_surface_pixels(&what, rows, cols)?;
    check_dataset_size(ds, &what, file_bytes)?;
    let n = (rows * cols) as usize;
    // Read straight into our own buffer (no intermediate array) and turn it into heights in
    // place, so the peak is the heights plus the mask.
    let mut values: Vec<f64> = match ds.dtype() {
        Datatype::FloatingPoint { size: 8, .. } => {
            let mut v = zeroed::<f64>(n, &what)?;
            ds.read_into(&mut v).map_err(|e| h5err(&what, e))?;
            v
        }
        Datatype::FloatingPoint { size: 4, .. } => {
            let mut v = zeroed::<f32>(n, &what)?;
            ds.read_into(&mut v).map_err(|e| h5err(&what, e))?;
            let mut out = Vec::new();
            out.try_reserve_exact(n)
                .map_err(|e| h5err(&format!("{what}: {n} values"), e))?;
            out.extend(v.into_iter().map(f64::from));
            out
        }
        other => {
            return Err(ParseError::invalid(format!(
                "surface dataset {path} has type {other:?}, not a float"
            )))
        }
    };
    let attrs = ds.attributes();
    let get = |name: &str| attrs.iter().find(|a| a.name == name);
    let no_data = match get("No Data") {
        Some(a) => a.read_as_f64().map_err(|e| h5err("attribute No Data", e))?,
        None => f64::INFINITY,
    };
    let unit = get("Unit")
        .and_then(attr_string)
        .ok_or_else(|| ParseError::invalid("surface attribute Unit is missing"))?;
    let scale_nm = match unit.as_str() {
        "Fringes" => {
            let p = get("Z Converter")
                .map(|a| converter_parameters(ds, a))
                .transpose()?
                .unwrap_or_default();
            let (w, s, o) = match p.get(1..4) {
                Some(&[w, s, o]) => (w, s, o),
                _ => (
                    scalar(get("Wavelength"), "Wavelength")?,
                    scalar(
                        get("Interferometric Scale Factor"),
                        "Interferometric Scale Factor",
                    )?,
                    scalar(get("Obliquity Factor"), "Obliquity Factor")?,
                ),
            };
            let f = w * s * o * 1e9;
            if !(f.is_finite() && f > 0.0) {
                return Err(ParseError::invalid(format!(
                    "attribute Z Converter Parameters W = {w}, S = {s}, O = {o} do not give a \
                     positive fringe scale"
                )));
            }
            f
        }
        "NanoMeters" => 1.0,
        "MicroMeters" => 1e3,
        "MilliMeters" => 1e6,
        "Meters" => 1e9,
        other => {
            return Err(ParseError::invalid(format!(
                "surface attribute Unit = '{other}' is not Fringes, NanoMeters, MicroMeters, \
                 MilliMeters or Meters"
            )))
        }
    };
    let pixel = |name: &str| -> Result<Option<f64>, ParseError> {
        let Some(a) = get(name) else { return Ok(None) };
        let p = converter_parameters(ds, a)?;
        match p.get(1) {
            Some(&v) if v.is_finite() && v > 0.0 => Ok(Some(v * 1e3)),
            Some(0.0) => Ok(None),
            Some(&v) => Err(ParseError::invalid(format!(
                "attribute {name} Parameters[1] = {v} is not a pixel size in m"
            ))),
            None => Ok(None),
        }
    };
    let dx = pixel("X Converter")?;
    let dy = pixel("Y Converter")?.or(dx);
    let dx = dx.or(dy);
    let mut valid = Vec::new();
    valid
        .try_reserve_exact(n)
        .map_err(|e| h5err(&format!("{what}: mask of {n} pixels"), e))?;
    for v in values.iter_mut() {
        let ok = v.is_finite() && *v < no_data;
        valid.push(ok);
        *v = if ok { *v * scale_nm } else { 0.0 };
    }
    let heights = values;
    if !valid.iter().any(|&v| v) {
        return Err(ParseError::NoValidPixel);
    }
    let dim = (rows as usize, cols as usize);
    let h = Array2::from_shape_vec(dim, heights).map_err(|e| h5err("surface shape", e))?;
    let m = Array2::from_shape_vec(dim, valid).map_err(|e| h5err("surface shape", e))?;
    let mut s = Surface::with_mask(h, m, dx, dy).map_err(|e| ParseError::invalid(e.to_string()))?;
    // The data window's corner in camera pixels, as cn_org in a .dat (same frame convention).
    if let Some(a) = get("Coordinates") {
        if let (Some(c0), Some(r0)) = (i32_member(a, "ColumnStart"), i32_member(a, "RowStart")) {
            s.origin_mm = (
                f64::from(c0) * dx.unwrap_or(1.0),
                f64::from(r0) * dy.unwrap_or(1.0),
            );
        }
    }
    Ok(s)
}

/// `n` zeroed values, failing cleanly (not aborting) when memory is short.
fn zeroed<T: Default + Clone>(n: usize, what: &str) -> Result<Vec<T>, ParseError> {
    let mut v = Vec::new();
    v.try_reserve_exact(n)
        .map_err(|e| h5err(&format!("{what}: {n} values"), e))?;
    v.resize(n, T::default());
    Ok(v)
}

/// An i32 member of a compound attribute, by name.
fn i32_member(a: &Attribute, name: &str) -> Option<i32> {
    let Datatype::Compound { fields, .. } = &a.datatype else {
        return None;
    };
    let f = fields.iter().find(|f| f.name == name)?;
    let Datatype::FixedPoint {
        size: 4,
        byte_order,
        ..
    } = f.datatype
    else {
        return None;
    };
    let off = f.byte_offset as usize;
    let mut b = [0u8; 4];
    b.copy_from_slice(a.raw_data.get(off..off + 4)?);
    Some(match byte_order {
        hdf5_reader::ByteOrder::BigEndian => i32::from_be_bytes(b),
        _ => i32::from_le_bytes(b),
    })
}

fn scalar(a: Option<&Attribute>, name: &str) -> Result<f64, ParseError> {
    a.ok_or_else(|| ParseError::invalid(format!("surface attribute {name} is missing")))?
        .read_as_f64()
        .map_err(|e| h5err(&format!("attribute {name}"), e))
}

fn attr_string(a: &Attribute) -> Option<String> {
    if let Some(v) = &a.decoded_strings {
        return v
            .first()
            .map(|s| s.trim_end_matches('\0').trim().to_string());
    }
    a.read_string()
        .ok()
        .map(|s| s.trim_end_matches('\0').trim().to_string())
}

/// The `Parameters` member (a vlen f64 array) of a converter compound attribute.
fn converter_parameters(ds: &Dataset, a: &Attribute) -> Result<Vec<f64>, ParseError> {
    let bad = |why: &str| ParseError::invalid(format!("attribute {}: {why}", a.name));
    let Datatype::Compound { fields, .. } = &a.datatype else {
        return Err(bad("not a compound"));
    };
    let f = fields
        .iter()
        .find(|f| f.name == "Parameters")
        .ok_or_else(|| bad("no Parameters member"))?;
    let off = f.byte_offset as usize;
    match &f.datatype {
        Datatype::VarLen { base, .. } => {
            let Datatype::FloatingPoint {
                size: 8,
                byte_order,
            } = **base
            else {
                return Err(bad("Parameters are not f64"));
            };
            let refsz = ds.vlen_reference_size();
            let r = a
                .raw_data
                .get(off..off + refsz)
                .ok_or_else(|| bad("record too short"))?;
            let b = ds
                .resolve_vlen_reference_bytes(r, 8)
                .map_err(|e| bad(&e.to_string()))?;
            Ok(b.chunks_exact(8)
                .map(|c| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(c);
                    match byte_order {
                        hdf5_reader::ByteOrder::BigEndian => f64::from_be_bytes(a),
                        _ => f64::from_le_bytes(a),
                    }
                })
                .collect())
        }
        Datatype::Array { base, dims } => {
            let Datatype::FloatingPoint {
                size: 8,
                byte_order,
            } = **base
            else {
                return Err(bad("Parameters are not f64"));
            };
            let n = dims.iter().product::<u64>() as usize;
            let b = a
                .raw_data
                .get(off..off.saturating_add(n.saturating_mul(8)))
                .ok_or_else(|| bad("record too short"))?;
            Ok(b.chunks_exact(8)
                .map(|c| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(c);
                    match byte_order {
                        hdf5_reader::ByteOrder::BigEndian => f64::from_be_bytes(a),
                        _ => f64::from_le_bytes(a),
                    }
                })
                .collect())
        }
        _ => Err(bad("Parameters have an unexpected type")),
    }
}

/// Provenance from the measurement's metadata group (missing entries stay `None`).
fn provenance(file: &Hdf5File, ds: &Dataset, attrs_group: Option<&str>) -> Provenance {
    let mut p = Provenance {
        format: "datx".into(),
        ..Provenance::default()
    };
    let ds_attrs = ds.attributes();
    p.wavelength_m = ds_attrs
        .iter()
        .find(|a| a.name == "Wavelength")
        .and_then(|a| a.read_as_f64().ok())
        .filter(|w| w.is_finite() && *w > 0.0);
    let Some(group) = attrs_group.and_then(|g| file.group(g).ok()) else {
        return p;
    };
    let Ok(attrs) = group.attributes() else {
        return p;
    };
    let text = |key: &str| {
        attrs
            .iter()
            .find(|a| a.name == format!("Data Context.Data Attributes.{key}"))
            .and_then(attr_string)
            .filter(|s| !s.is_empty())
    };
    let sys = text("System Type");
    let serial = text("System Serial Number");
    p.instrument = match (sys, serial) {
        (Some(t), Some(s)) => Some(format!("Zygo {t}, serial {s}")),
        (Some(t), None) => Some(format!("Zygo {t}")),
        (None, Some(s)) => Some(format!("Zygo, serial {s}")),
        (None, None) => None,
    };
    p.software = match (text("Software Info Name"), text("Software Info Version")) {
        (Some(n), Some(v)) => Some(format!("{n} {v}")),
        (n, v) => n.or(v),
    };
    p.objective = text("Objective");
    let comment: Vec<String> = [
        text("Comment"),
        text("Part Number").map(|s| format!("part {s}")),
        text("Part Serial Number").map(|s| format!("part serial {s}")),
    ]
    .into_iter()
    .flatten()
    .collect();
    p.comment = (!comment.is_empty()).then(|| comment.join("; "));
    p.date = attrs
        .iter()
        .find(|a| a.name == "Data Context.Data Attributes.Time Stamp")
        .and_then(time_stamp);
    if p.wavelength_m.is_none() {
        p.wavelength_m = attrs
            .iter()
            .find(|a| a.name == "Data Context.Data Attributes.Wavelength:Value")
            .and_then(|a| a.read_as_f64().ok())
            .filter(|w| w.is_finite() && *w > 0.0);
    }
    p
}

/// A `(time i64, millitm, timezone, dstflag)` compound as an ISO date (UTC).
fn time_stamp(a: &Attribute) -> Option<String> {
    let Datatype::Compound { fields, .. } = &a.datatype else {
        return None;
    };
    let f = fields.iter().find(|f| f.name == "time")?;
    let Datatype::FixedPoint {
        size: 8,
        byte_order,
        ..
    } = f.datatype
    else {
        return None;
    };
    let off = f.byte_offset as usize;
    let mut b = [0u8; 8];
    b.copy_from_slice(a.raw_data.get(off..off + 8)?);
    let t = match byte_order {
        hdf5_reader::ByteOrder::BigEndian => i64::from_be_bytes(b),
        _ => i64::from_le_bytes(b),
    };
    (t > 0).then(|| unix_to_iso8601(t))
}
