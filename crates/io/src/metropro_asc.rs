//! Zygo ASCII export reader ("Zygo ASCII Data File - Format 2", spec zygo-formats.md §3).
//!
//! After the header come the intensity block and the phase block, each closed by a `#` token;
//! the phase block holds raw counts (the same integers as the .dat), `2147483640` = no data,
//! row-major with the top row first. Values are parsed by whitespace, never by a fixed count
//! per line.

use bonnetlab_surface::Surface;

use crate::error::ParseError;
use crate::metropro_dat::build_surface;
use crate::zygo_meta::NO_DATA_MIN;
use crate::zygo_text::{parse_header, Lines, ASC_SIGNATURE};

/// Reads a Zygo ASCII map from its bytes.
pub fn parse(bytes: &[u8]) -> Result<Surface, ParseError> {
    let mut lines = Lines::new(bytes);
    let hdr = parse_header(&mut lines, ASC_SIGNATURE)?;
    let scale = hdr.meta.nm_per_count()?;
    let pixel_mm = hdr.meta.pixel_mm()?;

    // Intensity block: only counted (the Surface has no intensity channel).
    let want_int = hdr.intensity_count();
    let mut n_int = 0u64;
    let mut closed = false;
    'int: for (line_no, line) in lines.by_ref() {
        for tok in line
            .split(u8::is_ascii_whitespace)
            .filter(|t| !t.is_empty())
        {
            if tok == b"#" {
                closed = true;
                break 'int;
            }
            if !tok.iter().all(u8::is_ascii_digit) {
                return Err(ParseError::invalid(format!(
                    "line {line_no}: intensity value '{}' is not a non-negative integer",
                    String::from_utf8_lossy(tok)
                )));
            }
            n_int += 1;
        }
    }
    if !closed {
        return Err(ParseError::invalid(format!(
            "truncated: the intensity block ends after {n_int} values without its closing '#'"
        )));
    }
    if n_int != want_int {
        return Err(ParseError::invalid(format!(
            "intensity block has {n_int} values; ac_width x ac_height x ac_n_buckets = {want_int}"
        )));
    }

    let (rows, cols) = (hdr.cn_height(), hdr.cn_width());
    let want = rows * cols;
    // Each value takes at least two bytes (a digit and a separator): refuse before allocating.
    if want > lines.remaining() / 2 + 1 {
        return Err(ParseError::invalid(format!(
            "truncated: cn_width {cols} x cn_height {rows} = {want} phase values cannot fit in \
             the {} bytes left",
            lines.remaining()
        )));
    }
    let mut heights = Vec::with_capacity(want);
    let mut valid = Vec::with_capacity(want);
    let mut closed = false;
    'phase: for (line_no, line) in lines.by_ref() {
        for tok in line
            .split(u8::is_ascii_whitespace)
            .filter(|t| !t.is_empty())
        {
            if tok == b"#" {
                closed = true;
                break 'phase;
            }
            let raw = std::str::from_utf8(tok)
                .ok()
                .and_then(|t| t.parse::<i32>().ok())
                .ok_or_else(|| {
                    ParseError::invalid(format!(
                        "line {line_no}: phase value '{}' is not an integer",
                        String::from_utf8_lossy(tok)
                    ))
                })?;
            if heights.len() == want {
                return Err(ParseError::invalid(format!(
                    "line {line_no}: phase block has more than cn_width x cn_height = {want} values"
                )));
            }
            let ok = raw < NO_DATA_MIN;
            valid.push(ok);
            heights.push(if ok { f64::from(raw) * scale } else { 0.0 });
        }
    }
    if heights.len() != want {
        return Err(ParseError::invalid(format!(
            "{}phase block has {} values; cn_width x cn_height = {want}",
            if closed { "" } else { "truncated: " },
            heights.len()
        )));
    }
    build_surface(
        heights,
        valid,
        (rows, cols),
        &hdr.meta,
        pixel_mm,
        "metropro-asc",
    )
}
