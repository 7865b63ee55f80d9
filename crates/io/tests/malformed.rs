//! Malformed inputs, each built from a real file: a clean one-line error naming the file and
//! the field, with exit code 2 (bad input) or 1 (valid but unusable), never a panic.

mod common;

use std::path::{Path, PathBuf};

use bonnetlab_io::{read_surface, IoError};

fn real(name: &str) -> Vec<u8> {
    std::fs::read(common::real_dir().join(name)).unwrap()
}

/// Writes `bytes` as `name` in a temp dir and expects `read_surface` to fail.
fn fail(name: &str, bytes: &[u8]) -> (IoError, tempfile::TempDir, PathBuf) {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    let e = match read_surface(&p) {
        Ok(s) => panic!("{name}: read a {:?} map from malformed input", s.dim()),
        Err(e) => e,
    };
    (e, d, p)
}

/// The error names the file, contains `needle`, is one line and has exit code `code`.
fn expect(name: &str, bytes: &[u8], needle: &str, code: i32) -> String {
    let (e, _d, p) = fail(name, bytes);
    let msg = e.to_string();
    assert!(
        msg.starts_with(&p.display().to_string()),
        "no file name: {msg}"
    );
    assert!(msg.contains(needle), "'{needle}' not in: {msg}");
    assert!(!msg.contains('\n'), "multi-line: {msg}");
    assert_eq!(e.exit_code(), code, "{msg}");
    msg
}

fn set_u16(b: &mut [u8], off: usize, v: u16) {
    b[off..off + 2].copy_from_slice(&v.to_be_bytes());
}
fn set_u32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_be_bytes());
}

