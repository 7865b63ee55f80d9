//! Golden values (spec zygo-formats.md §7) on the 12 real Zygo files, and the .asc/.dat twins.

mod common;

use bonnetlab_io::read_surface;
use bonnetlab_surface::Term;
use common::{assert_rel, pv_rms, real_dir};

struct Golden {
    file: &'static str,
    format: &'static str,
    rows: usize,
    cols: usize,
    /// Pixel size in m; 0 = unknown.
    dx_m: f64,
    valid: usize,
    /// PV, RMS after piston; PV, RMS after piston + tilt (nm).
    stats: [f64; 4],
}

const GOLDEN: &[Golden] = &[
    Golden {
        file: "surfalize_test_1.dat",
        format: "metropro-dat",
        rows: 480,
        cols: 640,
        dx_m: 1.09825e-06,
        valid: 307200,
        stats: [1363.056, 75.2882, 1363.405, 13.3350],
    },
    Golden {
        file: "pyxsurf_05_C1S01.dat",
        format: "metropro-dat",
        rows: 480,
        cols: 640,
        dx_m: 1.0963e-07,
        valid: 307200,
        stats: [347.231, 86.4682, 289.487, 81.1547],
    },
    Golden {
        file: "pyxsurf_05_C1S01.asc",
        format: "metropro-asc",
        rows: 480,
        cols: 640,
        dx_m: 1.0963e-06,
        valid: 307200,
        stats: [347.231, 86.4682, 289.487, 81.1547],
    },
    Golden {
        file: "pyxsurf_07_PCO1.3S04.dat",
        format: "metropro-dat",
        rows: 480,
        cols: 640,
        dx_m: 1.0963e-07,
        valid: 307186,
        stats: [313.293, 80.8952, 307.342, 80.6452],
    },
    Golden {
        file: "pyxsurf_07_PCO1.3S04.asc",
        format: "metropro-asc",
        rows: 480,
        cols: 640,
        dx_m: 1.0963e-06,
        valid: 307186,
        stats: [313.293, 80.8952, 307.342, 80.6452],
    },
    Golden {
        file: "pyxsurf_20191018_01c_flat01_difffiducials.dat",
        format: "metropro-dat",
        rows: 345,
        cols: 346,
        dx_m: 0.0,
        valid: 93751,
        stats: [327.581, 54.9766, 327.581, 54.9766],
    },
    Golden {
        file: "pyxsurf_20191018_01c_flat01_difffiducials.asc",
        format: "metropro-asc",
        rows: 345,
        cols: 346,
        dx_m: 0.0,
        valid: 93751,
        stats: [327.562, 54.9729, 327.561, 54.9729],
    },
    Golden {
        file: "pyxsurf_03_flat04_differenceFiducials_nofid_verovero.dat",
        format: "metropro-dat",
        rows: 343,
        cols: 342,
        dx_m: 2.51153e-04,
        valid: 91315,
        stats: [1238.834, 122.6128, 1238.834, 122.6128],
    },
    Golden {
        file: "pyxsurf_01_801B.dat",
        format: "metropro-dat",
        rows: 480,
        cols: 640,
        dx_m: 2.45677e-04,
        valid: 122975,
        stats: [752.676, 228.5466, 736.725, 227.8523],
    },
    Golden {
        file: "pyxsurf_171212_PCO2_Zygo_data.asc",
        format: "metropro-asc",
        rows: 189,
        cols: 187,
        dx_m: 6.36653e-04,
        valid: 22633,
        stats: [1821.994, 372.2780, 1681.510, 354.8941],
    },
    Golden {
        file: "prysm_valid_zygo_dat_file.dat",
        format: "metropro-dat",
        rows: 432,
        cols: 425,
        dx_m: 1.17924e-04,
        valid: 136359,
        stats: [330.700, 44.5914, 330.700, 44.5914],
    },
    Golden {
        file: "monolithic_zygo_test.datx",
        format: "datx",
        rows: 259,
        cols: 33,
        dx_m: 1.0e-03,
        valid: 7771,
        stats: [453.030, 80.8177, 457.569, 80.1964],
    },
];

