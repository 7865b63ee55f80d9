//! Write-then-read round trips (.dat, EXR, CSV) and a byte-level check of the .dat we write
//! against the offsets of spec zygo-formats.md §2.3, independent of our reader.

mod common;

use std::path::Path;

use bonnetlab_io::{read_surface, write_surface, MapFormat};
use bonnetlab_surface::{Provenance, Surface};
use ndarray::Array2;

/// A 37 x 53 map with a 300 nm piston, ripple, a masked disc and a NaN stripe.
fn synthetic() -> Surface {
    let (rows, cols) = (37, 53);
    let h = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let (x, y) = (j as f64, i as f64);
        if i == 5 {
            return f64::NAN;
        }
        300.0 + 12.5 * (x / 3.0).sin() - 0.37 * y + 1e-3 * (x * y)
    });
    let valid = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let (dx, dy) = (j as f64 - 30.0, i as f64 - 20.0);
        dx * dx + dy * dy > 25.0
    });
    let mut s = Surface::with_mask(h, valid, Some(0.05), Some(0.05)).unwrap();
    s.origin_mm = (0.5, 1.0);
    s.provenance = Provenance {
        format: "synthetic".into(),
        wavelength_m: Some(632.8e-9),
        objective: Some("Sm Aperture".into()),
        comment: Some("round trip".into()),
        ..Provenance::default()
    };
    s
}

/// nm per count of the .dat we write (phase_res 1, S 0.5, O 1, W as f32).
fn dat_count_nm(w_m: f64) -> f64 {
    f64::from(w_m as f32) * 0.5 / 32768.0 * 1e9
}

fn assert_same_grid(a: &Surface, b: &Surface) {
    assert_eq!(a.dim(), b.dim());
    assert_eq!(a.valid(), b.valid(), "masks differ");
}

fn max_abs_diff(a: &Surface, b: &Surface) -> f64 {
    a.heights_nm()
        .iter()
        .zip(b.heights_nm())
        .fold(0.0, |m, (x, y)| m.max((x - y).abs()))
}

#[test]
fn dat_round_trip_is_within_half_a_count() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.dat");
    let s = synthetic();
    write_surface(&p, &s, MapFormat::MetroProDat).unwrap();
    let r = read_surface(&p).unwrap();
    assert_eq!(r.provenance.format, "metropro-dat");
    assert_same_grid(&s, &r);
    let count = dat_count_nm(632.8e-9);
    let err = max_abs_diff(&s, &r);
    assert!(
        err <= 0.5 * count * (1.0 + 1e-9),
        "max error {err} nm > half a count {count}"
    );
    assert!(err > 0.0, "quantisation must show somewhere");
    assert!((r.dx_mm.unwrap() - 0.05).abs() < 1e-8);
    assert!((r.origin_mm.0 - 0.5).abs() < 1e-6 && (r.origin_mm.1 - 1.0).abs() < 1e-6);
    assert_eq!(r.provenance.objective.as_deref(), Some("Sm Aperture"));
    assert_eq!(r.provenance.comment.as_deref(), Some("round trip"));
    assert_eq!(
        r.provenance.software, None,
        "we do not claim to be Zygo software"
    );
    assert_eq!(r.provenance.wavelength_m, Some(f64::from(632.8e-9f32)));
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn real_dat_rewritten_reads_back_within_half_a_count() {
    let dir = common::real_dir();
    for f in [
        "prysm_valid_zygo_dat_file.dat",
        "pyxsurf_20191018_01c_flat01_difffiducials.dat",
    ] {
        let s = read_surface(&dir.join(f)).unwrap();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("copy.dat");
        write_surface(&p, &s, MapFormat::MetroProDat).unwrap();
        let r = read_surface(&p).unwrap();
        assert_same_grid(&s, &r);
        assert_eq!((r.dx_mm.is_some()), s.dx_mm.is_some(), "{f}");
        let count = dat_count_nm(s.provenance.wavelength_m.unwrap());
        assert!(max_abs_diff(&s, &r) <= 0.5 * count * (1.0 + 1e-9), "{f}");
    }
}

