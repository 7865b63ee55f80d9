//! The committed bad-input corpus (tests/corpus, issue 8): each file, run through the built
//! binary, must give the manifest's exit code and a one-line error on stderr that names the
//! file and contains the manifest's substring (what is wrong), with nothing on stdout.
//!
//! Manifest `tests/corpus/manifest.tsv`: `file <TAB> command <TAB> exit code <TAB> substring
//! <TAB> comment`. The files are made by `generate_corpus` below from the real samples and our
//! own writer, so they are reproducible:
//! `cargo test --test reliability_corpus -- --ignored generate_corpus`.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "common/shared_data.rs"]
mod shared_data;

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

#[test]
fn every_corpus_file_fails_cleanly() {
    let manifest = std::fs::read_to_string(corpus_dir().join("manifest.tsv")).expect("manifest");
    let mut checked = 0;
    for (ln, line) in manifest.lines().enumerate() {
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split('\t').collect();
        assert!(f.len() >= 4, "manifest line {}: {line}", ln + 1);
        let (file, cmd, code, needle) = (f[0], f[1], f[2], f[3]);
        let code: i32 = code.parse().expect("exit code");
        let path = corpus_dir().join(file);
        assert!(path.exists(), "{file} is listed but missing");
        let mut args: Vec<String> = cmd.split_whitespace().map(String::from).collect();
        args.push(path.to_string_lossy().into_owned());
        if cmd.starts_with("stats") || cmd.starts_with("psd") {
            args.push("--json".into());
        }
        let out = Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{file} ({cmd}): {err}");
        assert!(out.stdout.is_empty(), "{file}: no output on failure");
        assert_eq!(err.trim_end().lines().count(), 1, "{file}: one line: {err}");
        assert!(
            err.contains(file),
            "{file}: the error names the file: {err}"
        );
        assert!(
            err.to_lowercase().contains(&needle.to_lowercase()),
            "{file}: expected '{needle}' in: {err}"
        );
        checked += 1;
    }
    assert!(checked >= 20, "only {checked} corpus entries");
}

fn real(name: &str) -> Vec<u8> {
    std::fs::read(shared_data::data_file("real", name)).expect("real sample")
}

fn put_u16(b: &mut [u8], off: usize, v: u16) {
    b[off..off + 2].copy_from_slice(&v.to_be_bytes());
}

fn put_u32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_be_bytes());
}

/// A small valid format-1 `.dat` (6 x 5, one invalid pixel) from our writer.
fn small_dat() -> Vec<u8> {
    let z = ndarray::Array2::from_shape_fn((6, 5), |(i, j)| {
        if (i, j) == (2, 3) {
            f64::NAN
        } else {
            (i * 5 + j) as f64 * 3.5 - 40.0
        }
    });
    let s = bonnetlab_surface::Surface::new(z, Some(0.1), Some(0.1)).unwrap();
    bonnetlab_io::metropro_dat_write::encode(&s).unwrap()
}

#[test]
#[ignore = "regenerates tests/corpus; run by hand after a deliberate change"]
fn generate_corpus() {
    let dir = corpus_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let w = |name: &str, b: &[u8]| std::fs::write(dir.join(name), b).unwrap();
    let dat = small_dat();
    let n = dat.len();
    w("empty.dat", b"");
    w(
        "renamed_text.dat",
        b"Surface map exported by another instrument\n1 2 3\n",
    );
    let mut b = dat.clone();
    b[3] = 0x00;
    w("wrong_magic.dat", &b);
    w("truncated_header.dat", &dat[..100]);
    w("truncated_phase.dat", &dat[..n - 10]);
    let mut b = dat.clone();
    put_u16(&mut b, 68, 7); // cn_width 5 -> 7 (cn_n_bytes and file size still say 5)
    w("width_mismatch.dat", &b);
    let mut b = dat.clone();
    put_u16(&mut b, 68, 60000);
    put_u16(&mut b, 70, 60000);
    put_u32(&mut b, 72, 60000u32.wrapping_mul(60000).wrapping_mul(4));
    w("huge_dims.dat", &b);
    let mut b = dat[..834].to_vec();
    put_u16(&mut b, 68, 0);
    put_u16(&mut b, 70, 0);
    put_u32(&mut b, 72, 0);
    w("zero_dims.dat", &b);
    let mut b = dat.clone();
    put_u16(&mut b, 218, 9);
    w("bad_phase_res.dat", &b);
    let mut b = dat.clone();
    put_u32(&mut b, 6, 4096);
    w("bad_header_size.dat", &b);
    let mut b = dat.clone();
    for c in b[834..].chunks_exact_mut(4) {
        c.copy_from_slice(&0x7FFF_FFF8u32.to_be_bytes());
    }
    w("no_valid_pixel.dat", &b);
    let mut b = dat.clone();
    put_u32(&mut b, 168, f32::NAN.to_bits()); // wavelength NaN
    w("nan_wavelength.dat", &b);
    // ASCII exports: the real PCO2 header with a 3 x 2 window.
    let asc = real("pyxsurf_171212_PCO2_Zygo_data.asc");
    let text = String::from_utf8_lossy(&asc);
    let header: Vec<&str> = text.lines().take(14).collect();
    let mut small = header.clone();
    small[2] = "0 0 0 0 0 0";
    small[3] = "0 0 3 2";
    let head = small.join("\n");
    w(
        "short_data.asc",
        format!("{head}\n#\n#\n1 2 3\n#\n").as_bytes(),
    );
    w(
        "non_numeric.asc",
        format!("{head}\n#\n#\n1 2 x3 4 5 6\n#\n").as_bytes(),
    );
    w(
        "header_only.asc",
        format!("{}\n", header[..6].join("\n")).as_bytes(),
    );
    let all_nodata = ["2147483640"; 6].join(" ");
    w(
        "no_valid_pixel.asc",
        format!("{head}\n#\n#\n{all_nodata}\n#\n").as_bytes(),
    );
    // .datx
    w(
        "not_hdf5.datx",
        b"\x89HDF\r\n\x1a\nthis is not really HDF5 at all, only its signature",
    );
    w("truncated.datx", &real("monolithic_zygo_test.datx")[..4096]);
    // CSV grids
    w("ragged.csv", b"# dx_mm=0.1 dy_mm=0.1\n1,2,3\n4,5\n");
    w(
        "non_numeric.csv",
        b"# dx_mm=0.1 dy_mm=0.1\n1,2,3\n4,five,6\n",
    );
    w("all_nan.csv", b"# dx_mm=0.1 dy_mm=0.1\nNaN,NaN\n,NaN\n");
    w("negative_dx.csv", b"# dx_mm=-0.1 dy_mm=0.1\n1,2\n3,4\n");
    // EXR: our own writer's output, cut short.
    let s = bonnetlab_surface::Surface::new(
        ndarray::Array2::from_shape_fn((8, 8), |(i, j)| (i + j) as f64),
        Some(0.1),
        Some(0.1),
    )
    .unwrap();
    let exr = bonnetlab_io::exr_map::encode(&s).unwrap();
    w("truncated.exr", &exr[..exr.len() / 2]);
    // Binary garbage with a map-like extension.
    let garbage: Vec<u8> = (0..512u32)
        .map(|k| (k.wrapping_mul(2654435761) >> 24) as u8)
        .collect();
    w("garbage.xyz", &garbage);
}
