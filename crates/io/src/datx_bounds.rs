//! Size bounds for `.datx` reads: how much memory a file of a given size may make the reader
//! allocate, checked on the dataspace *before* `hdf5-reader` allocates anything.
//!
//! A dataspace's extent is just a number in the file, so a mutated 130 KB file can declare
//! millions of link-table rows (the missing chunks read as fill values) or a 2^40-element
//! surface. The checks here tie every read to bytes the file actually holds:
//! - data not stored in chunks (contiguous or compact) must be present in the file, so its
//!   decoded size is at most the file size;
//! - chunked data may be compressed, so its decoded size is at most [`MAX_DECODE_RATIO`] times
//!   the file size;
//! - whatever the layout, a surface has at most [`MAX_SURFACE_PIXELS`] pixels and the
//!   `/MetaData` link table at most [`MAX_LINK_ROWS`] records of at most
//!   [`MAX_LINK_RECORD_BYTES`] bytes, whose records must also fit in the file.
//!
//! The same limits are handed to `hdf5-reader` ([`open_options`]) as a second line of defence:
//! it then refuses larger reads and decoded chunks before allocating them.

use hdf5_reader::{Dataset, OpenOptions};

use crate::error::ParseError;

/// Largest surface accepted, in pixels (8192 x 8192, four times the largest Zygo camera).
pub const MAX_SURFACE_PIXELS: u64 = 1 << 26;

/// Largest decoded-to-file size ratio accepted for chunked (possibly compressed) data. Surface
/// heights are noisy floats that deflate compresses by a small factor; 64 leaves room for maps
/// that are mostly `No Data` while stopping a small file from declaring gigabytes.
pub const MAX_DECODE_RATIO: u64 = 64;

/// Most records accepted in the `/MetaData` link table (real files have about ten).
pub const MAX_LINK_ROWS: u64 = 65_536;

/// Largest `/MetaData` record accepted, in bytes (real records are three 16-byte references).
pub const MAX_LINK_RECORD_BYTES: u64 = 4096;

/// Largest decoded read one dataset may make for a file of `file_bytes` bytes.
pub fn read_budget_bytes(file_bytes: usize) -> u64 {
    (file_bytes as u64)
        .saturating_mul(MAX_DECODE_RATIO)
        .min(MAX_SURFACE_PIXELS * 8)
}

/// `hdf5-reader` options for a file of `file_bytes` bytes: reads and decoded chunks limited to
/// [`read_budget_bytes`], and no chunk cache (every chunk is read once, and a cache would only
/// add to the peak).
pub fn open_options(file_bytes: usize) -> OpenOptions {
    let budget = usize::try_from(read_budget_bytes(file_bytes)).unwrap_or(usize::MAX);
    OpenOptions::default()
        .with_max_read_bytes(budget)
        .with_max_chunk_bytes(budget.min(hdf5_reader::DEFAULT_MAX_CHUNK_BYTES))
        .with_chunk_cache_bytes(0)
}

/// Checks that reading all of `ds` (`what` names it in the error) decodes no more than the
/// file of `file_bytes` bytes implies; returns the element count and element size.
pub fn check_dataset_size(
    ds: &Dataset,
    what: &str,
    file_bytes: usize,
) -> Result<(u64, u64), ParseError> {
    let elements = ds
        .shape()
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| {
            ParseError::invalid(format!(
                "{what} has dimensions {:?} whose product overflows",
                ds.shape()
            ))
        })?;
    let elem_bytes =
        ds.raw_element_size()
            .map_err(|e| ParseError::invalid(format!("{what} element size: {e}")))? as u64;
    check_decoded_size(
        what,
        elements,
        elem_bytes,
        ds.chunks().is_some(),
        file_bytes as u64,
    )?;
    Ok((elements, elem_bytes))
}