const DAT: &str = "surfalize_test_1.dat";
const DAT3: &str = "pyxsurf_03_flat04_differenceFiducials_nofid_verovero.dat";

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn truncated_dat() {
    let b = real(DAT);
    expect(
        "t.dat",
        &b[..b.len() - 1],
        "truncated: file size 1844033 bytes",
        2,
    );
    expect("t.dat", &b[..1000], "truncated", 2);
    expect("t.dat", &b[..100], "shorter than its 834-byte header", 2);
    expect("t.dat", &b[..7], "truncated", 2);
    let mut long = b.clone();
    long.push(0);
    expect("t.dat", &long, "trailing bytes", 2);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn wrong_magic_and_inconsistent_triple() {
    let mut b = real(DAT);
    b[3] = 0x7F;
    expect(
        "m.dat",
        &b,
        "header field magic_number = 0x881B037F is not a MetroPro magic",
        2,
    );
    // A .dat-named file with other content is reported as a bad magic number too.
    expect(
        "m.dat",
        b"hello world, not a map",
        "header field magic_number",
        2,
    );
    let mut b = real(DAT);
    set_u16(&mut b, 4, 3);
    expect(
        "f.dat",
        &b,
        "header field header_format = 3 does not match",
        2,
    );
    let mut b = real(DAT3);
    set_u32(&mut b, 6, 834);
    expect(
        "f3.dat",
        &b,
        "header field header_size = 834 is not 4096",
        2,
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn dimensions_disagreeing_with_the_file_size() {
    let mut b = real(DAT);
    set_u16(&mut b, 68, 641);
    expect(
        "d.dat",
        &b,
        "header field cn_n_bytes = 1228800 disagrees with 4 x cn_width 641",
        2,
    );
    // Consistent header, wrong file size.
    set_u32(&mut b, 72, 4 * 641 * 480);
    expect(
        "d.dat",
        &b,
        "truncated: file size 1844034 bytes, the header (cn_width 641",
        2,
    );
    let mut b = real(DAT);
    set_u16(&mut b, 52, 700);
    expect("d.dat", &b, "header field ac_n_bytes", 2);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn huge_and_zero_dimensions_never_allocate() {
    let mut b = real(DAT);
    // 60000 x 60000 would be 14.4 GB of i32: must be refused from the header alone.
    set_u16(&mut b, 68, 60000);
    set_u16(&mut b, 70, 60000);
    expect("h.dat", &b, "header field cn_n_bytes", 2);
    set_u32(&mut b, 72, (4u64 * 60000 * 60000 % (1u64 << 32)) as u32);
    expect(
        "h.dat",
        &b,
        "disagrees with 4 x cn_width 60000 x cn_height 60000 = 14400000000",
        2,
    );
    let mut b = real(DAT);
    set_u16(&mut b, 52, 65535);
    set_u16(&mut b, 54, 65535);
    set_u16(&mut b, 56, 65535);
    set_u32(&mut b, 60, u32::MAX);
    expect("h.dat", &b, "header field ac_n_bytes", 2);
    let mut b = real(DAT);
    set_u16(&mut b, 68, 0);
    expect("z.dat", &b, "header field cn_width = 0 is zero", 2);
    let mut b = real(DAT);
    set_u16(&mut b, 70, 0);
    set_u32(&mut b, 72, 0);
    expect("z.dat", &b, "header field cn_height = 0 is zero", 2);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn unknown_phase_res_and_bad_scale_fields() {
    let mut b = real(DAT);
    set_u16(&mut b, 218, 7);
    let msg = expect("p.dat", &b, "", 2);
    assert!(
        msg.ends_with("p.dat: header field phase_res = 7 is not 0, 1 or 2"),
        "{msg}"
    );
    let mut b = real(DAT);
    set_u32(&mut b, 168, 0f32.to_bits());
    expect(
        "w.dat",
        &b,
        "header field wavelength_in = 0 must be positive",
        2,
    );
    let mut b = real(DAT);
    set_u32(&mut b, 184, (-1.0f32).to_bits());
    expect("l.dat", &b, "header field lateral_res = -1", 2);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn no_valid_pixel_is_exit_code_1() {
    let mut b = real(DAT);
    let start = b.len() - 4 * 640 * 480;
    for c in b[start..].chunks_exact_mut(4) {
        c.copy_from_slice(&2_147_483_640i32.to_be_bytes());
    }
    expect("empty.dat", &b, "no valid pixel", 1);
    expect(
        "empty.csv",
        b"# dx_mm=0.1\n,,\nNaN,,nan\n",
        "no valid pixel",
        1,
    );
}

fn asc_text() -> String {
    String::from_utf8(real("pyxsurf_171212_PCO2_Zygo_data.asc")).unwrap()
}

/// Replaces line `n` (1-based) of `text`.
fn with_line(text: &str, n: usize, new: &str) -> String {
    text.lines()
        .enumerate()
        .map(|(i, l)| if i + 1 == n { new } else { l })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn non_numeric_and_short_ascii() {
    let t = asc_text();
    // The first phase line follows the intensity block; corrupt a token deep in the phase block.
    let lines: Vec<&str> = t.lines().collect();
    let n = lines.len() - 3;
    let bad = with_line(&t, n, &lines[n - 1].replacen(' ', "x ", 1));
    expect(
        "n.asc",
        bad.as_bytes(),
        &format!("line {n}: phase value"),
        2,
    );
    expect("s.asc", &t.as_bytes()[..t.len() / 2], "truncated", 2);
    expect("s.asc", &t.as_bytes()[..300], "truncated", 2);
    let ends_early = with_line(&t, n, "#");
    expect("e.asc", ends_early.as_bytes(), "phase block has", 2);
    let bad_w = with_line(&t, 8, "0 0.5 abc 0 1 0 0.000636653 1513096733");
    expect(
        "w.asc",
        bad_w.as_bytes(),
        "header line 8: field wavelength_in = 'abc' is not a number",
        2,
    );
    let huge = with_line(&t, 4, "59 21 60000 60000");
    expect("h.asc", huge.as_bytes(), "cannot fit", 2);
    let zero = with_line(&t, 4, "59 21 0 189");
    expect("z.asc", zero.as_bytes(), "cn_width = 0", 2);
    let pr = with_line(&t, 11, "5 0 20 1 96.8896 0 0 0 0");
    expect(
        "p.asc",
        pr.as_bytes(),
        "header field phase_res = 5 is not 0, 1 or 2",
        2,
    );
    expect(
        "h.asc",
        b"Zygo ASCII Data File - Format 2\n1 8 1 1\n",
        "truncated: the header ends",
        2,
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn bad_datx() {
    expect(
        "x.datx",
        b"this is not HDF5 at all, just text",
        "not an HDF5 file",
        2,
    );
    let b = real("monolithic_zygo_test.datx");
    for cut in [8, 100, 2000, b.len() / 2, b.len() - 100] {
        let (e, _d, p) = fail("t.datx", &b[..cut]);
        let msg = e.to_string();
        assert!(
            msg.starts_with(&p.display().to_string()) && !msg.contains('\n'),
            "{msg}"
        );
        assert_eq!(e.exit_code(), 2, "{msg}");
    }
}

#[test]
fn bad_csv_exr_and_unknown_content() {
    expect(
        "r.csv",
        b"1,2,3\n4,5\n",
        "line 2 has 2 cells, the first row has 3",
        2,
    );
    expect(
        "a.csv",
        b"1,2,3\n4,abc,6\n",
        "line 2, column 2: 'abc' is not a finite number",
        2,
    );
    expect("i.csv", b"1,2\ninf,3\n", "line 2, column 1", 2);
    expect(
        "k.csv",
        b"# dx_mm=abc\n1,2\n",
        "dx_mm = 'abc' is not a number",
        2,
    );
    expect(
        "e.exr",
        &[0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, 1, 2, 3],
        "EXR",
        2,
    );
    expect(
        "u.txt",
        b"\x00\x01\x02 binary junk",
        "unrecognised map format",
        2,
    );
    expect("empty.dat", b"", "empty", 2);
    let missing = Path::new("/nonexistent/dir/map.dat");
    let e = read_surface(missing).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("/nonexistent/dir/map.dat: cannot read"),
        "{e}"
    );
    assert_eq!(e.exit_code(), 2);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn bad_xyz() {
    let t = asc_text();
    let t = with_line(&t, 4, "59 21 2 2");
    let head: Vec<&str> = t.lines().take(15).collect();
    let mut x = head.join("\n").replacen(
        "Zygo ASCII Data File - Format 2",
        "Zygo XYZ Data File - Format 1",
        1,
    );
    x.push_str("\n59 21 0.5\n60 21 abc\n#\n");
    expect(
        "b.xyz",
        x.as_bytes(),
        "line 17: Z = 'abc' is not a number",
        2,
    );
    let big = with_line(&x, 4, "59 21 1000 1000");
    expect("big.xyz", big.as_bytes(), "cannot fit", 2);
    let mut y = head.join("\n").replacen(
        "Zygo ASCII Data File - Format 2",
        "Zygo XYZ Data File - Format 1",
        1,
    );
    y.push_str("\n59 21 0.5\n5000 21 0.1\n#\n");
    expect("o.xyz", y.as_bytes(), "outside the window", 2);
}

/// Seeded random corruptions (byte flips, truncations, header-field overwrites) of real files
/// of every format: each parse returns Ok or Err, never panics.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn random_corruptions_never_panic() {
    use bonnetlab_io::{detect_format, parse_bytes};
    use bonnetlab_surface::rng::Rng;
    let dir = common::real_dir();
    let mut rng = Rng::new(20_240_601);
    let asc = std::fs::read(dir.join("pyxsurf_171212_PCO2_Zygo_data.asc")).unwrap();
    let files = [
        std::fs::read(dir.join(DAT3)).unwrap(),
        std::fs::read(dir.join("monolithic_zygo_test.datx")).unwrap(),
        asc[..asc.len().min(200_000)].to_vec(),
    ];
    let mut outcomes = [0usize; 2];
    for base in &files {
        for _ in 0..60 {
            let mut b = base.clone();
            match rng.below(3) {
                0 => {
                    for _ in 0..1 + rng.below(8) {
                        let k = rng.below(b.len());
                        b[k] = rng.below(256) as u8;
                    }
                }
                1 => b.truncate(rng.below(b.len())),
                _ => {
                    // Overwrite a header-sized region start with random bytes.
                    let k = rng.below(b.len().min(900));
                    for x in b.iter_mut().skip(k).take(4) {
                        *x = rng.below(256) as u8;
                    }
                }
            }
            let ok = detect_format(&b, Path::new("x"))
                .and_then(|f| parse_bytes(&b, f))
                .is_ok();
            outcomes[usize::from(ok)] += 1;
        }
    }
    // Both outcomes occur: corruptions inside the data block still read, header ones fail.
    assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
}

/// The surface dataspace (rows, cols as two u64 LE) is overwritten: a contiguous surface
/// larger than the file, or over the pixel cap, is refused before anything is allocated for it.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn datx_surface_dimensions_beyond_the_file() {
    let b = real("monolithic_zygo_test.datx");
    let mut dims = [0u8; 16];
    dims[..8].copy_from_slice(&259u64.to_le_bytes());
    dims[8..].copy_from_slice(&33u64.to_le_bytes());
    let at = b
        .windows(16)
        .position(|w| w == dims)
        .expect("the 259 x 33 dataspace of the real file");
    let patched = |rows: u64, cols: u64| {
        let mut m = b.clone();
        m[at..at + 8].copy_from_slice(&rows.to_le_bytes());
        m[at + 8..at + 16].copy_from_slice(&cols.to_le_bytes());
        m
    };
    // 10 360 x 33 f64 = 2 735 040 bytes in a 131 672-byte file.
    let msg = expect(
        "big.datx",
        &patched(10_360, 33),
        "declares 341880 elements of 8 bytes (2735040 bytes), more than the file size",
        2,
    );
    assert!(msg.contains("surface dataset /Data/Surface/"), "{msg}");
    expect(
        "huge.datx",
        &patched(1 << 20, 1 << 20),
        "is 1048576 x 1048576 pixels, more than the 67108864 pixel limit",
        2,
    );
    expect(
        "overflow.datx",
        &patched(u64::MAX / 2, 33),
        "pixel limit",
        2,
    );
    // Within the file size but not matching the stored data: still a clean error.
    let (e, _d, _p) = fail("bit.datx", &patched(300, 33));
    assert!(!e.to_string().contains('\n'), "{e}");
}
