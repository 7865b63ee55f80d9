//! Plain CSV height grids: one row of the map per line, heights in nm, comma separated.
//!
//! Layout (what we write, and what we read):
//! ```text
//! # bonnetlab surface map: heights in nm; rows = Y, columns = X; empty cell = invalid pixel
//! # dx_mm=0.1 dy_mm=0.1 x0_mm=0 y0_mm=0
//! 1.25,1.5,,2
//! ```
//! Lines starting with `#` are comments; `key=value` tokens in them set `dx_mm`, `dy_mm`,
//! `x0_mm`, `y0_mm` (other keys are ignored; an absent pixel size is unknown). An empty cell or
//! `NaN` is an invalid pixel; anything else must be a finite number. Every row has the same
//! number of cells. Heights are written in Rust's shortest round-trip form, so a CSV written
//! and read back is exact.

use std::io::Write;

use ndarray::Array2;

use bonnetlab_surface::{Provenance, Surface};

use crate::error::ParseError;

/// Does this look like a CSV grid? (the first data line is numeric cells, or our header).
pub fn looks_like(head: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(head) else {
        // The head may cut a multi-byte char; only ASCII grids are recognised anyway.
        return false;
    };
    for line in text.lines() {
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        if t.starts_with('#') {
            if t.contains("dx_mm=") || t.starts_with("# bonnetlab surface map") {
                return true;
            }
            continue;
        }
        return t.split(',').all(|c| {
            let c = c.trim();
            c.is_empty() || c.eq_ignore_ascii_case("nan") || c.parse::<f64>().is_ok()
        });
    }
    false
}

/// Reads a CSV grid.
pub fn parse(bytes: &[u8]) -> Result<Surface, ParseError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| ParseError::invalid(format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
    let (mut dx, mut dy, mut x0, mut y0) = (None, None, 0.0, 0.0);
    let mut heights = Vec::new();
    let mut valid = Vec::new();
    let mut cols = None;
    let mut rows = 0usize;
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        if let Some(c) = t.strip_prefix('#') {
            for tok in c.split(|ch: char| ch.is_whitespace() || ch == ',') {
                let Some((k, v)) = tok.split_once('=') else {
                    continue;
                };
                let slot = match k {
                    "dx_mm" => &mut dx,
                    "dy_mm" => &mut dy,
                    "x0_mm" | "y0_mm" => {
                        let val = num(v, line_no, k)?;
                        if k == "x0_mm" {
                            x0 = val;
                        } else {
                            y0 = val;
                        }
                        continue;
                    }
                    _ => continue,
                };
                let val = num(v, line_no, k)?;
                if val <= 0.0 {
                    return Err(ParseError::invalid(format!(
                        "line {line_no}: {k} = {v} must be positive"
                    )));
                }
                *slot = Some(val);
            }
            continue;
        }
        let mut n = 0usize;
        for (j, cell) in t.split(',').enumerate() {
            let c = cell.trim();
            if c.is_empty() || c.eq_ignore_ascii_case("nan") {
                heights.push(0.0);
                valid.push(false);
            } else {
                let v = c
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        ParseError::invalid(format!(
                            "line {line_no}, column {}: '{c}' is not a finite number",
                            j + 1
                        ))
                    })?;
                heights.push(v);
                valid.push(true);
            }
            n += 1;
        }
        match cols {
            None => cols = Some(n),
            Some(m) if m != n => {
                return Err(ParseError::invalid(format!(
                    "line {line_no} has {n} cells, the first row has {m}"
                )))
            }
            _ => {}
        }
        rows += 1;
    }
    let Some(cols) = cols else {
        return Err(ParseError::invalid("no data rows"));
    };
    if !valid.iter().any(|&v| v) {
        return Err(ParseError::NoValidPixel);
    }
    let h = Array2::from_shape_vec((rows, cols), heights)
        .map_err(|e| ParseError::invalid(e.to_string()))?;
    let v = Array2::from_shape_vec((rows, cols), valid)
        .map_err(|e| ParseError::invalid(e.to_string()))?;
    let mut s = Surface::with_mask(h, v, dx.or(dy), dy.or(dx))
        .map_err(|e| ParseError::invalid(e.to_string()))?;
    s.origin_mm = (x0, y0);
    s.provenance = Provenance {
        format: "csv".into(),
        ..Provenance::default()
    };
    Ok(s)
}

fn num(v: &str, line_no: usize, key: &str) -> Result<f64, ParseError> {
    v.parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| {
            ParseError::invalid(format!("line {line_no}: {key} = '{v}' is not a number"))
        })
}

/// Writes a surface as a CSV grid (see the module doc for the layout).
pub fn write(s: &Surface, w: &mut dyn Write) -> std::io::Result<()> {
    write_labelled(s, w, "surface map: heights in nm")
}

/// [`write`] for a grid of another quantity: `what` names it and its unit in the first
/// comment line (for example `dwell map: seconds per pixel`).
pub fn write_labelled(s: &Surface, w: &mut dyn Write, what: &str) -> std::io::Result<()> {
    writeln!(
        w,
        "# bonnetlab {what}; rows = Y, columns = X; empty cell = invalid pixel"
    )?;
    let mut meta = Vec::new();
    if let Some(dx) = s.dx_mm {
        meta.push(format!("dx_mm={dx}"));
    }
    if let Some(dy) = s.dy_mm {
        meta.push(format!("dy_mm={dy}"));
    }
    meta.push(format!("x0_mm={}", s.origin_mm.0));
    meta.push(format!("y0_mm={}", s.origin_mm.1));
    writeln!(w, "# {}", meta.join(" "))?;
    let mut line = String::new();
    for (hr, vr) in s.heights_nm().rows().into_iter().zip(s.valid().rows()) {
        line.clear();
        for (j, (&h, &v)) in hr.iter().zip(vr.iter()).enumerate() {
            if j > 0 {
                line.push(',');
            }
            if v {
                line.push_str(&h.to_string());
            }
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
    }
    Ok(())
}