/// The layout rule of the module doc on plain numbers (kept separate so it is testable without
/// building HDF5 files).
pub fn check_decoded_size(
    what: &str,
    elements: u64,
    elem_bytes: u64,
    chunked: bool,
    file_bytes: u64,
) -> Result<(), ParseError> {
    let decoded = elements.checked_mul(elem_bytes).ok_or_else(|| {
        ParseError::invalid(format!(
            "{what} declares {elements} elements of {elem_bytes} bytes, which overflows"
        ))
    })?;
    let (limit, why) = if chunked {
        (
            file_bytes.saturating_mul(MAX_DECODE_RATIO),
            format!("{MAX_DECODE_RATIO} x the file size of {file_bytes} bytes"),
        )
    } else {
        (
            file_bytes,
            format!("the file size of {file_bytes} bytes (it is not chunked)"),
        )
    };
    if decoded > limit {
        return Err(ParseError::invalid(format!(
            "{what} declares {elements} elements of {elem_bytes} bytes ({decoded} bytes), more \
             than {why}"
        )));
    }
    Ok(())
}

/// The pixel cap on a `rows x cols` surface.
pub fn check_surface_pixels(what: &str, rows: u64, cols: u64) -> Result<(), ParseError> {
    match rows.checked_mul(cols) {
        Some(n) if n <= MAX_SURFACE_PIXELS => Ok(()),
        _ => Err(ParseError::invalid(format!(
            "{what} is {rows} x {cols} pixels, more than the {MAX_SURFACE_PIXELS} pixel limit"
        ))),
    }
}

/// The `/MetaData` record caps: count, record size, and records present in the file.
pub fn check_link_table(rows: u64, record_bytes: u64, file_bytes: u64) -> Result<(), ParseError> {
    if rows > MAX_LINK_ROWS {
        return Err(ParseError::invalid(format!(
            "/MetaData declares {rows} records, more than the {MAX_LINK_ROWS} record limit"
        )));
    }
    if record_bytes == 0 || record_bytes > MAX_LINK_RECORD_BYTES {
        return Err(ParseError::invalid(format!(
            "/MetaData record size {record_bytes} bytes is not in 1..={MAX_LINK_RECORD_BYTES}"
        )));
    }
    // Each record references three strings stored elsewhere in the file, so even compressed
    // the records cannot outweigh the file.
    if rows * record_bytes > file_bytes {
        return Err(ParseError::invalid(format!(
            "/MetaData declares {rows} records of {record_bytes} bytes, more than the file size \
             of {file_bytes} bytes"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contiguous_data_must_fit_in_the_file() {
        // 259 x 33 f64 = 68 376 bytes: fits a 131 672-byte file, not a 60 000-byte one.
        assert!(check_decoded_size("s", 259 * 33, 8, false, 131_672).is_ok());
        let e = check_decoded_size("s", 259 * 33, 8, false, 60_000).unwrap_err();
        assert!(e.to_string().contains("68376 bytes"), "{e}");
        // Exactly the file size is allowed; one byte more is not.
        assert!(check_decoded_size("s", 1000, 8, false, 8000).is_ok());
        assert!(check_decoded_size("s", 1001, 8, false, 8000).is_err());
    }

    #[test]
    fn chunked_data_may_decode_to_the_ratio_times_the_file() {
        let f = 10_000u64;
        let max_elems = f * MAX_DECODE_RATIO / 8;
        assert!(check_decoded_size("s", max_elems, 8, true, f).is_ok());
        assert!(check_decoded_size("s", max_elems + 1, 8, true, f).is_err());
        let e = check_decoded_size("s", u64::MAX / 4, 8, true, f).unwrap_err();
        assert!(e.to_string().contains("overflows"), "{e}");
    }

    #[test]
    fn pixel_cap_and_overflow() {
        assert!(check_surface_pixels("s", 8192, 8192).is_ok());
        assert!(check_surface_pixels("s", 8192, 8193).is_err());
        assert!(check_surface_pixels("s", u64::MAX, 2).is_err());
    }

    #[test]
    fn link_table_caps() {
        assert!(check_link_table(10, 48, 131_672).is_ok());
        // The fuzz findings: 2 097 162 rows; 10 rows of 86 555 736 bytes.
        assert!(check_link_table(2_097_162, 48, 131_672).is_err());
        assert!(check_link_table(10, 86_555_736, 127_913).is_err());
        assert!(check_link_table(2000, 48, 90_000).is_err());
        assert!(check_link_table(10, 0, 131_672).is_err());
    }

    #[test]
    fn budget_is_ratio_times_file_capped_by_the_largest_surface() {
        assert_eq!(read_budget_bytes(1000), 1000 * MAX_DECODE_RATIO);
        assert_eq!(read_budget_bytes(usize::MAX), MAX_SURFACE_PIXELS * 8);
    }
}
