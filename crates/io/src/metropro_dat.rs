//! MetroPro binary `.dat` reader, header formats 1, 2 and 3 (spec zygo-formats.md §2).
//!
//! The header is mostly big-endian (`sys_serial2` at 798 is little-endian); the intensity block
//! (u16 BE, skipped here) and the phase block (i32 BE, row-major, top row first) follow it. The
//! sizes the header declares are checked against each other and against the bytes present
//! before anything is allocated, so a corrupt header cannot make us allocate gigabytes.

use ndarray::Array2;

use bonnetlab_surface::Surface;

use crate::error::ParseError;
use crate::text::{be_f32, be_i16, be_i32, be_u16, be_u32, latin1_field, le_i32};
use crate::zygo_meta::{ZygoMeta, NO_DATA_MIN};

/// The accepted (magic, header_format, header_size) triples.
pub const MAGICS: [(u32, u16, u32); 3] = [
    (0x881B_036F, 1, 834),
    (0x881B_0370, 2, 834),
    (0x881B_0371, 3, 4096),
];

/// True when the bytes start with one of the MetroPro magic numbers.
pub fn has_magic(bytes: &[u8]) -> bool {
    be_u32(bytes, 0).is_some_and(|m| MAGICS.iter().any(|t| t.0 == m))
}

/// The structural fields of a `.dat` header (the rest goes into `ZygoMeta`).
#[derive(Debug, Clone, PartialEq)]
pub struct DatHeader {
    pub header_format: u16,
    pub header_size: u32,
    pub ac_width: u16,
    pub ac_height: u16,
    pub ac_n_buckets: u16,
    pub ac_n_bytes: u32,
    pub cn_width: u16,
    pub cn_height: u16,
    pub cn_n_bytes: u32,
    pub meta: ZygoMeta,
}

/// Parses and cross-checks the header against the file length.
pub fn parse_header(bytes: &[u8]) -> Result<DatHeader, ParseError> {
    let short = || {
        ParseError::invalid(format!(
            "truncated: {} bytes, shorter than a MetroPro header (834 bytes)",
            bytes.len()
        ))
    };
    let magic = be_u32(bytes, 0).ok_or_else(short)?;
    let Some(&(_, want_format, want_size)) = MAGICS.iter().find(|t| t.0 == magic) else {
        return Err(ParseError::field(
            "magic_number",
            format!("{magic:#010X}"),
            "is not a MetroPro magic number (0x881B036F, 0x881B0370 or 0x881B0371)",
        ));
    };
    let header_format = be_u16(bytes, 4).ok_or_else(short)?;
    let header_size = be_u32(bytes, 6).ok_or_else(short)?;
    if header_format != want_format {
        return Err(ParseError::field(
            "header_format",
            header_format,
            format!("does not match magic number {magic:#010X} (expects {want_format})"),
        ));
    }
    if header_size != want_size {
        return Err(ParseError::field(
            "header_size",
            header_size,
            format!("is not {want_size} for header format {header_format}"),
        ));
    }
    if bytes.len() < header_size as usize {
        return Err(ParseError::invalid(format!(
            "truncated: {} bytes, shorter than its {header_size}-byte header",
            bytes.len()
        )));
    }
    // From here every fixed offset below 834 is inside the slice.
    let h = &bytes[..header_size as usize];
    let i16f = |off| i32::from(be_i16(h, off).unwrap_or(0));
    let f32f = |off| f64::from(be_f32(h, off).unwrap_or(0.0));
    let text = |off: usize, len: usize| latin1_field(h.get(off..off + len).unwrap_or(&[]));

    let sys_serial2 = le_i32(h, 798).unwrap_or(0);
    let sys_serial16 = be_u16(h, 242).unwrap_or(0);
    let meta = ZygoMeta {
        swinfo_type: i16f(10),
        version: (i16f(42), i16f(44), i16f(46)),
        swinfo_date: text(12, 30),
        time_stamp: i64::from(be_i32(h, 76).unwrap_or(0)),
        comment: text(80, 82),
        part_name: text(258, 40),
        part_ser_num: text(320, 40),
        intf_scale_factor: f32f(164),
        wavelength_m: f32f(168),
        obliquity_factor: f32f(176),
        lateral_res_m: f32f(184),
        phase_res: i16f(218),
        sign: i16f(232),
        sys_type: i16f(238),
        // sys_serial2 (i32 LE @798) holds the full serial; the i16 @242 is its low 16 bits.
        serial: if sys_serial2 != 0 {
            i64::from(sys_serial2)
        } else {
            i64::from(sys_serial16)
        },
        obj_name: text(246, 12),
        zoom_descr: text(562, 8),
        cn_org: (i16f(64), i16f(66)),
    };
    let hdr = DatHeader {
        header_format,
        header_size,
        ac_width: be_u16(h, 52).unwrap_or(0),
        ac_height: be_u16(h, 54).unwrap_or(0),
        ac_n_buckets: be_u16(h, 56).unwrap_or(0),
        ac_n_bytes: be_u32(h, 60).unwrap_or(0),
        cn_width: be_u16(h, 68).unwrap_or(0),
        cn_height: be_u16(h, 70).unwrap_or(0),
        cn_n_bytes: be_u32(h, 72).unwrap_or(0),
        meta,
    };
    hdr.check_sizes(bytes.len() as u64)?;
    Ok(hdr)
}

