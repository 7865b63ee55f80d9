//! `bonnetlab stats` end to end: the built binary on the 12 real Zygo files against the golden
//! values of shared/spec/zygo-formats.md section 7, and exit codes plus one-line errors that
//! name the file for malformed inputs built in a temporary directory.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

#[path = "common/shared_data.rs"]
mod shared_data;

fn real(name: &str) -> PathBuf {
    shared_data::data_file("real", name)
}

fn stats(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .arg("stats")
        .args(args)
        .output()
        .expect("the binary runs")
}

fn json(file: &Path, remove: &str) -> serde_json::Value {
    let out = stats(&[file.to_str().unwrap(), "--remove", remove, "--json"]);
    assert!(
        out.status.success(),
        "{}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON object")
}

/// (file, format, rows, cols, dx [m] or 0 for unknown, valid, PV piston, RMS piston,
/// PV plane, RMS plane): spec/zygo-formats.md section 7.
type Golden = (
    &'static str,
    &'static str,
    usize,
    usize,
    f64,
    usize,
    f64,
    f64,
    f64,
    f64,
);

#[rustfmt::skip]
const GOLDEN: [Golden; 12] = [
    ("surfalize_test_1.dat", "metropro-dat", 480, 640, 1.09825e-06, 307200, 1363.056, 75.2882, 1363.405, 13.3350),
    ("pyxsurf_05_C1S01.dat", "metropro-dat", 480, 640, 1.0963e-07, 307200, 347.231, 86.4682, 289.487, 81.1547),
    ("pyxsurf_05_C1S01.asc", "metropro-asc", 480, 640, 1.0963e-06, 307200, 347.231, 86.4682, 289.487, 81.1547),
    ("pyxsurf_07_PCO1.3S04.dat", "metropro-dat", 480, 640, 1.0963e-07, 307186, 313.293, 80.8952, 307.342, 80.6452),
    ("pyxsurf_07_PCO1.3S04.asc", "metropro-asc", 480, 640, 1.0963e-06, 307186, 313.293, 80.8952, 307.342, 80.6452),
    ("pyxsurf_20191018_01c_flat01_difffiducials.dat", "metropro-dat", 345, 346, 0.0, 93751, 327.581, 54.9766, 327.581, 54.9766),
    ("pyxsurf_20191018_01c_flat01_difffiducials.asc", "metropro-asc", 345, 346, 0.0, 93751, 327.562, 54.9729, 327.561, 54.9729),
    ("pyxsurf_03_flat04_differenceFiducials_nofid_verovero.dat", "metropro-dat", 343, 342, 2.51153e-04, 91315, 1238.834, 122.6128, 1238.834, 122.6128),
    ("pyxsurf_01_801B.dat", "metropro-dat", 480, 640, 2.45677e-04, 122975, 752.676, 228.5466, 736.725, 227.8523),
    ("pyxsurf_171212_PCO2_Zygo_data.asc", "metropro-asc", 189, 187, 6.36653e-04, 22633, 1821.994, 372.2780, 1681.510, 354.8941),
    ("prysm_valid_zygo_dat_file.dat", "metropro-dat", 432, 425, 1.17924e-04, 136359, 330.700, 44.5914, 330.700, 44.5914),
    ("monolithic_zygo_test.datx", "datx", 259, 33, 1.0e-03, 7771, 453.030, 80.8177, 457.569, 80.1964),
];

