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
use bonnetlab::process::tif::GaussianTif;
use bonnetlab::process::{read_path_csv, Grid, RasterSpec};
use bonnetlab::surface::Surface;
use bonnetlab::vibration::coupling::{predict, CouplingInput, CouplingOptions};
use bonnetlab::vibration::params::{Bonnet, VibrationParams};
use ndarray::Array2;

const PITCH_MM: f64 = 2.0;

/// Writes before.dat, path.csv and recipe.toml into `d`; returns the recipe path.
fn make_run(d: &Path) -> std::path::PathBuf {
    let before = Array2::from_shape_fn((56, 64), |(i, j)| {
        let (x, y) = (j as f64 * 0.5, i as f64 * 0.5);
        10.0 * ((x - 16.0).powi(2) + (y - 14.0).powi(2)) / 256.0 + (x / 5.0).sin()
    });
    let s = Surface::new(before, Some(0.5), Some(0.5)).unwrap();
    write_surface(&d.join("before.dat"), &s, MapFormat::MetroProDat).unwrap();
    let mut spec = RasterSpec::over_rect((-4.0, 36.0), (-4.0, 32.0), PITCH_MM, 20.0);
    spec.sample_dt_s = 0.05;
    let path = spec.generate().unwrap();
    std::fs::write(d.join("path.csv"), path_to_csv(&path)).unwrap();
    let recipe = d.join("recipe.toml");
    std::fs::write(
        &recipe,
        "[measurement]\nbefore = \"before.dat\"\n[tif]\nmodel = { kind = \"gaussian\", sigma_mm = 1.0, \
         peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }\n[path]\nlog = \"path.csv\"\npitch_mm = 2.0\n\
         [process]\nbonnet = \"original\"\nspindle_rpm = 1000.0\noffset_mm = 0.6\n\
         inner_pressure_mpa = 0.25\n",
    )
    .unwrap();
    recipe
}

fn simulate(recipe: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let o = Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .arg("simulate")
        .arg(recipe)
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(out.join("simulation.json")).unwrap()).unwrap()
}

/// The library's prediction from the run's files, built without the CLI.
fn library_removal(d: &Path, bonnet: Bonnet) -> Array2<f64> {
    let before = read_surface(&d.join("before.dat")).unwrap();
    let path = read_path_csv(&d.join("path.csv")).unwrap();
    let tif = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
    let params =
        VibrationParams::from_parts(None, Some(1000.0), Some(0.6), Some(0.25), None).unwrap();
    let input = CouplingInput {
        grid: Grid::of(&before).unwrap(),
        valid: Some(before.valid()),
        base_tif: &tif,
        path: &path,
        params: &params,
        pitch_mm: Some(PITCH_MM),
    };
    predict(&input, bonnet, &CouplingOptions::default())
        .unwrap()
        .removal_nm()
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
        let lib = library_removal(
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
        // .dat counts are W/65536 with W = 632.8 nm: a read is within half a count.
        let half_count_nm = 0.5 * 632.8 / 65536.0;
        assert!(
            max_diff <= half_count_nm * (1.0 + 1e-6),
            "{bonnet}: max |cli - lib| = {max_diff} nm (peak {peak} nm)"
        );
        eprintln!(
            "{bonnet}: induced MSF {:.4e} nm, sigma1 {:.4} nm, max diff {max_diff:.2e} nm, mechanisms {}",
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
