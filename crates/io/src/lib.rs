//! Reading and writing surface maps: every format a ZYGO NV7300 (MetroPro / Mx) exports, plus
//! CSV and EXR grids; and atomic output files (temporary file + rename).
//!
//! `read_surface` detects the format from the file's content (magic numbers, signature lines),
//! never from its extension alone, and returns a `Surface` in nm with its mask, pixel size in mm
//! (`None` when the file says 0) and provenance (`provenance.format` is the format tag of the
//! CLI contract). Errors name the file and the field; none of the readers panics or allocates
//! more than the file's size implies.

pub mod atomic;
pub mod csv_grid;
pub mod datx;
mod datx_bounds;
pub mod detect;
pub mod error;
pub mod exr_map;
pub mod input;
pub mod metropro_asc;
pub mod metropro_dat;
pub mod metropro_dat_write;
pub mod text;
pub mod zygo_meta;
pub mod zygo_text;
pub mod zygo_xyz;

use std::path::Path;

use bonnetlab_surface::Surface;

pub use detect::{detect_format, MapFormat};
pub use error::{IoError, ParseError};

/// Reads a surface map of any supported format, detected by content.
///
/// Only regular files of at most [`input::MAP_LIMIT`] bytes are read (a FIFO or a device is
/// refused before it is opened), and the format is detected from the first 4 KiB before the
/// rest is read, so a huge file with a wrong signature is refused at once.
pub fn read_surface(path: &Path) -> Result<Surface, IoError> {
    let (head, len) = input::read_head(path, input::MAP_LIMIT, DETECT_BYTES)
        .map_err(|e| IoError::read(path, e))?;
    let fmt = detect_format(&head, path).map_err(|e| IoError::parse(path, e))?;
    let bytes = if (head.len() as u64) < len {
        drop(head);
        input::read_bounded(path, input::MAP_LIMIT).map_err(|e| IoError::read(path, e))?
    } else {
        head
    };
    let mut s = parse_bytes(&bytes, fmt).map_err(|e| IoError::parse(path, e))?;
    s.provenance.source_path = Some(path.display().to_string());
    Ok(s)
}

/// How many leading bytes format detection looks at (it never reads further).
const DETECT_BYTES: usize = 4096;

/// Parses bytes already known to be in format `fmt`.
pub fn parse_bytes(bytes: &[u8], fmt: MapFormat) -> Result<Surface, ParseError> {
    match fmt {
        MapFormat::MetroProDat => metropro_dat::parse(bytes),
        MapFormat::MetroProAsc => metropro_asc::parse(bytes),
        MapFormat::Datx => datx::parse(bytes),
        MapFormat::ZygoXyz => zygo_xyz::parse(bytes),
        MapFormat::Csv => csv_grid::parse(bytes),
        MapFormat::Exr => exr_map::parse(bytes),
    }
}

/// Writes a surface atomically in `fmt` (MetroPro `.dat`, CSV or EXR).
pub fn write_surface(path: &Path, s: &Surface, fmt: MapFormat) -> Result<(), IoError> {
    let unrep = |what: String| IoError::Unrepresentable {
        file: path.display().to_string(),
        what,
    };
    let result = match fmt {
        MapFormat::MetroProDat => {
            let bytes = metropro_dat_write::encode(s).map_err(unrep)?;
            atomic::write_atomic(path, &bytes)
        }
        MapFormat::Exr => {
            let bytes = exr_map::encode(s).map_err(unrep)?;
            atomic::write_atomic(path, &bytes)
        }
        MapFormat::Csv => atomic::write_atomic_with(path, |w| csv_grid::write(s, w)),
        other => {
            return Err(IoError::Unsupported {
                file: path.display().to_string(),
                what: format!(
                    "writing {} is not supported (write .dat, .csv or .exr)",
                    other.tag()
                ),
            })
        }
    };
    result.map_err(|e| IoError::write(path, e))
}