fn close(got: f64, want: f64, rel: f64) -> bool {
    (got - want).abs() <= rel * want.abs()
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn real_files_match_golden_values() {
    for &(name, format, rows, cols, dx_m, valid, pv_p, rms_p, pv_t, rms_t) in &GOLDEN {
        let file = real(name);
        let j = json(&file, "piston");
        assert_eq!(j["format"], format, "{name}");
        assert_eq!(j["rows"], rows, "{name}");
        assert_eq!(j["cols"], cols, "{name}");
        assert_eq!(j["valid"], valid, "{name}");
        assert_eq!(j["removed"], serde_json::json!(["piston"]), "{name}");
        if dx_m == 0.0 {
            assert!(
                j["dx_mm"].is_null() && j["dy_mm"].is_null(),
                "{name}: unknown pixel size"
            );
        } else {
            let dx = j["dx_mm"].as_f64().expect("dx_mm");
            // Golden dx values are printed to 5-6 significant digits.
            assert!(close(dx, dx_m * 1e3, 5e-5), "{name}: dx {dx} mm");
        }
        // Golden PV values have 3 decimals: 1e-4 relative or half a unit in the last place.
        let tol = |v: f64, digits: f64| (1e-4 * v).max(0.5 * digits);
        let pv = j["pv_nm"].as_f64().unwrap();
        let rms = j["rms_nm"].as_f64().unwrap();
        assert!(
            (pv - pv_p).abs() <= tol(pv_p, 1e-3),
            "{name}: PV piston {pv} vs {pv_p}"
        );
        assert!(
            (rms - rms_p).abs() <= tol(rms_p, 1e-4),
            "{name}: RMS piston {rms} vs {rms_p}"
        );
        for key in ["sa_nm", "ssk", "sku", "sp_nm", "sv_nm"] {
            assert!(j[key].as_f64().is_some_and(f64::is_finite), "{name}: {key}");
        }
        let j = json(&file, "piston,tilt");
        assert_eq!(j["removed"], serde_json::json!(["piston", "tilt"]));
        let pv = j["pv_nm"].as_f64().unwrap();
        let rms = j["rms_nm"].as_f64().unwrap();
        assert!(
            (pv - pv_t).abs() <= tol(pv_t, 1e-3),
            "{name}: PV plane {pv} vs {pv_t}"
        );
        assert!(
            (rms - rms_t).abs() <= tol(rms_t, 1e-4),
            "{name}: RMS plane {rms} vs {rms_t}"
        );
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn table_output_and_higher_order_terms() {
    let file = real("prysm_valid_zygo_dat_file.dat");
    let out = stats(&[file.to_str().unwrap(), "--remove", "piston,tilt,power"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("removed   piston, tilt, power"), "{text}");
    assert!(text.contains("RMS (Sq)"));
    // More terms can only lower the RMS: each set's span contains the previous one.
    let mut last = f64::INFINITY;
    for terms in ["piston", "piston,tilt,power", "zernike9", "zernike37"] {
        let rms = json(&file, terms)["rms_nm"].as_f64().unwrap();
        assert!(rms <= last + 1e-9, "{terms}: {rms} > {last}");
        last = rms;
    }
    let out = stats(&[
        file.to_str().unwrap(),
        "--remove",
        "legendre3",
        "--pvr",
        "--json",
    ]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let pvr = j["pvr_nm"].as_f64().unwrap();
    assert!(pvr > 0.0 && j["pvr_set"].as_str().unwrap().contains("Z1-Z37"));
}

/// Runs stats on `file` and checks the exit code and a one-line stderr naming the file.
fn expect_error(file: &Path, extra: &[&str], code: i32, needle: &str) {
    let mut args = vec![file.to_str().unwrap()];
    args.extend_from_slice(extra);
    let out = stats(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "{}: {err}", file.display());
    assert!(out.stdout.is_empty(), "no partial output");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    let name = file.file_name().unwrap().to_str().unwrap();
    assert!(err.contains(name), "names the file: {err}");
    assert!(
        err.to_lowercase().contains(needle),
        "mentions '{needle}': {err}"
    );
}

fn set_u16(b: &mut [u8], off: usize, v: u16) {
    b[off..off + 2].copy_from_slice(&v.to_be_bytes());
}

fn set_u32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_be_bytes());
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn malformed_inputs_give_exit_codes_and_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    // A small format-1 file without intensity: header 834, phase 345 x 346.
    let good = std::fs::read(real("pyxsurf_20191018_01c_flat01_difffiducials.dat")).unwrap();

    expect_error(&write("empty.dat", b""), &[], 2, "");
    expect_error(
        &write("words.dat", b"this is not a map at all\n"),
        &[],
        2,
        "",
    );
    expect_error(&write("truncated.dat", &good[..2000]), &[], 2, "");
    let mut b = good.clone();
    set_u16(&mut b, 68, 347); // cn_width no longer matches cn_n_bytes nor the file size
    expect_error(&write("width.dat", &b), &[], 2, "cn_");
    let mut b = good.clone();
    set_u16(&mut b, 68, 60000);
    set_u16(&mut b, 70, 60000);
    set_u32(&mut b, 72, 60000u32.wrapping_mul(60000).wrapping_mul(4)); // wraps: inconsistent anyway
    expect_error(&write("huge.dat", &b), &[], 2, "");
    let mut b = good.clone();
    set_u16(&mut b, 68, 0);
    set_u16(&mut b, 70, 0);
    set_u32(&mut b, 72, 0);
    expect_error(&write("zero.dat", &b[..834]), &[], 2, "");
    let mut b = good.clone();
    set_u16(&mut b, 218, 7);
    expect_error(&write("phase_res.dat", &b), &[], 2, "phase_res");
    // Well-formed but every phase value is the no-data marker: valid but unusable, exit 1.
    let mut b = good.clone();
    for chunk in b[834..].chunks_exact_mut(4) {
        chunk.copy_from_slice(&0x7FFF_FFF8u32.to_be_bytes());
    }
    expect_error(&write("nodata.dat", &b), &[], 1, "no valid pixel");
    // Short ASCII export: the header only.
    let asc = std::fs::read(real("pyxsurf_171212_PCO2_Zygo_data.asc")).unwrap();
    expect_error(&write("short.asc", &asc[..600]), &[], 2, "");
    expect_error(&dir.path().join("missing.dat"), &[], 2, "");
    // A bad term list is a usage error (the binary parses it before reading the file).
    let out = stats(&[
        real("prysm_valid_zygo_dat_file.dat").to_str().unwrap(),
        "--remove",
        "coma",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("coma"));
}

/// Every map file of a shared data directory (the directory must exist and hold maps: a
/// missing checkout fails here with the path, it never passes silently).
fn maps_in(dir: &Path) -> Vec<PathBuf> {
    let entries = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: cannot list the shared data ({e})", dir.display()));
    let mut v: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| ["dat", "asc", "datx", "xyz"].contains(&e))
        })
        .collect();
    v.sort();
    assert!(!v.is_empty(), "{}: no map files", dir.display());
    v
}

/// Issue #19: `stats --bands` on every real file (shared/data/real and external) and on the
/// demo sample maps: the resolvable bands add up in quadrature to the map RMS (within 1 %,
/// the bound; the method makes it exact), and every absent band has a reason.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn bands_add_in_quadrature_on_every_real_file_and_the_demo_maps() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = maps_in(&shared_data::data_dir("real"));
    files.extend(maps_in(&shared_data::data_dir("external")));
    for run in ["original", "suppression"] {
        files.extend(maps_in(&root.join("samples").join(run)));
    }
    let mut checked = 0;
    for file in &files {
        for (edges, remove) in [("1/33,1/0.12", "piston,tilt"), ("2,20", "piston")] {
            let out = stats(&[
                file.to_str().unwrap(),
                "--remove",
                remove,
                "--bands",
                edges,
                "--json",
            ]);
            assert!(
                out.status.success(),
                "{}: {}",
                file.display(),
                String::from_utf8_lossy(&out.stderr)
            );
            let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let b = &j["bands"];
            let rms = j["rms_nm"].as_f64().unwrap();
            let mut sum = 0.0;
            let mut parts = Vec::new();
            for band in ["figure", "msf", "fine"] {
                match b[format!("{band}_rms_nm")].as_f64() {
                    Some(v) => {
                        assert!(v.is_finite() && v >= 0.0);
                        sum += v * v;
                        parts.push(format!("{band} {v:.3}"));
                    }
                    None => {
                        let why = b[format!("{band}_reason")].as_str().unwrap_or_else(|| {
                            panic!("{}: {band} null without a reason", file.display())
                        });
                        assert!(why.starts_with("not resolvable"), "{why}");
                        parts.push(format!("{band} absent"));
                    }
                }
            }
            if j["dx_mm"].is_null() {
                assert_eq!(sum, 0.0, "{}: no pixel size, no band", file.display());
                continue;
            }
            eprintln!(
                "{} [{edges}] {remove}: rms {rms:.3} nm = {} (quadrature {:.6}, cross {:.2e})",
                file.file_name().unwrap().to_string_lossy(),
                parts.join(", "),
                sum.sqrt() / rms,
                b["cross_term_fraction"].as_f64().unwrap()
            );
            assert!(
                (sum.sqrt() / rms - 1.0).abs() < 0.01,
                "{}: bands {} vs RMS {rms}",
                file.display(),
                sum.sqrt()
            );
            checked += 1;
        }
    }
    assert!(checked >= 40, "only {checked} maps with a pixel size");
}

