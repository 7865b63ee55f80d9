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