fn check(g: &Golden) {
    let dir = real_dir();
    let s = read_surface(&dir.join(g.file)).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.provenance.format, g.format, "{}", g.file);
    assert_eq!(s.dim(), (g.rows, g.cols), "{}", g.file);
    assert_eq!(s.valid_count(), g.valid, "{}", g.file);
    if g.dx_m == 0.0 {
        assert_eq!(
            (s.dx_mm, s.dy_mm),
            (None, None),
            "{}: pixel size 0 must be unknown",
            g.file
        );
    } else {
        assert_rel(
            &format!("{} dx", g.file),
            s.dx_mm.unwrap(),
            g.dx_m * 1e3,
            1e-4,
        );
        assert_rel(
            &format!("{} dy", g.file),
            s.dy_mm.unwrap(),
            g.dx_m * 1e3,
            1e-4,
        );
    }
    let (pv, rms) = pv_rms(&s, &[Term::Piston]);
    let (pv_t, rms_t) = pv_rms(&s, &[Term::Piston, Term::Tilt]);
    for (what, got, want) in [
        ("PV piston", pv, g.stats[0]),
        ("RMS piston", rms, g.stats[1]),
        ("PV plane", pv_t, g.stats[2]),
        ("RMS plane", rms_t, g.stats[3]),
    ] {
        assert_rel(&format!("{} {what}", g.file), got, want, 1e-4);
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn every_real_zygo_file_matches_its_golden_values() {
    let mut seen = 0;
    for g in GOLDEN {
        check(g);
        seen += 1;
    }
    assert_eq!(seen, GOLDEN.len());
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn provenance_of_a_newview_dat() {
    let dir = real_dir();
    let s = read_surface(&dir.join("surfalize_test_1.dat")).unwrap();
    let p = &s.provenance;
    assert_eq!(p.wavelength_m.map(|w| (w * 1e9).round()), Some(570.0));
    assert!(p.objective.as_deref().unwrap().contains("20X"), "{p:?}");
    assert!(
        p.software.as_deref().unwrap().starts_with("MetroPro 8.1.5"),
        "{p:?}"
    );
    assert!(
        p.instrument.as_deref().unwrap().contains("sys_type 22"),
        "{p:?}"
    );
    assert!(p
        .source_path
        .as_deref()
        .unwrap()
        .ends_with("surfalize_test_1.dat"));
    let s = read_surface(&dir.join("pyxsurf_05_C1S01.dat")).unwrap();
    // The full serial (i32 LE @798) and the measurement time stamp (2018, per the .asc twin).
    assert!(s
        .provenance
        .instrument
        .as_deref()
        .unwrap()
        .ends_with("serial 63026"));
    assert!(s
        .provenance
        .date
        .as_deref()
        .unwrap()
        .starts_with("2018-03-30"));
    let s = read_surface(&dir.join("monolithic_zygo_test.datx")).unwrap();
    let p = &s.provenance;
    assert_eq!(p.instrument.as_deref(), Some("Zygo GPI, serial 651365"));
    assert_eq!(p.software.as_deref(), Some("MetroPro 8.3.3"));
    assert_eq!(p.objective.as_deref(), Some("Sm Aperture"));
    // Coordinates {RowStart 22, ColumnStart 15} at 1 mm/pixel.
    assert!((s.origin_mm.0 - 15.0).abs() < 1e-5 && (s.origin_mm.1 - 22.0).abs() < 1e-5);
    assert!((p.wavelength_m.unwrap() - 632.8e-9).abs() < 1e-12, "{p:?}");
    let s = read_surface(&dir.join("pyxsurf_07_PCO1.3S04.asc")).unwrap();
    assert!(s
        .provenance
        .comment
        .as_deref()
        .unwrap()
        .contains("PCO1.3S04"));
}

/// Each .asc equals its .dat twin within one count, with the same mask.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn asc_equals_its_dat_twin_within_one_count() {
    let dir = real_dir();
    for stem in [
        "pyxsurf_05_C1S01",
        "pyxsurf_07_PCO1.3S04",
        "pyxsurf_20191018_01c_flat01_difffiducials",
    ] {
        let d = read_surface(&dir.join(format!("{stem}.dat"))).unwrap();
        let a = read_surface(&dir.join(format!("{stem}.asc"))).unwrap();
        assert_eq!(d.dim(), a.dim(), "{stem}");
        assert_eq!(d.valid(), a.valid(), "{stem}: masks differ");
        let w = d.provenance.wavelength_m.unwrap();
        let count_nm = w * 0.5 / 32768.0 * 1e9;
        let mut worst = 0.0f64;
        let mut n_diff = 0;
        let mut worst_rel = 0.0f64;
        for (x, y) in d.heights_nm().iter().zip(a.heights_nm()) {
            worst = worst.max((x - y).abs());
            // The .dat stores W as f32, the .asc prints it in decimal: 1e-7 relative apart.
            let rel = (x - y).abs() / x.abs().max(y.abs()).max(1e-300);
            if rel > 1e-6 {
                n_diff += 1;
                worst_rel = worst_rel.max(rel);
            }
        }
        assert!(
            worst <= count_nm * 1.000_01,
            "{stem}: max difference {worst} nm > one count {count_nm} nm"
        );
        if stem.contains("2019") {
            // The Mx double export rounds separately (spec §3.2): many ±1 differences.
            assert!(n_diff > 1000, "{stem}: {n_diff}");
        } else {
            assert_eq!(
                n_diff, 0,
                "{stem}: MetroPro twins are identical in counts (worst {worst_rel:.1e})"
            );
        }
    }
}

/// The XYZ layout of spec §4 (unverified against a real file): built here from a real .asc
/// header and its phase data (X, Y in camera pixels incl. cn_org, Z in µm, `No Data`).
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn xyz_built_from_a_real_asc_reads_the_same_map() {
    let dir = real_dir();
    let asc_path = dir.join("pyxsurf_171212_PCO2_Zygo_data.asc");
    let asc = read_surface(&asc_path).unwrap();
    let text = std::fs::read_to_string(&asc_path).unwrap();
    let mut out: String = text.lines().take(15).collect::<Vec<_>>().join("\r\n");
    out = out.replacen(
        "Zygo ASCII Data File - Format 2",
        "Zygo XYZ Data File - Format 1",
        1,
    );
    out.push_str("\r\n");
    let (rows, cols) = asc.dim();
    let (ox, oy) = (59, 21); // line 4 of this file: cn_org 59 21
    for i in 0..rows {
        for j in 0..cols {
            match asc.get(i, j) {
                Some(h) => out.push_str(&format!("{} {} {:.9}\r\n", j + ox, i + oy, h / 1e3)),
                None => out.push_str(&format!("{} {} No Data\r\n", j + ox, i + oy)),
            }
        }
    }
    out.push_str("#\r\n");
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("map.xyz");
    std::fs::write(&p, out).unwrap();
    let x = read_surface(&p).unwrap();
    assert_eq!(x.provenance.format, "zygo-xyz");
    assert_eq!(x.dim(), asc.dim());
    assert_eq!(x.valid(), asc.valid());
    assert_eq!(x.dx_mm, asc.dx_mm);
    assert_eq!(x.origin_mm, asc.origin_mm);
    let worst = x
        .heights_nm()
        .iter()
        .zip(asc.heights_nm())
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-5, "{worst} nm");
}

/// A Windows (CRLF) copy of a real .asc reads identically.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn crlf_asc_reads_like_lf() {
    let dir = real_dir();
    let p = dir.join("pyxsurf_20191018_01c_flat01_difffiducials.asc");
    let lf = read_surface(&p).unwrap();
    let text = std::fs::read_to_string(&p).unwrap().replace('\n', "\r\n");
    let d = tempfile::tempdir().unwrap();
    let q = d.path().join("crlf.asc");
    std::fs::write(&q, text).unwrap();
    let crlf = read_surface(&q).unwrap();
    assert_eq!(crlf.heights_nm(), lf.heights_nm());
    assert_eq!(crlf.valid(), lf.valid());
}