/// `--minus`: two measurements of one flat (the repeatability series `01_801B`, `02_801B`)
/// differ by the RMS a lab declares as its instrument's repeatability. The binary's figure is
/// checked against the difference formed here on the pixels valid in both, with its
/// least-squares plane solved from the 3 x 3 normal equations in this test (not the surface
/// crate's form removal).
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn minus_gives_the_repeatability_of_two_measurements() {
    let a_path = shared_data::data_file("external", "pyxsurf_02_801B.dat");
    let b_path = real("pyxsurf_01_801B.dat");
    let read = |p: &Path| bonnetlab::io::read_surface(p).unwrap_or_else(|e| panic!("{e}"));
    let (a, b) = (read(&a_path), read(&b_path));
    // The difference on the common valid pixels, and its plane by normal equations.
    let mut pts: Vec<(f64, f64, f64)> = Vec::new();
    for ((i, j), &ha) in a.heights_nm().indexed_iter() {
        if a.valid()[(i, j)] && b.valid()[(i, j)] {
            pts.push((j as f64, i as f64, ha - b.heights_nm()[(i, j)]));
        }
    }
    let mut n = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for &(x, y, z) in &pts {
        let v = [1.0, x, y];
        for p in 0..3 {
            for q in 0..3 {
                n[p][q] += v[p] * v[q];
            }
            r[p] += v[p] * z;
        }
    }
    // Cramer's rule on the 3 x 3 system.
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&n);
    let c: Vec<f64> = (0..3)
        .map(|k| {
            let mut m = n;
            for p in 0..3 {
                m[p][k] = r[p];
            }
            det(&m) / d
        })
        .collect();
    let ss: f64 = pts
        .iter()
        .map(|&(x, y, z)| (z - c[0] - c[1] * x - c[2] * y).powi(2))
        .sum();
    let want = (ss / pts.len() as f64).sqrt();

    let out = stats(&[
        a_path.to_str().unwrap(),
        "--minus",
        b_path.to_str().unwrap(),
        "--remove",
        "piston,tilt",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(j["valid"].as_u64(), Some(pts.len() as u64));
    let got = j["rms_nm"].as_f64().expect("rms_nm");
    assert!(close(got, want, 1e-9), "rms {got} vs {want}");
    assert!(
        (1.5..1.8).contains(&got),
        "the pair differs by {got} nm RMS"
    );
    assert_eq!(j["minus"].as_str(), b_path.to_str());
    assert_eq!(j["format"].as_str(), Some("metropro-dat"));

    // The table says what was subtracted.
    let out = stats(&[
        a_path.to_str().unwrap(),
        "--minus",
        b_path.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("minus "));

    // A map of another grid is refused, naming it, exit 2 and nothing on stdout.
    let other = real("surfalize_test_1.dat");
    let out = stats(&[a_path.to_str().unwrap(), "--minus", other.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(out.stdout.is_empty());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("surfalize_test_1.dat") && err.contains("grid"),
        "{err}"
    );
}

/// A map minus itself is flat: RMS 0 and skewness / kurtosis null with the reason beside them
/// (they were printed as 0.0, and Sv as -0.0). A real map's parameters stay numbers.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn a_flat_difference_has_undefined_moments_with_a_reason() {
    let p = real("pyxsurf_01_801B.dat");
    let ps = p.to_str().unwrap();
    let out = stats(&[ps, "--minus", ps, "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["rms_nm"].as_f64(), Some(0.0), "{v}");
    assert!(v["ssk"].is_null() && v["sku"].is_null(), "{v}");
    assert!(
        v["moments_reason"]
            .as_str()
            .is_some_and(|r| r.contains("flat")),
        "{v}"
    );
    assert_eq!(serde_json::to_string(&v["sv_nm"]).unwrap(), "0.0");
    let real_map = json(&p, "piston");
    assert!(real_map["ssk"].is_number() && real_map.get("moments_reason").is_none());
    // The table says so too.
    let out = stats(&[ps, "--minus", ps]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("undefined (a flat map"));
}
