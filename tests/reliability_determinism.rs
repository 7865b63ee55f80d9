//! Determinism (issue 8): the same command on the same input gives byte-identical output,
//! across runs and across thread counts (form fits reduce row bands in a fixed order).

use std::path::PathBuf;
use std::process::Command;

#[path = "common/shared_data.rs"]
mod shared_data;

fn real(name: &str) -> PathBuf {
    shared_data::data_file("real", name)
}

fn run(args: &[&str], threads: Option<&str>) -> Vec<u8> {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bonnetlab"));
    c.args(args);
    if let Some(t) = threads {
        c.env("RAYON_NUM_THREADS", t);
    }
    let out = c.output().expect("binary runs");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!out.stdout.is_empty());
    out.stdout
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn stats_json_is_byte_identical_across_runs_and_thread_counts() {
    let file = real("prysm_valid_zygo_dat_file.dat");
    let f = file.to_str().unwrap();
    for remove in ["piston,tilt", "zernike37"] {
        let args = ["stats", f, "--remove", remove, "--pvr", "--json"];
        let a = run(&args, None);
        let b = run(&args, None);
        let one = run(&args, Some("1"));
        assert_eq!(a, b, "{remove}: two runs differ");
        assert_eq!(a, one, "{remove}: one thread differs from many");
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn psd_json_is_byte_identical_across_runs() {
    let file = real("pyxsurf_01_801B.dat");
    let args = ["psd", file.to_str().unwrap(), "--json", "--pitch-mm", "3"];
    let a = run(&args, None);
    let b = run(&args, None);
    let one = run(&args, Some("1"));
    assert_eq!(a, b, "two runs differ");
    assert_eq!(a, one, "one thread differs from many");
}

/// The calibration evaluates candidates side by side and keeps several forward-model
/// workspaces per channel; its JSON must still be the same bytes on every run and thread count.
/// A path wiggle (every candidate column then walks a perturbed path, with line phases that
/// build new kernels) and a wider spot (the scale scan, one forward model per scale).
#[test]
fn calibrate_json_is_byte_identical_across_runs_and_thread_counts() {
    use bonnetlab::calibrate::synth::write::write_run;
    use bonnetlab::calibrate::synth::{generate, Injected, SynthConfig};
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig {
        seed: 15,
        effects: vec![
            Injected::reference_wiggle(),
            Injected::TifScale { scale: 1.1 },
        ],
        ..SynthConfig::default()
    };
    let recipe = write_run(dir.path(), &generate(&cfg).unwrap()).unwrap();
    let r = recipe.to_str().unwrap();
    let json = |name: &str, threads: Option<&str>| -> Vec<u8> {
        let out = dir.path().join(name);
        run(&["calibrate", r, "--json", out.to_str().unwrap()], threads);
        std::fs::read(&out).unwrap()
    };
    let a = json("a.json", None);
    let v: serde_json::Value = serde_json::from_slice(&a).unwrap();
    let kinds: Vec<&str> = v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|e| e["kind"].as_str())
        .collect();
    assert!(kinds.contains(&"periodic_path_error"), "{kinds:?}");
    assert_eq!(a, json("b.json", None), "two runs differ");
    assert_eq!(
        a,
        json("one.json", Some("1")),
        "one thread differs from many"
    );
    assert_eq!(
        a,
        json("four.json", Some("4")),
        "four threads differ from two"
    );
}