#[test]
fn dat_header_bytes_match_the_spec_offsets() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.dat");
    let s = synthetic();
    write_surface(&p, &s, MapFormat::MetroProDat).unwrap();
    let b = std::fs::read(&p).unwrap();
    let u16b = |o: usize| u16::from_be_bytes([b[o], b[o + 1]]);
    let i16b = |o: usize| i16::from_be_bytes([b[o], b[o + 1]]);
    let u32b = |o: usize| u32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let i32b = |o: usize| i32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let f32b = |o: usize| f32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let (rows, cols) = s.dim();
    assert_eq!(u32b(0), 0x881B_036F, "magic_number");
    assert_eq!(u16b(4), 1, "header_format");
    assert_eq!(u32b(6), 834, "header_size");
    assert_eq!(
        u16b(52) as usize * u16b(54) as usize * u16b(56) as usize,
        0,
        "no intensity"
    );
    assert_eq!(u32b(60), 0, "ac_n_bytes");
    assert_eq!((i16b(64), i16b(66)), (10, 20), "cn_org = origin / dx");
    assert_eq!(
        (u16b(68) as usize, u16b(70) as usize),
        (cols, rows),
        "cn_width, cn_height"
    );
    assert_eq!(u32b(72) as usize, 4 * rows * cols, "cn_n_bytes");
    assert_eq!(f32b(164), 0.5, "intf_scale_factor");
    assert_eq!(f32b(168), 632.8e-9f32, "wavelength_in");
    assert_eq!(f32b(176), 1.0, "obliquity_factor");
    assert_eq!(f32b(184), 0.05e-3f32, "lateral_res in m");
    assert_eq!(i16b(218), 1, "phase_res");
    assert_eq!(i16b(232), 0, "sign");
    assert_eq!(b.len(), 834 + 4 * rows * cols, "file size");
    // Phase block: raw * W * S * O / R = height, R = 32768; invalid = 2147483640.
    let nm_per_count = f64::from(f32b(168)) * 0.5 * 1.0 / 32768.0 * 1e9;
    for i in 0..rows {
        for j in 0..cols {
            let raw = i32b(834 + 4 * (i * cols + j));
            match s.get(i, j) {
                Some(h) => assert!((f64::from(raw) * nm_per_count - h).abs() <= 0.5 * nm_per_count),
                None => assert_eq!(raw, 2_147_483_640, "no-data marker at ({i}, {j})"),
            }
        }
    }
}

#[test]
fn tall_maps_fall_back_to_phase_res_0_and_absurd_ones_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("tall.dat");
    // 30 mm of height: beyond phase_res 1 (±20.7 mm at 632.8 nm), within phase_res 0.
    let s = Surface::new(
        Array2::from_shape_fn((4, 4), |(i, j)| (i * 4 + j) as f64 * 2e6),
        None,
        None,
    )
    .unwrap();
    write_surface(&p, &s, MapFormat::MetroProDat).unwrap();
    let b = std::fs::read(&p).unwrap();
    assert_eq!(i16::from_be_bytes([b[218], b[219]]), 0);
    let r = read_surface(&p).unwrap();
    let count = f64::from(632.8e-9f32) * 0.5 / 4096.0 * 1e9;
    assert!(max_abs_diff(&s, &r) <= 0.5 * count * (1.0 + 1e-9));
    assert_eq!((r.dx_mm, r.dy_mm), (None, None));

    let huge = Surface::new(Array2::from_elem((2, 2), 1e12), None, None).unwrap();
    let e = write_surface(&d.path().join("huge.dat"), &huge, MapFormat::MetroProDat).unwrap_err();
    assert_eq!(e.exit_code(), 1);
    assert!(e.to_string().contains("huge.dat"), "{e}");
    assert!(!d.path().join("huge.dat").exists());
}

#[test]
fn exr_round_trip_keeps_mask_metadata_and_f32_precision() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.exr");
    let s = synthetic();
    write_surface(&p, &s, MapFormat::Exr).unwrap();
    let r = read_surface(&p).unwrap();
    assert_eq!(r.provenance.format, "exr");
    assert_same_grid(&s, &r);
    // f32 relative to the stored offset (the mean): |h - mean| < 40 nm here.
    let err = max_abs_diff(&s, &r);
    assert!(err < 40.0 * f64::from(f32::EPSILON), "max error {err}");
    assert_eq!((r.dx_mm, r.dy_mm), (Some(0.05), Some(0.05)));
    assert_eq!(r.origin_mm, (0.5, 1.0));
    assert_eq!(r.provenance.wavelength_m, Some(632.8e-9));
    assert_eq!(r.provenance.comment.as_deref(), Some("round trip"));
}

#[test]
fn csv_round_trip_is_exact() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.csv");
    let s = synthetic();
    write_surface(&p, &s, MapFormat::Csv).unwrap();
    let r = read_surface(&p).unwrap();
    assert_eq!(r.provenance.format, "csv");
    assert_same_grid(&s, &r);
    assert_eq!(s.heights_nm(), r.heights_nm());
    assert_eq!(
        (r.dx_mm, r.dy_mm, r.origin_mm),
        (Some(0.05), Some(0.05), (0.5, 1.0))
    );
    // Unknown pixel size stays unknown.
    let u = Surface::new(Array2::from_elem((2, 3), 1.5), None, None).unwrap();
    write_surface(&p, &u, MapFormat::Csv).unwrap();
    let r = read_surface(&p).unwrap();
    assert_eq!((r.dx_mm, r.dy_mm), (None, None));
}

#[test]
fn format_is_detected_by_content_not_extension() {
    let d = tempfile::tempdir().unwrap();
    let s = synthetic();
    for (fmt, tag) in [
        (MapFormat::MetroProDat, "metropro-dat"),
        (MapFormat::Exr, "exr"),
        (MapFormat::Csv, "csv"),
    ] {
        let p = d.path().join("map.bin");
        write_surface(&p, &s, fmt).unwrap();
        assert_eq!(read_surface(&p).unwrap().provenance.format, tag);
    }
    assert_eq!(
        MapFormat::from_extension(Path::new("a/b.DAT")),
        Some(MapFormat::MetroProDat)
    );
    assert_eq!(MapFormat::from_extension(Path::new("a/b.txt")), None);
    let e = write_surface(&d.path().join("x.asc"), &s, MapFormat::MetroProAsc).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(
        e.to_string()
            .contains("writing metropro-asc is not supported"),
        "{e}"
    );
}
