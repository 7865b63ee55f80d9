//! Format detection by content: magic numbers for the binary formats, the signature line for
//! the Zygo text exports. The extension only chooses the most helpful error when nothing matches
//! (a `.dat` with a wrong magic number is reported as exactly that).

use std::path::Path;

use crate::error::ParseError;
use crate::text::be_u32;
use crate::zygo_text::{ASC_SIGNATURE, XYZ_SIGNATURE};
use crate::{csv_grid, datx, exr_map, metropro_dat};

/// The map formats bonnetlab reads (and, for some, writes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MapFormat {
    /// MetroPro binary `.dat` (header formats 1, 2, 3).
    MetroProDat,
    /// Zygo ASCII export `.asc` (Format 2).
    MetroProAsc,
    /// Zygo XYZ export `.xyz` (Format 1).
    ZygoXyz,
    /// Mx `.datx` (HDF5).
    Datx,
    /// Plain CSV grid of heights in nm.
    Csv,
    /// OpenEXR float height map.
    Exr,
}

impl MapFormat {
    /// The tag used in `provenance.format` and the CLI's JSON.
    pub fn tag(self) -> &'static str {
        match self {
            MapFormat::MetroProDat => "metropro-dat",
            MapFormat::MetroProAsc => "metropro-asc",
            MapFormat::ZygoXyz => "zygo-xyz",
            MapFormat::Datx => "datx",
            MapFormat::Csv => "csv",
            MapFormat::Exr => "exr",
        }
    }

    /// The format an output file name asks for (for writers; readers detect by content).
    pub fn from_extension(path: &Path) -> Option<MapFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "dat" => Some(MapFormat::MetroProDat),
            "asc" => Some(MapFormat::MetroProAsc),
            "xyz" => Some(MapFormat::ZygoXyz),
            "datx" => Some(MapFormat::Datx),
            "csv" => Some(MapFormat::Csv),
            "exr" => Some(MapFormat::Exr),
            _ => None,
        }
    }
}

/// Detects the format of a file's bytes; `path` only refines the error message.
pub fn detect_format(bytes: &[u8], path: &Path) -> Result<MapFormat, ParseError> {
    if metropro_dat::has_magic(bytes) {
        return Ok(MapFormat::MetroProDat);
    }
    if datx::has_magic(bytes) {
        return Ok(MapFormat::Datx);
    }
    if exr_map::has_magic(bytes) {
        return Ok(MapFormat::Exr);
    }
    let head = &bytes[..bytes.len().min(256)];
    let head_text = String::from_utf8_lossy(head);
    let first = head_text.trim_start_matches('\u{feff}').trim_start();
    if first.starts_with(ASC_SIGNATURE) {
        return Ok(MapFormat::MetroProAsc);
    }
    if first.starts_with(XYZ_SIGNATURE) {
        return Ok(MapFormat::ZygoXyz);
    }
    if csv_grid::looks_like(&bytes[..bytes.len().min(4096)]) {
        return Ok(MapFormat::Csv);
    }
    if bytes.is_empty() {
        return Err(ParseError::invalid("the file is empty"));
    }
    match MapFormat::from_extension(path) {
        Some(MapFormat::MetroProDat) => {
            let magic = be_u32(bytes, 0)
                .map(|m| format!("{m:#010X}"))
                .unwrap_or_else(|| format!("{} bytes", bytes.len()));
            Err(ParseError::field(
                "magic_number",
                magic,
                "is not a MetroPro magic number (0x881B036F, 0x881B0370 or 0x881B0371)",
            ))
        }
        Some(MapFormat::MetroProAsc) => Err(ParseError::invalid(format!(
            "line 1 is not '{ASC_SIGNATURE} ...'"
        ))),
        Some(MapFormat::ZygoXyz) => Err(ParseError::invalid(format!(
            "line 1 is not '{XYZ_SIGNATURE} ...'"
        ))),
        Some(MapFormat::Datx) => Err(ParseError::invalid(
            "not an HDF5 file (no HDF5 signature at byte 0): not a .datx",
        )),
        Some(MapFormat::Exr) => Err(ParseError::invalid(
            "not an OpenEXR file (magic 76 2f 31 01 missing)",
        )),
        Some(MapFormat::Csv) => Err(ParseError::invalid(
            "not a CSV grid: the first data line is not comma-separated numbers",
        )),
        None => Err(ParseError::invalid(
            "unrecognised map format (not MetroPro .dat, Mx .datx, Zygo ASCII .asc or .xyz, EXR or a CSV grid)",
        )),
    }
}
