//! The 14-line header shared by the Zygo ASCII (`.asc`, "Format 2") and XYZ (`.xyz`, "Format 1")
//! exports, and a line cursor over the file (spec zygo-formats.md §3.1).
//!
//! Lines are split on LF with an optional CR (Windows exports), tokens on whitespace with
//! `"quoted strings"` kept whole; numbers may carry Windows 3-digit exponents (`5.7e-007`).

use crate::error::ParseError;
use crate::text::{latin1, tokenize_quoted};
use crate::zygo_meta::ZygoMeta;

/// First-line signatures.
pub const ASC_SIGNATURE: &str = "Zygo ASCII Data File";
pub const XYZ_SIGNATURE: &str = "Zygo XYZ Data File";

/// Lines of a byte buffer with 1-based line numbers; CR before LF is dropped.
pub struct Lines<'a> {
    rest: &'a [u8],
    pub line_no: usize,
}

impl<'a> Lines<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Lines {
            rest: bytes,
            line_no: 0,
        }
    }

    /// Bytes not yet consumed.
    pub fn remaining(&self) -> usize {
        self.rest.len()
    }
}

impl<'a> Iterator for Lines<'a> {
    type Item = (usize, &'a [u8]);
    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        let (line, rest) = match self.rest.iter().position(|&b| b == b'\n') {
            Some(i) => (&self.rest[..i], &self.rest[i + 1..]),
            None => (self.rest, &[][..]),
        };
        self.rest = rest;
        self.line_no += 1;
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        Some((self.line_no, line))
    }
}

/// The parsed header.
#[derive(Debug, Clone, PartialEq)]
pub struct TextHeader {
    /// ac_org_x, ac_org_y, ac_width, ac_height, ac_n_buckets.
    pub ac: [i64; 5],
    /// cn_org_x, cn_org_y, cn_width, cn_height.
    pub cn: [i64; 4],
    pub meta: ZygoMeta,
}

impl TextHeader {
    pub fn cn_width(&self) -> usize {
        self.cn[2] as usize
    }
    pub fn cn_height(&self) -> usize {
        self.cn[3] as usize
    }
    /// Intensity values the header announces.
    pub fn intensity_count(&self) -> u64 {
        (self.ac[2] as u64) * (self.ac[3] as u64) * (self.ac[4] as u64)
    }
}

struct HeaderLine {
    line_no: usize,
    toks: Vec<String>,
}

impl HeaderLine {
    fn tok(&self, i: usize, name: &str) -> Result<&str, ParseError> {
        self.toks.get(i).map(String::as_str).ok_or_else(|| {
            ParseError::invalid(format!(
                "header line {}: field {name} (token {}) is missing",
                self.line_no,
                i + 1
            ))
        })
    }

    fn num(&self, i: usize, name: &str) -> Result<f64, ParseError> {
        let t = self.tok(i, name)?;
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                ParseError::invalid(format!(
                    "header line {}: field {name} = '{t}' is not a number",
                    self.line_no
                ))
            })
    }

    fn int(&self, i: usize, name: &str) -> Result<i64, ParseError> {
        let t = self.tok(i, name)?;
        t.parse::<i64>().map_err(|_| {
            ParseError::invalid(format!(
                "header line {}: field {name} = '{t}' is not an integer",
                self.line_no
            ))
        })
    }

    /// A non-negative dimension below 65536 (the binary header holds them in u16).
    fn dim(&self, i: usize, name: &str) -> Result<i64, ParseError> {
        let v = self.int(i, name)?;
        if !(0..=65535).contains(&v) {
            return Err(ParseError::invalid(format!(
                "header line {}: field {name} = {v} is outside 0..65535",
                self.line_no
            )));
        }
        Ok(v)
    }

    /// Optional text token (missing -> empty).
    fn text(&self, i: usize) -> String {
        self.toks.get(i).cloned().unwrap_or_default()
    }
}

/// Reads the signature line, the 14-line header and the `#` that closes it.
pub fn parse_header(lines: &mut Lines<'_>, signature: &str) -> Result<TextHeader, ParseError> {
    let mut hl = Vec::with_capacity(14);
    for k in 0..14 {
        let Some((line_no, raw)) = lines.next() else {
            return Err(ParseError::invalid(format!(
                "truncated: the header ends after {k} of 14 lines"
            )));
        };
        let text = latin1(raw);
        if k == 0 {
            if !text.trim_start().starts_with(signature) {
                return Err(ParseError::invalid(format!(
                    "line 1 is not '{signature} ...'"
                )));
            }
            continue;
        }
        hl.push(HeaderLine {
            line_no,
            toks: tokenize_quoted(&text),
        });
    }
    match lines.next() {
        Some((_, l)) if l.trim_ascii() == b"#" => {}
        Some((n, _)) => {
            return Err(ParseError::invalid(format!(
                "line {n}: expected '#' closing the 14-line header"
            )))
        }
        None => return Err(ParseError::invalid("truncated: no data after the header")),
    }
    // hl[k] is header line k + 2.
    let [l2, l3, l4, l5, l6, l7, l8, l9, _l10, l11, _l12, _l13, l14] = &hl[..] else {
        return Err(ParseError::invalid("header has the wrong number of lines"));
    };
    let ac = [
        l3.int(0, "ac_org_x")?,
        l3.int(1, "ac_org_y")?,
        l3.dim(2, "ac_width")?,
        l3.dim(3, "ac_height")?,
        l3.dim(4, "ac_n_buckets")?,
    ];
    let cn = [
        l4.int(0, "cn_org_x")?,
        l4.int(1, "cn_org_y")?,
        l4.dim(2, "cn_width")?,
        l4.dim(3, "cn_height")?,
    ];
    for (v, name) in [(cn[2], "cn_width"), (cn[3], "cn_height")] {
        if v == 0 {
            return Err(ParseError::invalid(format!(
                "header line 4: field {name} = 0: the phase map is empty"
            )));
        }
    }
    let clamp_i32 = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
    let meta = ZygoMeta {
        swinfo_type: clamp_i32(l2.int(0, "swinfo_type")?),
        version: (
            clamp_i32(l2.int(1, "swinfo_vers_maj")?),
            clamp_i32(l2.int(2, "swinfo_vers_min")?),
            clamp_i32(l2.int(3, "swinfo_vers_bug")?),
        ),
        swinfo_date: l2.text(4),
        comment: l5.text(0),
        part_ser_num: l6.text(0),
        part_name: l7.text(0),
        intf_scale_factor: l8.num(1, "intf_scale_factor")?,
        wavelength_m: l8.num(2, "wavelength_in")?,
        obliquity_factor: l8.num(4, "obliquity_factor")?,
        lateral_res_m: l8.num(6, "camera_res")?,
        time_stamp: l8.int(7, "time_stamp").unwrap_or(0),
        sys_type: clamp_i32(l9.int(2, "sys_type")?),
        serial: l9.int(4, "sys_serial")?,
        obj_name: l9.text(6),
        phase_res: clamp_i32(l11.int(0, "phase_res")?),
        sign: clamp_i32(l11.int(7, "sign")?),
        zoom_descr: l14.text(0),
        cn_org: (clamp_i32(cn[0]), clamp_i32(cn[1])),
    };
    Ok(TextHeader { ac, cn, meta })
}
