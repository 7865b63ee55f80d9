//! OpenEXR height maps through the pure-Rust `exr` crate.
//!
//! We write one layer with one 32-bit float channel `Z` (EXR has no 64-bit float samples):
//! `Z = height_nm - offset_nm`, with the f64 `bonnetlab.offset_nm` (the mean valid height) kept
//! as an attribute so a large piston costs no precision; invalid pixels are NaN. Attributes
//! `bonnetlab.dx_mm`, `bonnetlab.dy_mm` (absent = unknown), `bonnetlab.x0_mm`,
//! `bonnetlab.y0_mm` (f64) and `bonnetlab.<provenance field>` (text) carry the metadata.
//! Reading accepts any scan-line or tiled EXR: channel `Z`, else `Y`, else the first channel;
//! NaN and infinite samples are invalid.

use std::collections::HashMap;
use std::io::Cursor;

use exr::prelude::*;
use ndarray::Array2;

use bonnetlab_surface::{Provenance, Surface};

use crate::error::ParseError;

pub const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

pub fn has_magic(bytes: &[u8]) -> bool {
    bytes.starts_with(&EXR_MAGIC)
}

/// Largest pixel count accepted per byte of file: deflate tops out near 1032:1, i.e. 516 f16
/// or 258 f32 pixels per byte; anything far beyond is a corrupt header, refused before `exr`
/// allocates.
const MAX_PIXELS_PER_BYTE: usize = 1100;

/// Reads an EXR height map.
pub fn parse(bytes: &[u8]) -> std::result::Result<Surface, ParseError> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| ParseError::invalid(format!("EXR header: {e}")))?;
    let Some(header) = meta.headers.first() else {
        return Err(ParseError::invalid("EXR file has no layer"));
    };
    let size = header.layer_size;
    let area = size.width().saturating_mul(size.height());
    if area == 0 {
        return Err(ParseError::invalid("EXR data window is empty"));
    }
    if area / MAX_PIXELS_PER_BYTE > bytes.len() {
        return Err(ParseError::invalid(format!(
            "EXR data window {} x {} is impossible for a {}-byte file",
            size.width(),
            size.height(),
            bytes.len()
        )));
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| ParseError::invalid(format!("EXR: {e}")))?;
    let layer = &image.layer_data;
    let list = &layer.channel_data.list;
    let chan = list
        .iter()
        .find(|c| c.name.eq("Z"))
        .or_else(|| list.iter().find(|c| c.name.eq("Y")))
        .or_else(|| list.first())
        .ok_or_else(|| ParseError::invalid("EXR layer has no channel"))?;
    let (w, h) = (layer.size.width(), layer.size.height());
    let attrs = &layer.attributes.other;
    let f64_attr = |k: &str| match attrs.get(&Text::from(k)) {
        Some(AttributeValue::F64(v)) => Some(*v),
        Some(AttributeValue::F32(v)) => Some(f64::from(*v)),
        _ => None,
    };
    let offset = f64_attr("bonnetlab.offset_nm")
        .filter(|v| v.is_finite())
        .unwrap_or(0.0);
    let mut heights = Vec::with_capacity(w * h);
    let mut valid = Vec::with_capacity(w * h);
    let push = |z: f64, heights: &mut Vec<f64>, valid: &mut Vec<bool>| {
        let ok = z.is_finite();
        valid.push(ok);
        heights.push(if ok { z + offset } else { 0.0 });
    };
    match &chan.sample_data {
        FlatSamples::F32(v) => v
            .iter()
            .for_each(|&z| push(f64::from(z), &mut heights, &mut valid)),
        FlatSamples::F16(v) => v
            .iter()
            .for_each(|&z| push(f64::from(z.to_f32()), &mut heights, &mut valid)),
        FlatSamples::U32(v) => v
            .iter()
            .for_each(|&z| push(f64::from(z), &mut heights, &mut valid)),
    }
    if heights.len() != w * h {
        return Err(ParseError::invalid(format!(
            "EXR channel has {} samples for a {w} x {h} layer",
            heights.len()
        )));
    }
    if !valid.iter().any(|&v| v) {
        return Err(ParseError::NoValidPixel);
    }
    let pix = |k: &str| f64_attr(k).filter(|v| v.is_finite() && *v > 0.0);
    let (dx, dy) = (pix("bonnetlab.dx_mm"), pix("bonnetlab.dy_mm"));
    let hm =
        Array2::from_shape_vec((h, w), heights).map_err(|e| ParseError::invalid(e.to_string()))?;
    let vm =
        Array2::from_shape_vec((h, w), valid).map_err(|e| ParseError::invalid(e.to_string()))?;
    let mut s =
        Surface::with_mask(hm, vm, dx, dy).map_err(|e| ParseError::invalid(e.to_string()))?;
    s.origin_mm = (
        f64_attr("bonnetlab.x0_mm").unwrap_or(0.0),
        f64_attr("bonnetlab.y0_mm").unwrap_or(0.0),
    );
    let text = |k: &str| match attrs.get(&Text::from(format!("bonnetlab.{k}").as_str())) {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        _ => None,
    };
    s.provenance = Provenance {
        format: "exr".into(),
        source_path: None,
        instrument: text("instrument"),
        wavelength_m: f64_attr("bonnetlab.wavelength_m"),
        objective: text("objective"),
        date: text("date"),
        comment: text("comment"),
        software: text("software"),
    };
    Ok(s)
}

