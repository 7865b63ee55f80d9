//! Zygo XYZ export reader ("Zygo XYZ Data File - Format 1", spec zygo-formats.md §4).
//!
//! **Unverified layout** (no real file could be obtained; it follows three independent
//! parsers): the ASCII header, a `#`, then one line `X Y Z` per camera pixel, X = column and
//! Y = row in camera pixels (so they include the `cn_org` offset), Z in micrometres, or
//! `X Y No Data` for a missing point; a final `#`. If every X, Y falls inside the window
//! relative to (0, 0) but not relative to `cn_org`, they are taken as window indices instead.
//! Pixels without a line are invalid.

use bonnetlab_surface::Surface;

use crate::error::ParseError;
use crate::metropro_dat::build_surface;
use crate::zygo_text::{parse_header, Lines, XYZ_SIGNATURE};

/// Reads a Zygo XYZ map from its bytes.
pub fn parse(bytes: &[u8]) -> Result<Surface, ParseError> {
    let mut lines = Lines::new(bytes);
    let hdr = parse_header(&mut lines, XYZ_SIGNATURE)?;
    let pixel_mm = hdr.meta.pixel_mm()?;
    let (rows, cols) = (hdr.cn_height(), hdr.cn_width());
    // Every pixel costs at least one byte in any plausible export: refuse before allocating.
    if rows * cols > lines.remaining() {
        return Err(ParseError::invalid(format!(
            "truncated: cn_width {cols} x cn_height {rows} pixels cannot fit in the {} bytes left",
            lines.remaining()
        )));
    }
    // (x, y, z in nm or None), bounded by the file size.
    let mut points: Vec<(i64, i64, Option<f64>)> = Vec::new();
    for (line_no, raw) in lines.by_ref() {
        let text = String::from_utf8_lossy(raw);
        let t = text.trim();
        if t.is_empty() {
            continue;
        }
        if t == "#" {
            break;
        }
        let mut it = t.split_whitespace();
        let mut coord = |name: &str| -> Result<i64, ParseError> {
            let tok = it
                .next()
                .ok_or_else(|| ParseError::invalid(format!("line {line_no}: {name} is missing")))?;
            tok.parse::<i64>().map_err(|_| {
                ParseError::invalid(format!(
                    "line {line_no}: {name} = '{tok}' is not an integer pixel index"
                ))
            })
        };
        let (x, y) = (coord("X")?, coord("Y")?);
        let rest: Vec<&str> = it.collect();
        let z = match rest.as_slice() {
            [a, b] if a.eq_ignore_ascii_case("no") && b.eq_ignore_ascii_case("data") => None,
            [z] => Some(
                z.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        ParseError::invalid(format!("line {line_no}: Z = '{z}' is not a number"))
                    })?
                    * 1e3,
            ),
            _ => {
                return Err(ParseError::invalid(format!(
                    "line {line_no}: expected 'X Y Z' or 'X Y No Data'"
                )))
            }
        };
        points.push((x, y, z));
    }
    let (ox, oy) = (hdr.cn[0], hdr.cn[1]);
    let inside = |dx: i64, dy: i64| {
        points.iter().all(|&(x, y, _)| {
            (0..cols as i64).contains(&(x - dx)) && (0..rows as i64).contains(&(y - dy))
        })
    };
    let (sx, sy) = if inside(ox, oy) {
        (ox, oy)
    } else if inside(0, 0) {
        (0, 0)
    } else {
        let (x, y, _) = points
            .iter()
            .find(|&&(x, y, _)| {
                !((0..cols as i64).contains(&(x - ox)) && (0..rows as i64).contains(&(y - oy)))
            })
            .copied()
            .unwrap_or((0, 0, None));
        return Err(ParseError::invalid(format!(
            "pixel ({x}, {y}) lies outside the window cn_org ({ox}, {oy}) size {cols} x {rows}"
        )));
    };
    let mut heights = vec![0.0; rows * cols];
    let mut valid = vec![false; rows * cols];
    for (x, y, z) in points {
        let k = (y - sy) as usize * cols + (x - sx) as usize;
        if let Some(z) = z {
            heights[k] = z;
            valid[k] = true;
        }
    }
    build_surface(
        heights,
        valid,
        (rows, cols),
        &hdr.meta,
        pixel_mm,
        "zygo-xyz",
    )
}
