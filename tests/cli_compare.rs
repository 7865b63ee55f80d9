//! `bonnetlab compare` end to end: the paper's convergence arithmetic on maps built to its exact
//! RMS and PV, report.json against numbers the library computes independently, the report's
//! files, and one-line errors with the right exit codes.

use std::path::{Path, PathBuf};
use std::process::Command;

use ndarray::Array2;

use bonnetlab::io::{write_surface, MapFormat};
use bonnetlab::spectrum::{psd_xy, ripple_from_psds, PsdOptions, RippleOptions};
use bonnetlab::surface::rng::Rng;
use bonnetlab::surface::{convergence, height_stats, remove_terms, Surface, Term};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

const PT: [Term; 2] = [Term::Piston, Term::Tilt];

/// A map whose residual after piston + tilt has exactly `rms` and `pv` (nm), then a set-up
/// piston and tilt added back. Built as a smooth field plus a spike whose size is found by
/// bisection on PV / RMS, then scaled; all on the given validity mask.
fn map_with(rms: f64, pv: f64, seed: u64, valid: &Array2<bool>) -> Surface {
    let (rows, cols) = valid.dim();
    let mut rng = Rng::new(seed);
    let (a, b, c) = (
        rng.uniform() * 6.0,
        rng.uniform() * 6.0,
        rng.uniform() * 6.0,
    );
    let base = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let (x, y) = (j as f64 / cols as f64, i as f64 / rows as f64);
        (7.0 * x + a).sin() * (5.0 * y + b).cos() + 0.4 * (11.0 * (x + y) + c).sin()
    });
    // The spike sits where the smooth field peaks, so PV grows with its size.
    let (mut si, mut sj, mut best) = (0, 0, f64::MIN);
    for ((i, j), &v) in base.indexed_iter() {
        if valid[(i, j)] && v > best {
            (si, sj, best) = (i, j, v);
        }
    }
    let residual = |alpha: f64| -> Surface {
        let mut z = base.clone();
        z[(si, sj)] += alpha;
        let s = Surface::with_mask(z, valid.clone(), Some(0.5), Some(0.5)).unwrap();
        remove_terms(&s, &PT).unwrap().0
    };
    let ratio = |alpha: f64| {
        let st = height_stats(&residual(alpha)).unwrap();
        st.pv_nm / st.rms_nm
    };
    let target = pv / rms;
    assert!(
        ratio(0.0) < target,
        "base ratio {} already above {target}",
        ratio(0.0)
    );
    let (mut lo, mut hi) = (0.0, 1.0);
    while ratio(hi) < target {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if ratio(mid) < target {
            lo = mid
        } else {
            hi = mid
        }
    }
    let r = residual(0.5 * (lo + hi));
    let st = height_stats(&r).unwrap();
    let scaled = r.heights_nm() * (rms / st.rms_nm);
    // Set-up terms that compare must remove again.
    let tilted = Array2::from_shape_fn((rows, cols), |(i, j)| {
        scaled[(i, j)] + 250.0 + 3.0 * j as f64 * 0.5 - 1.7 * i as f64 * 0.5
    });
    Surface::with_mask(tilted, valid.clone(), Some(0.5), Some(0.5)).unwrap()
}