impl DatHeader {
    /// Intensity bytes the dimensions imply (u64: 60000 x 60000 must not overflow).
    fn intensity_bytes(&self) -> u64 {
        2 * u64::from(self.ac_width) * u64::from(self.ac_height) * u64::from(self.ac_n_buckets)
    }

    fn phase_bytes(&self) -> u64 {
        4 * u64::from(self.cn_width) * u64::from(self.cn_height)
    }

    fn check_sizes(&self, file_len: u64) -> Result<(), ParseError> {
        if self.cn_width == 0 || self.cn_height == 0 {
            let (f, v) = if self.cn_width == 0 {
                ("cn_width", self.cn_width)
            } else {
                ("cn_height", self.cn_height)
            };
            return Err(ParseError::field(f, v, "is zero: the phase map is empty"));
        }
        if u64::from(self.ac_n_bytes) != self.intensity_bytes() {
            return Err(ParseError::field(
                "ac_n_bytes",
                self.ac_n_bytes,
                format!(
                    "disagrees with 2 x ac_width {} x ac_height {} x ac_n_buckets {} = {}",
                    self.ac_width,
                    self.ac_height,
                    self.ac_n_buckets,
                    self.intensity_bytes()
                ),
            ));
        }
        if u64::from(self.cn_n_bytes) != self.phase_bytes() {
            return Err(ParseError::field(
                "cn_n_bytes",
                self.cn_n_bytes,
                format!(
                    "disagrees with 4 x cn_width {} x cn_height {} = {}",
                    self.cn_width,
                    self.cn_height,
                    self.phase_bytes()
                ),
            ));
        }
        let want = u64::from(self.header_size) + self.intensity_bytes() + self.phase_bytes();
        if want != file_len {
            let how = if file_len < want {
                "truncated"
            } else {
                "trailing bytes"
            };
            return Err(ParseError::invalid(format!(
                "{how}: file size {file_len} bytes, the header (cn_width {} x cn_height {}, \
                 ac_n_bytes {}) implies {want}",
                self.cn_width, self.cn_height, self.ac_n_bytes
            )));
        }
        Ok(())
    }
}

/// Reads a `.dat` map from its bytes, and the largest height magnitude (nm) of its valid pixels
/// (0 when none), found in the same pass: the read's height check then needs no pass of its
/// own.
pub fn parse(bytes: &[u8]) -> Result<(Surface, f64), ParseError> {
    let hdr = parse_header(bytes)?;
    let scale = hdr.meta.nm_per_count()?;
    let pixel_mm = hdr.meta.pixel_mm()?;
    let start = hdr.header_size as usize + hdr.ac_n_bytes as usize;
    let (rows, cols) = (usize::from(hdr.cn_height), usize::from(hdr.cn_width));
    // check_sizes proved start + 4 * rows * cols == bytes.len().
    let phase = bytes
        .get(start..)
        .ok_or_else(|| ParseError::invalid("phase block missing"))?;
    // Zeroed buffers filled in place: one pass, no capacity checks (this loop is the read time
    // of a 4096 x 4096 map).
    let mut heights = vec![0.0f64; rows * cols];
    let mut valid = vec![false; rows * cols];
    // |raw * scale| = |raw| |scale| exactly, and rounding is monotonic: the largest |height| is
    // the largest |raw| times |scale|.
    let mut peak_raw = 0u32;
    for ((c, h), v) in phase
        .chunks_exact(4)
        .zip(heights.iter_mut())
        .zip(valid.iter_mut())
    {
        let raw = i32::from_be_bytes([c[0], c[1], c[2], c[3]]);
        if raw < NO_DATA_MIN {
            *v = true;
            *h = f64::from(raw) * scale;
            peak_raw = peak_raw.max(raw.unsigned_abs());
        }
    }
    let s = build_surface(
        heights,
        valid,
        (rows, cols),
        &hdr.meta,
        pixel_mm,
        "metropro-dat",
    )?;
    Ok((s, f64::from(peak_raw) * scale.abs()))
}

/// Assembles a surface from row-major heights and mask; fails with `NoValidPixel` when empty.
pub(crate) fn build_surface(
    heights: Vec<f64>,
    valid: Vec<bool>,
    (rows, cols): (usize, usize),
    meta: &ZygoMeta,
    pixel_mm: Option<f64>,
    format: &str,
) -> Result<Surface, ParseError> {
    if !valid.iter().any(|&v| v) {
        return Err(ParseError::NoValidPixel);
    }
    let h = Array2::from_shape_vec((rows, cols), heights)
        .map_err(|e| ParseError::invalid(format!("phase block shape: {e}")))?;
    let v = Array2::from_shape_vec((rows, cols), valid)
        .map_err(|e| ParseError::invalid(format!("phase block shape: {e}")))?;
    let mut s = Surface::with_mask(h, v, pixel_mm, pixel_mm)
        .map_err(|e| ParseError::invalid(e.to_string()))?;
    s.origin_mm = meta.origin_mm(pixel_mm);
    s.provenance = meta.provenance(format);
    Ok(s)
}