/// Encodes a surface as an EXR file (see the module doc).
pub fn encode(s: &Surface) -> std::result::Result<Vec<u8>, String> {
    let (rows, cols) = s.dim();
    let n = s.valid_count();
    let offset = if n > 0 {
        s.valid_heights().sum::<f64>() / n as f64
    } else {
        0.0
    };
    let samples: Vec<f32> = s
        .heights_nm()
        .iter()
        .zip(s.valid())
        .map(|(&h, &v)| if v { (h - offset) as f32 } else { f32::NAN })
        .collect();
    let mut other: HashMap<Text, AttributeValue> = HashMap::new();
    let mut put = |k: &str, v: AttributeValue| {
        other.insert(Text::from(k), v);
    };
    put("bonnetlab.offset_nm", AttributeValue::F64(offset));
    if let Some(dx) = s.dx_mm {
        put("bonnetlab.dx_mm", AttributeValue::F64(dx));
    }
    if let Some(dy) = s.dy_mm {
        put("bonnetlab.dy_mm", AttributeValue::F64(dy));
    }
    put("bonnetlab.x0_mm", AttributeValue::F64(s.origin_mm.0));
    put("bonnetlab.y0_mm", AttributeValue::F64(s.origin_mm.1));
    if let Some(w) = s.provenance.wavelength_m {
        put("bonnetlab.wavelength_m", AttributeValue::F64(w));
    }
    let p = &s.provenance;
    for (k, v) in [
        ("instrument", &p.instrument),
        ("objective", &p.objective),
        ("date", &p.date),
        ("comment", &p.comment),
        ("software", &p.software),
    ] {
        if let Some(t) = v.as_deref().and_then(|t| {
            // EXR text is Latin-1: replace anything beyond it.
            let l: String = t
                .chars()
                .map(|c| if u32::from(c) < 256 { c } else { '?' })
                .collect();
            Text::new_or_none(l)
        }) {
            put(&format!("bonnetlab.{k}"), AttributeValue::Text(t));
        }
    }
    let mut attrs = LayerAttributes::named("height_nm");
    attrs.other = other;
    let layer = Layer::new(
        (cols, rows),
        attrs,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
            "Z",
            FlatSamples::F32(samples),
        )])),
    );
    let image = Image::from_layer(layer);
    let mut buf = Cursor::new(Vec::new());
    image
        .write()
        .to_buffered(&mut buf)
        .map_err(|e| format!("EXR encoding failed: {e}"))?;
    Ok(buf.into_inner())
}