fn write_csv(dir: &Path, name: &str, s: &Surface) -> PathBuf {
    let p = dir.join(name);
    write_surface(&p, s, MapFormat::Csv).unwrap();
    p
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn f(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing in {v}"))
}

#[test]
fn paper_table_arithmetic_through_compare() {
    let dir = tempfile::tempdir().unwrap();
    // A common mask with a few invalid pixels, the same for all maps of a run.
    let (rows, cols) = (64, 80);
    let valid = Array2::from_shape_fn((rows, cols), |(i, j)| !(i % 17 == 3 && j % 13 == 5));
    let table = [
        ("original", 143.426, 126.684, 740.438, 657.146),
        ("suppression", 91.309, 76.109, 515.286, 445.987),
    ];
    let mut cmd = bin();
    cmd.arg("compare");
    for (k, (name, rb, ra, pb, pa)) in table.iter().enumerate() {
        let b = write_csv(
            dir.path(),
            &format!("{name}_b.csv"),
            &map_with(*rb, *pb, 10 + k as u64, &valid),
        );
        let a = write_csv(
            dir.path(),
            &format!("{name}_a.csv"),
            &map_with(*ra, *pa, 20 + k as u64, &valid),
        );
        cmd.arg("--run")
            .arg(format!("{name}={},{}", b.display(), a.display()));
    }
    let out = dir.path().join("out");
    let o = cmd.arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = read_json(&out.join("report.json"));
    let runs = j["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for (r, (name, rb, ra, pb, pa)) in runs.iter().zip(table) {
        assert_eq!(r["name"], name);
        // The maps are built exactly: every number matches the table to rounding.
        assert!((f(r, "rms_before_nm") - rb).abs() < 1e-6, "{r}");
        assert!((f(r, "rms_after_nm") - ra).abs() < 1e-6);
        assert!((f(r, "pv_before_nm") - pb).abs() < 1e-6);
        assert!((f(r, "pv_after_nm") - pa).abs() < 1e-6);
        assert_eq!(r["removed"], serde_json::json!(["piston", "tilt"]));
    }
    // The paper's percentages, to 0.05 percentage points (they were computed from rounded CRs).
    let close = |v: f64, paper_pct: f64| (100.0 * v - paper_pct).abs() < 0.05;
    let (o_, s_) = (&runs[0], &runs[1]);
    assert!(close(f(o_, "cr_rms"), 11.67), "{}", f(o_, "cr_rms"));
    assert!(close(f(o_, "cr_pv"), 11.25), "{}", f(o_, "cr_pv"));
    assert!(close(f(s_, "cr_rms"), 16.64), "{}", f(s_, "cr_rms"));
    assert!(close(f(s_, "cr_pv"), 13.45), "{}", f(s_, "cr_pv"));
    assert!(
        close(f(s_, "improvement_cr_rms"), 42.59),
        "{}",
        f(s_, "improvement_cr_rms")
    );
    assert!(
        close(f(s_, "improvement_cr_pv"), 19.56),
        "{}",
        f(s_, "improvement_cr_pv")
    );
    assert!(
        o_.get("improvement_cr_rms").is_none(),
        "the first run is the reference"
    );
    // Exact arithmetic from the table.
    let cr = |b: f64, a: f64| (b - a) / b;
    let want = (cr(91.309, 76.109) - cr(143.426, 126.684)) / cr(143.426, 126.684);
    assert!((f(s_, "improvement_cr_rms") - want).abs() < 1e-8);
    // No pitch given: no ripple objects.
    assert!(o_.get("ripple_before").is_none());
}

/// Repeat measurements and a pitch: report.json against the library, computed here by a
/// separate path (common mask, per-map statistics, averaged PSDs, ripple from the PSDs).
#[test]
fn report_json_matches_the_library_with_repeats_and_ripple() {
    let dir = tempfile::tempdir().unwrap();
    let maps = bonnetlab::report::samples::generate(5, 2);
    let mut paths = std::collections::BTreeMap::new();
    for m in &maps {
        let p = dir.path().join(m.relative_path().replace('/', "_"));
        write_surface(&p, &m.surface, MapFormat::MetroProDat).unwrap();
        paths.insert((m.bonnet.clone(), m.state, m.repeat), p);
    }
    let arg = |b: &str| {
        let p = |st: &'static str, k: usize| paths[&(b.to_string(), st, k)].display().to_string();
        format!(
            "{b}={}+{},{}+{}",
            p("before", 1),
            p("before", 2),
            p("after", 1),
            p("after", 2)
        )
    };
    let out = dir.path().join("rep");
    let o = bin()
        .args([
            "compare",
            "--pitch-mm",
            "3",
            "--run",
            &arg("original"),
            "--run",
            &arg("suppression"),
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = read_json(&out.join("report.json"));
    assert_eq!(j["settings"]["window"], "hann");
    for r in j["runs"].as_array().unwrap() {
        let name = r["name"].as_str().unwrap();
        let read = |st: &'static str, k| {
            bonnetlab::io::read_surface(&paths[&(name.to_string(), st, k)]).unwrap()
        };
        let all = [
            read("before", 1),
            read("before", 2),
            read("after", 1),
            read("after", 2),
        ];
        let mut common = all[0].valid().clone();
        for s in &all[1..] {
            ndarray::Zip::from(&mut common)
                .and(s.valid())
                .for_each(|c, &v| *c = *c && v);
        }
        assert_eq!(
            r["common_valid"].as_u64().unwrap() as usize,
            common.iter().filter(|&&v| v).count()
        );
        let resid: Vec<Surface> = all
            .iter()
            .map(|s| {
                remove_terms(&s.with_valid(common.clone()).unwrap(), &PT)
                    .unwrap()
                    .0
            })
            .collect();
        let st: Vec<_> = resid.iter().map(|s| height_stats(s).unwrap()).collect();
        let rms_b = 0.5 * (st[0].rms_nm + st[1].rms_nm);
        let rms_a = 0.5 * (st[2].rms_nm + st[3].rms_nm);
        let pv_b = 0.5 * (st[0].pv_nm + st[1].pv_nm);
        assert!((f(r, "rms_before_nm") - rms_b).abs() < 1e-9 * rms_b);
        assert!((f(r, "rms_after_nm") - rms_a).abs() < 1e-9 * rms_a);
        assert!((f(r, "pv_before_nm") - pv_b).abs() < 1e-9 * pv_b);
        assert!((f(r, "cr_rms") - (rms_b - rms_a) / rms_b).abs() < 1e-12);
        // Sample sd of two values = |a - b| / sqrt 2.
        let sd = (st[0].rms_nm - st[1].rms_nm).abs() / 2f64.sqrt();
        assert!((f(&r["spread"], "rms_before_sd_nm") - sd).abs() < 1e-9);
        // Ripple from PSDs averaged over the two after maps.
        let opts = PsdOptions::default();
        let (x1, y1) = psd_xy(&resid[2], &opts).unwrap();
        let (x2, y2) = psd_xy(&resid[3], &opts).unwrap();
        let avg = |a: &bonnetlab::spectrum::Psd1d, b: &bonnetlab::spectrum::Psd1d| {
            let mut m = a.clone();
            for (o, v) in m.psd_nm2_mm.iter_mut().zip(&b.psd_nm2_mm) {
                *o = 0.5 * (*o + v);
            }
            m
        };
        let rip = ripple_from_psds(
            &avg(&x1, &x2),
            &avg(&y1, &y2),
            3.0,
            &RippleOptions::default(),
        )
        .unwrap();
        let ra = &r["ripple_after"];
        for key in ["sigma1_nm", "sigma_total_nm", "a_eq_nm", "prominence_db"] {
            assert!(
                (f(ra, key) - serde_json::to_value(&rip).unwrap()[key].as_f64().unwrap()).abs()
                    < 1e-9,
                "{key}"
            );
        }
        assert!((f(ra, "pitch_mm") - 3.0).abs() < 1e-12);
        assert!(ra["y_over_x"].is_number());
        // The PSD CSV holds the averaged Y PSD of the after maps.
        let csv = std::fs::read_to_string(out.join(format!("psd_y_{name}.csv"))).unwrap();
        let mut lines = csv.lines();
        assert_eq!(
            lines.next(),
            Some("freq_per_mm,psd_before_nm2_mm,psd_after_nm2_mm")
        );
        let ya = avg(&y1, &y2);
        let row5: Vec<f64> = lines
            .nth(5)
            .unwrap()
            .split(',')
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(row5[0], ya.freq_per_mm[5]);
        assert!((row5[2] - ya.psd_nm2_mm[5]).abs() <= 1e-12 * ya.psd_nm2_mm[5].abs());
        // Bands state their edges.
        let bands = r["bands"].as_array().unwrap();
        let names: Vec<&str> = bands.iter().map(|b| b["band"].as_str().unwrap()).collect();
        assert_eq!(names, ["figure", "msf", "ripple"]);
        assert!(bands
            .iter()
            .all(|b| b["f2_per_mm"].as_f64().unwrap() > b["f1_per_mm"].as_f64().unwrap()));
    }
    let supp = &j["runs"][1];
    let noise = &supp["improvement"]["noise"];
    assert!(noise["rms_within_noise"].is_boolean(), "{supp}");
    // The sample's bonnets differ by about 5 CR points with a repeat noise well under one point.
    assert_eq!(noise["rms_within_noise"], false);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("data:image/png;base64,") && html.contains("<svg"));
    assert!(
        !html.contains("src=\"http") && !html.contains("<script"),
        "must be self-contained"
    );
    assert!(html.contains("beyond the measurement noise"));
}

/// With a single map per state, the numbers equal bonnetlab_surface::convergence.
#[test]
fn single_maps_match_surface_convergence() {
    let dir = tempfile::tempdir().unwrap();
    let maps = bonnetlab::report::samples::generate(9, 1);
    let (b, a) = (&maps[0].surface, &maps[1].surface);
    let (pb, pa) = (
        write_csv(dir.path(), "b.csv", b),
        write_csv(dir.path(), "a.csv", a),
    );
    let out = dir.path().join("o");
    let o = bin()
        .args(["compare", "--remove", "piston,tilt,power", "--run"])
        .arg(format!("only={},{}", pb.display(), pa.display()))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = read_json(&out.join("report.json"));
    let r = &j["runs"][0];
    let c = convergence(b, a, &[Term::Piston, Term::Tilt, Term::Power]).unwrap();
    assert!((f(r, "cr_rms") - c.cr_rms).abs() < 1e-12);
    assert!((f(r, "cr_pv") - c.cr_pv).abs() < 1e-12);
    assert!((f(r, "rms_after_nm") - c.rms_after_nm).abs() < 1e-9);
    assert_eq!(r["common_valid"].as_u64().unwrap() as usize, c.common_valid);
    assert_eq!(r["removed"], serde_json::json!(["piston", "tilt", "power"]));
    assert!(r["spread"].is_null());
}

#[test]
fn errors_are_one_line_with_the_file_and_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    let missing = dir.path().join("nope.dat");
    let o = bin()
        .args(["compare", "--run"])
        .arg(format!("x={},{}", missing.display(), missing.display()))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nope.dat") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!out.join("report.json").exists());

    // Grids that differ within a run.
    let s1 = Surface::new(
        Array2::from_shape_fn((20, 30), |(i, j)| (i * j) as f64),
        Some(0.5),
        Some(0.5),
    )
    .unwrap();
    let s2 = Surface::new(
        Array2::from_shape_fn((20, 31), |(i, j)| (i + j) as f64),
        Some(0.5),
        Some(0.5),
    )
    .unwrap();
    let (p1, p2) = (
        write_csv(dir.path(), "g1.csv", &s1),
        write_csv(dir.path(), "g2.csv", &s2),
    );
    let o = bin()
        .args(["compare", "--run"])
        .arg(format!("g={},{}", p1.display(), p2.display()))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("g2.csv") && err.contains("grid"), "{err}");

    // Malformed --run and a bad pitch.
    let o = bin()
        .args(["compare", "--run", "nameonly", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("NAME=BEFORE,AFTER"));
    let o = bin()
        .args(["compare", "--pitch-mm", "-3", "--run"])
        .arg(format!("g={},{}", p1.display(), p1.display()))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

/// A recipe run's declared repeatability (`[measurement] repeatability_nm`) reaches the run's
/// calibration inside `compare`, and the report says so (null when a recipe does not declare
/// it). The bundled original-bonnet sample, its recipe copied with absolute paths and the key
/// added; the sample files are read, not copied or changed.
#[test]
fn a_recipes_declared_repeatability_reaches_its_calibration() {
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/original");
    let text = std::fs::read_to_string(sample.join("recipe.toml")).expect("the sample recipe");
    let mut with = text.clone();
    for name in ["before.dat", "after.dat", "spot.dat", "path.csv"] {
        let abs = sample.join(name);
        with = with.replace(
            &format!("\"{name}\""),
            &format!("{:?}", abs.display().to_string()),
        );
    }
    with = with.replace("[measurement]\n", "[measurement]\nrepeatability_nm = 0.9\n");
    assert!(with.contains("repeatability_nm = 0.9") && !with.contains("\"before.dat\""));
    let dir = tempfile::tempdir().expect("a temporary directory");
    let recipe = dir.path().join("declared.toml");
    std::fs::write(&recipe, with).expect("the recipe is written");
    let out_dir = dir.path().join("out");
    let out = bin()
        .args(["compare", "--run"])
        .arg(format!("declared={}", recipe.display()))
        .args(["--run"])
        .arg(format!("sample={}", sample.join("recipe.toml").display()))
        .arg("--out")
        .arg(&out_dir)
        .output()
        .expect("the binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j = read_json(&out_dir.join("report.json"));
    let cal = |i: usize| &j["runs"][i]["calibration"];
    assert_eq!(cal(0)["repeatability_nm"].as_f64(), Some(0.9));
    assert!(
        cal(1)["repeatability_nm"].is_null(),
        "{}",
        cal(1)["repeatability_nm"]
    );
    // The declared run's rounds made the smooth check with a bound from the declared value
    // (2 sqrt(0.9^2 - floor^2): at most 1.8 nm); the other run's without one.
    let bounds = |i: usize| -> Vec<serde_json::Value> {
        cal(i)["rounds"]
            .as_array()
            .expect("rounds")
            .iter()
            .filter(|r| r["smooth_check"].is_object())
            .map(|r| r["smooth_check"]["drift_bound_nm"].clone())
            .collect()
    };
    let declared = bounds(0);
    assert!(!declared.is_empty(), "no round made the smooth check");
    for b in declared {
        let b = b.as_f64().expect("a bound");
        assert!((0.0..=1.8).contains(&b), "bound {b}");
    }
    assert!(bounds(1).iter().all(|b| b.is_null()));
}
