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
    // A `.dat` parse finds its largest height as it converts the counts: within the limit, the
    // check's own pass over the map is not needed (it cost a 640 x 480 read 1.12-1.18x).
    if fmt == MapFormat::MetroProDat {
        let (s, peak) = metropro_dat::parse(bytes)?;
        if peak > HEIGHT_LIMIT_NM || peak.is_nan() {
            check_heights(&s)?;
        }
        return Ok(s);
    }
    let s = parse_format(bytes, fmt)?;
    check_heights(&s)?;
    Ok(s)
}

/// Largest height magnitude a map may hold, nm (1000 km). Beyond it a valid pixel is not a
/// surface height but a corrupt value, and sums of its squares (RMS, form fits, PSDs) would
/// overflow to a silent infinity or NaN: such a map is refused when read.
pub const HEIGHT_LIMIT_NM: f64 = 1e15;

fn check_heights(s: &Surface) -> Result<(), ParseError> {
    // One branch-free pass over the heights alone: a surface holds no non-finite height and
    // zero at every invalid pixel (`Surface::with_mask`), so a height beyond the limit is a
    // valid pixel's. The offending pixel is looked up only when there is one. Indexing every
    // pixel made reading a 640 x 480 `.dat` 2.0x slower than without the check; this pass is
    // about 7 % of that read's profile (reports/performance.md), and a `.dat` skips it when its
    // parse found every height within the limit.
    let over = |a: bool, z: &f64| a | (z.abs() > HEIGHT_LIMIT_NM);
    let all_fine = match s.heights_nm().as_slice() {
        Some(h) => !h.chunks(1024).any(|c| c.iter().fold(false, over)),
        None => !s.heights_nm().iter().fold(false, over),
    };
    if all_fine {
        return Ok(());
    }
    let bad = s
        .heights_nm()
        .indexed_iter()
        .zip(s.valid().iter())
        .find(|((_, z), &v)| v && (z.is_nan() || z.abs() > HEIGHT_LIMIT_NM));
    match bad {
        Some((((i, j), z), _)) => Err(ParseError::Invalid(format!(
            "height {} nm at row {}, column {} is beyond +/-{} nm: not a surface height",
            bonnetlab_surface::format::sig(*z, 4),
            i + 1,
            j + 1,
            bonnetlab_surface::format::sig(HEIGHT_LIMIT_NM, 1)
        ))),
        None => Ok(()),
    }
}

fn parse_format(bytes: &[u8], fmt: MapFormat) -> Result<Surface, ParseError> {
    match fmt {
        MapFormat::MetroProDat => metropro_dat::parse(bytes).map(|(s, _)| s),
        MapFormat::MetroProAsc => metropro_asc::parse(bytes),
        MapFormat::Datx => datx::parse(bytes),
        MapFormat::ZygoXyz => zygo_xyz::parse(bytes),
        MapFormat::Csv => csv_grid::parse(bytes),
        MapFormat::Exr => exr_map::parse(bytes),
    }
}

/// Encodes a surface in `fmt` (MetroPro `.dat`, CSV or EXR), for writing whole; the error
/// says why the map cannot be written in that format.
pub fn encode_surface(s: &Surface, fmt: MapFormat) -> Result<Vec<u8>, String> {
    match fmt {
        MapFormat::MetroProDat => metropro_dat_write::encode(s),
        MapFormat::Exr => exr_map::encode(s),
        MapFormat::Csv => {
            let mut buf = Vec::new();
            csv_grid::write(s, &mut buf).map_err(|e| e.to_string())?;
            Ok(buf)
        }
        other => Err(format!(
            "writing {} is not supported (write .dat, .csv or .exr)",
            other.tag()
        )),
    }
}

/// Writes a surface atomically in `fmt` (MetroPro `.dat`, CSV or EXR).
pub fn write_surface(path: &Path, s: &Surface, fmt: MapFormat) -> Result<(), IoError> {
    if matches!(fmt, MapFormat::Csv) {
        return atomic::write_atomic_with(path, |w| csv_grid::write(s, w))
            .map_err(|e| IoError::write(path, e));
    }
    let bytes = encode_surface(s, fmt).map_err(|what| match fmt {
        MapFormat::MetroProDat | MapFormat::Exr => IoError::Unrepresentable {
            file: path.display().to_string(),
            what,
        },
        _ => IoError::Unsupported {
            file: path.display().to_string(),
            what,
        },
    })?;
    atomic::write_atomic(path, &bytes).map_err(|e| IoError::write(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn heights_beyond_the_limit_are_refused_at_their_pixel_and_only_where_valid() {
        // 600 x 700: many 1024-pixel chunks, the bad pixel in a late one.
        let mut h = Array2::from_shape_fn((600, 700), |(i, j)| (i as f64 - j as f64) * 0.5);
        h[[412, 37]] = -2e15;
        let s = Surface::new(h.clone(), Some(0.1), Some(0.1)).unwrap();
        let e = check_heights(&s).unwrap_err().to_string();
        assert!(e.contains("row 413, column 38"), "{e}");
        // The same value on a masked pixel is no height at all: accepted.
        let mut valid = Array2::from_elem(h.dim(), true);
        valid[[412, 37]] = false;
        let s = Surface::with_mask(h.clone(), valid, Some(0.1), Some(0.1)).unwrap();
        assert!(check_heights(&s).is_ok());
        // At the limit itself: accepted.
        h[[412, 37]] = HEIGHT_LIMIT_NM;
        let s = Surface::new(h, Some(0.1), Some(0.1)).unwrap();
        assert!(check_heights(&s).is_ok());
    }

    /// A `.dat` read skips the check's pass when its parse found every height within the limit,
    /// and still refuses, naming the pixel, a map with one beyond it; the same map within the
    /// limit reads back as written.
    #[test]
    fn a_dat_beyond_the_height_limit_is_refused_at_its_pixel() {
        let mut h = Array2::from_shape_fn((30, 40), |(i, j)| (i as f64 - j as f64) * 1e13);
        h[[17, 23]] = 4e15;
        // Written at 632.8 nm (heights scaled down by 1e-9 to fit the counts), then the header's
        // wavelength (big-endian f32 at byte 168) corrupted to 632.8 m: the counts now read
        // 1e9 times higher, one pixel beyond the limit.
        let dat = |h: Array2<f64>| {
            let s = Surface::new(h.mapv(|z| z * 1e-9), Some(0.1), Some(0.1)).unwrap();
            let mut b = encode_surface(&s, MapFormat::MetroProDat).unwrap();
            b[168..172].copy_from_slice(&(632.8f32).to_be_bytes());
            b
        };
        let bytes = dat(h.clone());
        let e = parse_bytes(&bytes, MapFormat::MetroProDat)
            .unwrap_err()
            .to_string();
        assert!(e.contains("row 18, column 24"), "{e}");
        h[[17, 23]] = 1e14;
        let bytes = dat(h);
        let back = parse_bytes(&bytes, MapFormat::MetroProDat).unwrap();
        let (_, peak) = metropro_dat::parse(&bytes).unwrap();
        let max = back.heights_nm().iter().fold(0.0f64, |m, z| m.max(z.abs()));
        assert_eq!(peak, max);
        assert!(((back.heights_nm()[[17, 23]] - 1e14) / 1e14).abs() < 1e-4);
    }
}
