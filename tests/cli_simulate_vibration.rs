//! `bonnetlab simulate` with the vibration coupling on a small generated run (Gaussian model TIF,
//! raster log, `[process]` table): for each bonnet the JSON lists the coupling mechanisms with
//! finite shares summing to 1 over the whole `mechanisms` array (as `mechanism_share_basis`
//! says), and the written removal equals the library's `coupling::predict` evaluated here
//! independently from the same files (to the .dat quantisation). `--no-vibration` leaves only
//! `nominal_raster`; `--sweep-rpm` writes the sweep table, JSON array and plot.

use std::path::Path;
use std::process::Command;

use bonnetlab::io::{read_surface, write_surface, MapFormat};
use bonnetlab::process::path::log::path_to_csv;
use bonnetlab::process::recipe::TifSource;
use bonnetlab::process::simulate::ToolModel;
use bonnetlab::process::tif::GaussianTif;
use bonnetlab::process::{read_path_csv, Grid, RasterSpec};
use bonnetlab::surface::Surface;
use bonnetlab::vibration::coupling::{predict, CouplingInput, CouplingOptions};
use bonnetlab::vibration::params::{Bonnet, VibrationParams};
use ndarray::Array2;

const PITCH_MM: f64 = 2.0;
/// A strong force fluctuation near the 19.8 Hz principal mode, so the vibration-induced removal
/// is well above the .dat count and the CLI-vs-library check can tell coupling on from off.
const VIBRATION: &str = "[vibration]\nfn_n = 400.0\n";

/// Writes before.dat, path.csv and recipe.toml into `d`; returns the recipe path.
fn make_run(d: &Path) -> std::path::PathBuf {
    let before = Array2::from_shape_fn((56, 64), |(i, j)| {
        let (x, y) = (j as f64 * 0.5, i as f64 * 0.5);
        10.0 * ((x - 16.0).powi(2) + (y - 14.0).powi(2)) / 256.0 + (x / 5.0).sin()
    });
    let s = Surface::new(before, Some(0.5), Some(0.5)).unwrap();
    write_surface(&d.join("before.dat"), &s, MapFormat::MetroProDat).unwrap();
    let mut spec = RasterSpec::over_rect((-4.0, 36.0), (-4.0, 32.0), PITCH_MM, 5.0);
    spec.sample_dt_s = 0.1;
    let path = spec.generate().unwrap();
    std::fs::write(d.join("path.csv"), path_to_csv(&path)).unwrap();
    let recipe = d.join("recipe.toml");
    std::fs::write(
        &recipe,
        format!("[measurement]\nbefore = \"before.dat\"\n[tif]\nmodel = {{ kind = \"gaussian\", sigma_mm = 1.0, \
         peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }}\n[path]\nlog = \"path.csv\"\npitch_mm = 2.0\n\
         [process]\nbonnet = \"original\"\nspindle_rpm = 1188.0\noffset_mm = 0.6\n\
         inner_pressure_mpa = 0.25\n{VIBRATION}"),
    )
    .unwrap();
    recipe
}

fn simulate(recipe: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    simulate_with_stdout(recipe, out, extra).0
}

