//! `bonnetlab simulate` end to end on a small generated run (Gaussian model TIF, raster log):
//! the output files exist, the JSON holds the contract's fields, and the predicted removal's
//! mean matches the analytic volume rate x dwell per area. (The full generated-run check,
//! measured spot + noise vs an independent deposition, is not written yet.)

use std::process::{Command, Output};

use bonnetlab::io::{write_surface, MapFormat};
use bonnetlab::process::path::log::path_to_csv;
use bonnetlab::process::RasterSpec;
use bonnetlab::surface::Surface;
use ndarray::Array2;

/// `bonnetlab simulate RECIPE [ARGS] --out OUT`.
fn simulate(recipe: &std::path::Path, out: &std::path::Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .arg("simulate")
        .arg(recipe)
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn simulate_writes_maps_json_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let before = Array2::from_shape_fn((160, 200), |(i, j)| {
        let (x, y) = (j as f64 * 0.25, i as f64 * 0.25);
        20.0 * ((x - 25.0).powi(2) + (y - 20.0).powi(2)) / 625.0 + 2.0 * (x / 7.0).sin()
    });
    let s = Surface::new(before, Some(0.25), Some(0.25)).unwrap();
    write_surface(&d.join("before.dat"), &s, MapFormat::MetroProDat).unwrap();
    let mut spec = RasterSpec::over_rect((-6.0, 56.0), (-6.0, 46.0), 2.0, 4.0);
    spec.sample_dt_s = 0.2;
    let path = spec.generate().unwrap();
    std::fs::write(d.join("path.csv"), path_to_csv(&path)).unwrap();
    std::fs::write(
        d.join("recipe.toml"),
        "[measurement]\nbefore = \"before.dat\"\n[tif]\nmodel = { kind = \"gaussian\", sigma_mm = 1.0, \
         peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }\n[path]\nlog = \"path.csv\"\npitch_mm = 2.0\n\
         [process]\nbonnet = \"original\"\n",
    )
    .unwrap();
    let out = d.join("out");
    // The nominal prediction (the analytic mean below has no vibration in it).
    let o = simulate(&d.join("recipe.toml"), &out, &["--no-vibration"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "predicted_after.dat",
        "predicted_removal.dat",
        "simulation.json",
        "predicted_psd_y.png",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("simulation.json")).unwrap()).unwrap();
    for k in ["rms_after_nm", "pv_after_nm", "cr_rms"] {
        assert!(v[k].as_f64().is_some(), "{k}");
    }
    assert!(v["ripple"]["sigma1_nm"].as_f64().is_some());
    assert_eq!(v["mechanisms"][0]["name"], "nominal_raster");
    assert!((v["mechanisms"][0]["share"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    // Mean removal = volume rate / (pitch x feed): 2 pi sigma^2 peak (1 - e^-8) / (2 x 4).
    let vol = 2.0 * std::f64::consts::PI * 10.0 * (1.0 - (-8.0f64).exp());
    let expect = vol / 8.0;
    let removal = bonnetlab::io::read_surface(&out.join("predicted_removal.dat")).unwrap();
    let mean = removal.valid_heights().sum::<f64>() / removal.valid_count() as f64;
    assert!((mean / expect - 1.0).abs() < 0.01, "{mean} vs {expect}");
    assert!(v.get("ripple_reason").is_none(), "{}", v["ripple_reason"]);
    // Without a pitch in the recipe the ripple is null with its reason beside it.
    let nopitch = std::fs::read_to_string(d.join("recipe.toml"))
        .unwrap()
        .replacen("pitch_mm = 2.0\n", "", 1);
    std::fs::write(d.join("nopitch.toml"), nopitch).unwrap();
    let o = simulate(
        &d.join("nopitch.toml"),
        &d.join("nopitch"),
        &["--no-vibration"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let w: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("nopitch").join("simulation.json")).unwrap())
            .unwrap();
    assert!(w["ripple"].is_null(), "{}", w["ripple"]);
    assert!(
        w["ripple_reason"]
            .as_str()
            .is_some_and(|r| r.contains("pitch_mm")),
        "{}",
        w["ripple_reason"]
    );
    // A recipe whose pixels are area means: the prediction is each pixel's mean of the
    // removal. The TIF is 100x faster here so that the box's effect (0.19 nm RMS) stands far
    // above the .dat files' height step (about 0.01 nm). Measured: the area prediction is
    // 0.016 nm RMS from the camera's pixel means below, the point prediction 0.174 nm.
    assert_eq!(v["pixels"], "point");
    let recipe = std::fs::read_to_string(d.join("recipe.toml"))
        .unwrap()
        .replacen(
            "peak_rate_nm_per_s = 10.0",
            "peak_rate_nm_per_s = 1000.0",
            1,
        );
    let predict = |name: &str, recipe: String| {
        std::fs::write(d.join(format!("{name}.toml")), recipe).unwrap();
        let out = d.join(name);
        let o = simulate(&d.join(format!("{name}.toml")), &out, &["--no-vibration"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("simulation.json")).unwrap()).unwrap();
        let r = bonnetlab::io::read_surface(&out.join("predicted_removal.dat")).unwrap();
        (v, r)
    };
    let (vp, point) = predict("point", recipe.clone());
    let (va, area) = predict(
        "area",
        recipe.replacen("[measurement]\n", "[measurement]\npixels = \"area\"\n", 1),
    );
    assert_eq!(vp["pixels"], "point");
    assert_eq!(va["pixels"], "area");
    // The truth a camera pixel reports: exact time-domain deposition of the Gaussian on a grid
    // four times finer, averaged over each map pixel's 4 x 4 sub-pixels (the library's exact
    // deposition, not the fast model simulate uses, and not its box quadrature).
    let k = 4usize;
    let (rows, cols) = point.heights_nm().dim();
    let fine = bonnetlab::process::Grid::new(
        rows * k,
        cols * k,
        0.25 / k as f64,
        0.25 / k as f64,
        -0.125 + 0.125 / k as f64,
        -0.125 + 0.125 / k as f64,
    )
    .unwrap();
    let g = bonnetlab::process::tif::GaussianTif::new(1.0, 8.0, 1000.0).unwrap();
    let exact = bonnetlab::process::removal::deposit_exact(
        &path,
        &g,
        &fine,
        None,
        &bonnetlab::process::removal::ExactOptions::default(),
    )
    .unwrap();
    let means = Array2::from_shape_fn((rows, cols), |(i, j)| {
        exact
            .slice(ndarray::s![i * k..(i + 1) * k, j * k..(j + 1) * k])
            .mean()
            .unwrap()
    });
    let drms = |a: &Array2<f64>, b: &Array2<f64>| {
        ((a - b).iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt()
    };
    let box_effect = drms(point.heights_nm(), area.heights_nm());
    let d_area = drms(area.heights_nm(), &means);
    let d_point = drms(point.heights_nm(), &means);
    assert!(
        box_effect > 0.1,
        "the box changes the prediction: {box_effect} nm"
    );
    assert!(
        d_area < 0.2 * d_point,
        "area {d_area} nm, point {d_point} nm from the pixel means"
    );
    let mean_of = |s: &Surface| s.valid_heights().sum::<f64>() / s.valid_count() as f64;
    let (mp, ma) = (mean_of(&point), mean_of(&area));
    assert!((ma / mp - 1.0).abs() < 1e-3, "{ma} vs {mp}");
    // Bad recipe: one line naming the file and key, exit 2.
    std::fs::write(d.join("bad.toml"), "[measurement]\nbefore = \"before.dat\"\n[tif]\nspot = \"s.dat\"\n[path]\nlog = \"p.csv\"\n").unwrap();
    let o = simulate(&d.join("bad.toml"), &out, &[]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml") && err.contains("dwell_s"), "{err}");
}

/// A flat before map has no convergence ratio: `cr_rms` / `cr_pv` are null with `cr_reason`
/// beside them (they were 0.0, printed "CR 0.0 %"), and the summary line says undefined.
#[test]
fn flat_before_map_has_no_convergence_ratio() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = Surface::new(Array2::from_elem((80, 100), 5.0), Some(0.25), Some(0.25)).unwrap();
    write_surface(&d.join("before.dat"), &s, MapFormat::MetroProDat).unwrap();
    let mut spec = RasterSpec::over_rect((-6.0, 31.0), (-6.0, 26.0), 2.0, 4.0);
    spec.sample_dt_s = 0.2;
    std::fs::write(d.join("path.csv"), path_to_csv(&spec.generate().unwrap())).unwrap();
    std::fs::write(
        d.join("recipe.toml"),
        "[measurement]\nbefore = \"before.dat\"\n[tif]\nmodel = { kind = \"gaussian\", sigma_mm = 1.0, \
         peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }\n[path]\nlog = \"path.csv\"\npitch_mm = 2.0\n",
    )
    .unwrap();
    let out = d.join("out");
    let o = simulate(&d.join("recipe.toml"), &out, &["--no-vibration"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("simulation.json")).unwrap()).unwrap();
    assert!(v["cr_rms"].is_null() && v["cr_pv"].is_null(), "{v}");
    let why = v["cr_reason"].as_str().unwrap_or_default();
    assert!(why.contains("flat") && why.contains("undefined"), "{v}");
    assert!(v["rms_after_nm"].as_f64().is_some_and(|r| r > 0.0));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("CR undefined") && !stdout.contains("CR 0.0 %"),
        "{stdout}"
    );
}
