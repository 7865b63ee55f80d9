//! Where the shared test data and the browser are, and what a test does when they are absent.
//!
//! The real Zygo maps and the public dwell cases live outside the repository, in `shared/data`
//! (`real/`, `external/`, `dwell/`). They are found at `$BONNETLAB_SHARED_DATA` when that is set,
//! else at `shared/data` beside the repository (the nearest ancestor of the crate that has one,
//! so `../shared/data` for a plain clone). The browser is `$BONNETLAB_CHROMIUM` when set, else the
//! first of `chromium`, `chromium-browser`, `google-chrome` on `PATH`.
//!
//! A test that needs the data carries
//!
//! ```text
//! #[cfg_attr(no_shared_data, ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)")]
//! ```
//!
//! and takes its folder from [`data_dir`]. The package's build script sets `no_shared_data` (and
//! `no_chromium`) only when the data (the browser) is absent and `CI` is not `true`: `cargo test`
//! then lists each such test as `ignored, needs ...` and the build prints a `NOT RUN` warning.
//! Whenever the test does run, [`data_dir`] panics with instructions if the data is missing, so a
//! test never passes without checking. Under `CI=true` nothing is ignored.
//!
//! The same file is compiled into the build scripts (`build.rs`, `crates/io/build.rs`) so the
//! build and the tests look in the same place.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// Environment variable naming the `shared/data` folder.
pub const DATA_ENV: &str = "BONNETLAB_SHARED_DATA";
/// Environment variable naming the Chromium binary.
pub const CHROMIUM_ENV: &str = "BONNETLAB_CHROMIUM";

/// The `shared/data` folder, or a message saying where it was looked for.
pub fn locate_data() -> Result<PathBuf, String> {
    if let Some(d) = std::env::var_os(DATA_ENV) {
        let d = PathBuf::from(d);
        return if d.join("real").is_dir() {
            Ok(d)
        } else {
            Err(format!(
                "{DATA_ENV}={} has no real/ folder (it must point at shared/data)",
                d.display()
            ))
        };
    }
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    for anc in here.ancestors() {
        let cand = anc.join("shared").join("data");
        if cand.join("real").is_dir() {
            return Ok(cand);
        }
    }
    Err(format!(
        "no shared/data beside {} and {DATA_ENV} is not set",
        here.display()
    ))
}

/// `shared/data/<sub>` (for example `"real"` or `"dwell"`). Panics, with what to do, when the
/// data is absent: call it only from a test marked as needing the data.
pub fn data_dir(sub: &str) -> PathBuf {
    match locate_data() {
        Ok(d) => {
            let p = d.join(sub);
            assert!(p.is_dir(), "shared data folder {} is missing", p.display());
            p
        }
        Err(why) => panic!(
            "this test needs the shared test data: {why}.\n\
             Put the shared/ folder beside the repository (../shared/data) or set \
             {DATA_ENV}=/path/to/shared/data, then run cargo test again."
        ),
    }
}

/// One file of `shared/data/<sub>`.
pub fn data_file(sub: &str, name: &str) -> PathBuf {
    let p = data_dir(sub).join(name);
    assert!(p.is_file(), "shared data file {} is missing", p.display());
    p
}

/// The Chromium binary, or why there is none (a variable naming a missing file is named).
pub fn locate_chromium() -> Result<PathBuf, String> {
    if let Some(p) = std::env::var_os(CHROMIUM_ENV) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(format!("{CHROMIUM_ENV}={} is not a file", p.display()))
        };
    }
    let names = [
        "chromium",
        "chromium-browser",
        "google-chrome",
        "google-chrome-stable",
    ];
    std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
        .flat_map(|dir| names.map(|n| dir.join(n)))
        .find(|p| p.is_file())
        .ok_or_else(|| format!("no {} on PATH", names.join(" / ")))
}

/// The Chromium binary; panics with what to do when there is none.
pub fn chromium() -> PathBuf {
    locate_chromium().unwrap_or_else(|why| {
        panic!(
            "this test needs headless Chromium ({why}): install Debian's `chromium` \
             (apt-get install chromium) or set {CHROMIUM_ENV}=/path/to/chromium"
        )
    })
}

/// What a build script prints and sets (`gate` is called from `build.rs`).
pub fn gate() {
    println!("cargo::rustc-check-cfg=cfg(no_shared_data)");
    println!("cargo::rustc-check-cfg=cfg(no_chromium)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-changed={}", file!());
    for v in [DATA_ENV, CHROMIUM_ENV, "CI", "PATH"] {
        println!("cargo::rerun-if-env-changed={v}");
    }
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    match locate_data() {
        Ok(d) => println!("cargo::rerun-if-changed={}", d.display()),
        Err(why) if ci => println!(
            "cargo::warning=CI=true and {why}: every test that needs shared/data will fail"
        ),
        Err(why) => {
            println!("cargo::rustc-cfg=no_shared_data");
            println!(
                "cargo::warning=NOT RUN: the tests that read shared/data ({why}); they are listed \
                 as ignored. Set {DATA_ENV}=/path/to/shared/data to run them."
            );
        }
    }
    if !std::env::var("CARGO_PKG_NAME").is_ok_and(|n| n == "bonnetlab") {
        return;
    }
    match locate_chromium() {
        Ok(p) => println!("cargo::rerun-if-changed={}", p.display()),
        Err(why) if ci => {
            println!("cargo::warning=CI=true and {why}: the browser test will fail")
        }
        Err(why) => {
            println!("cargo::rustc-cfg=no_chromium");
            println!(
                "cargo::warning=NOT RUN: the browser report test ({why}); \
                 apt-get install chromium or set {CHROMIUM_ENV}, then rebuild."
            );
        }
    }
}