/// [`simulate`], also returning what the command printed on stdout.
fn simulate_with_stdout(recipe: &Path, out: &Path, extra: &[&str]) -> (serde_json::Value, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .arg("simulate")
        .arg(recipe)
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (
        serde_json::from_slice(&std::fs::read(out.join("simulation.json")).unwrap()).unwrap(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
    )
}

/// The library's prediction from the run's files, built without the CLI.
/// Returns the predicted removal and its vibration-induced part (nm).
fn library_removal(d: &Path, bonnet: Bonnet) -> (Array2<f64>, Array2<f64>) {
    let before = read_surface(&d.join("before.dat")).unwrap();
    let path = read_path_csv(&d.join("path.csv")).unwrap();
    let grid = Grid::of(&before).unwrap();
    let tif = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
    let tool =
        ToolModel::from_source(&TifSource::Gaussian(tif), None, grid.dx_mm, grid.dy_mm).unwrap();
    let table: toml::Table = VIBRATION.parse().unwrap();
    let vib = table["vibration"].as_table().unwrap();
    let params =
        VibrationParams::from_parts(Some(vib), Some(1188.0), Some(0.6), Some(0.25), None).unwrap();
    let input = CouplingInput {
        grid,
        valid: Some(before.valid()),
        tool: &tool,
        path: &path,
        params: &params,
        pitch_mm: Some(PITCH_MM),
    };
    let p = predict(&input, bonnet, &CouplingOptions::default()).unwrap();
    (p.removal_nm(), p.maps.induced())
}

#[test]
fn simulate_with_vibration_reports_mechanisms_per_bonnet() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let recipe = make_run(d);
    let mut induced = Vec::new();
    for bonnet in ["original", "suppression"] {
        let out = d.join(format!("out_{bonnet}"));
        let v = simulate(&recipe, &out, &["--bonnet", bonnet]);
        assert_eq!(v["bonnet"], bonnet);
        assert!(v["mechanism_share_basis"]
            .as_str()
            .unwrap()
            .contains("all entries"));
        let mech = v["mechanisms"].as_array().unwrap();
        let names: Vec<&str> = mech.iter().map(|m| m["name"].as_str().unwrap()).collect();
        assert_eq!(names[0], "nominal_raster");
        for n in [
            "normal_offset",
            "lateral_jitter",
            "envelope",
            "dwell_execution",
        ] {
            assert!(names.contains(&n), "{n} missing in {names:?}");
        }
        let mut share_sum = 0.0;
        let mut power_sum = 0.0;
        for m in mech {
            let share = m["share"].as_f64().unwrap();
            let rms = m["msf_band_rms_nm"].as_f64().unwrap();
            assert!(share.is_finite() && (0.0..=1.0).contains(&share), "{m}");
            assert!(rms.is_finite() && rms >= 0.0, "{m}");
            assert!(m["enabled"].as_bool().is_some(), "{m}");
            share_sum += share;
            power_sum += rms * rms;
        }
        assert!((share_sum - 1.0).abs() < 1e-9, "shares sum to {share_sum}");
        // Each share is the entry's band power over the summed band power (brute force).
        for m in mech {
            let rms = m["msf_band_rms_nm"].as_f64().unwrap();
            let share = m["share"].as_f64().unwrap();
            assert!((share - rms * rms / power_sum).abs() < 1e-12, "{m}");
        }
        let vib = &v["vibration"];
        assert_eq!(vib["bonnet"], bonnet);
        let ripple = &v["ripple"];
        assert!(ripple["sigma1_nm"].as_f64().unwrap().is_finite());
        assert!(ripple["sigma_total_nm"].as_f64().unwrap().is_finite());
        assert_eq!(vib["ripple"], *ripple);
        induced.push(vib["induced_msf_band_rms_nm"].as_f64().unwrap());

        // Removal written by the CLI vs the library's predict() from the same files.
        let (lib, lib_induced) = library_removal(
            d,
            if bonnet == "original" {
                Bonnet::Original
            } else {
                Bonnet::Suppression
            },
        );
        let cli = read_surface(&out.join("predicted_removal.dat")).unwrap();
        assert_eq!(cli.heights_nm().dim(), lib.dim());
        let peak = lib.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let max_diff = cli
            .heights_nm()
            .iter()
            .zip(lib.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f64, f64::max);
        assert!(peak > 1.0, "removal peak {peak} nm");
        let induced_peak = lib_induced.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        // .dat counts are W/65536 with W = 632.8 nm: a read is within half a count.
        let half_count_nm = 0.5 * 632.8 / 65536.0;
        assert!(
            max_diff <= half_count_nm * (1.0 + 1e-6),
            "{bonnet}: max |cli - lib| = {max_diff} nm (peak {peak} nm)"
        );
        // The check is only meaningful when the coupling changes the removal by many counts.
        assert!(
            induced_peak > 20.0 * half_count_nm,
            "{bonnet}: induced peak {induced_peak} nm"
        );
        eprintln!(
            "{bonnet}: induced MSF {:.4e} nm, sigma1 {:.4} nm, max diff {max_diff:.2e} nm, induced peak {induced_peak:.3e} nm, mechanisms {}",
            induced.last().unwrap(),
            ripple["sigma1_nm"].as_f64().unwrap(),
            serde_json::to_string(mech).unwrap()
        );
    }
    assert!(
        induced[0] != induced[1],
        "bonnets give the same induced MSF"
    );

    // --no-vibration: the nominal removal only.
    let out = d.join("out_nominal");
    let v = simulate(&recipe, &out, &["--no-vibration"]);
    let mech = v["mechanisms"].as_array().unwrap();
    assert_eq!(mech.len(), 1);
    assert_eq!(mech[0]["name"], "nominal_raster");
    assert!((mech[0]["share"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    assert!(v["vibration"].is_null());
}

#[test]
fn simulate_sweep_rpm_writes_table_json_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let recipe = make_run(d);
    let out = d.join("out_sweep");
    let (v, stdout) = simulate_with_stdout(&recipe, &out, &["--sweep-rpm"]);
    // The one success line names the sweep it wrote (before: only simulation.json).
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    let sweep_csv = out.join("spindle_sweep.csv").display().to_string();
    assert!(
        stdout.contains(&format!(
            "spindle sweep (30 rows, 250 to 2000 rpm) in {sweep_csv} and spindle_sweep.png"
        )),
        "{stdout}"
    );
    let rows = v["spindle_sweep"].as_array().unwrap();
    // 250..2000 rpm in 125 rpm steps, both bonnets.
    assert_eq!(rows.len(), 15 * 2);
    assert!(out.join("spindle_sweep.png").is_file());
    let csv = std::fs::read_to_string(out.join("spindle_sweep.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 31);
    assert!(lines[0].starts_with("spindle_rpm,bonnet,"));
    for (row, line) in rows.iter().zip(&lines[1..]) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(
            f[0].parse::<f64>().unwrap(),
            row["spindle_rpm"].as_f64().unwrap()
        );
        assert_eq!(f[1], row["bonnet"].as_str().unwrap());
        let s1: f64 = f[6].parse().unwrap();
        assert!((s1 - row["ripple_sigma1_nm"].as_f64().unwrap()).abs() <= 1e-12 * s1.abs());
    }
    // Resonance: the original bonnet's induced MSF peaks inside the band, not at its ends, and
    // the damped suppression bonnet's peak is lower.
    let induced = |b: &str| -> Vec<f64> {
        rows.iter()
            .filter(|r| r["bonnet"] == b)
            .map(|r| r["induced_msf_band_rms_nm"].as_f64().unwrap())
            .collect()
    };
    let (o, s) = (induced("original"), induced("suppression"));
    let max = |v: &[f64]| v.iter().cloned().fold(f64::MIN, f64::max);
    eprintln!("induced MSF original {o:?}\nsuppression {s:?}");
    assert!(max(&s) < max(&o), "{} vs {}", max(&s), max(&o));
    let argmax = o.iter().position(|&v| v == max(&o)).unwrap();
    assert!(argmax > 0 && argmax + 1 < o.len(), "peak at index {argmax}");
}

#[test]
fn bad_vibration_table_is_one_line_exit_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let recipe = make_run(d);
    let text = std::fs::read_to_string(&recipe).unwrap() + "bogus_key = 1.0\n";
    let bad = d.join("bad_vib.toml");
    std::fs::write(&bad, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .arg("simulate")
        .arg(&bad)
        .arg("--out")
        .arg(d.join("out_bad"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("bad_vib.toml") && err.contains("bogus_key"),
        "{err}"
    );
}
