//! Issue #17: the long-running commands show progress on a terminal (calibrate, spots, simulate with
//! `--sweep-rpm`) and print nothing extra when stderr is not a terminal. The terminal is a
//! pseudo-terminal made by util-linux `script`, which the test needs (it fails, naming it, when
//! `script` is missing; it never passes without running).

use std::path::{Path, PathBuf};
use std::process::Command;

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_bonnetlab")
}

fn samples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples")
}

/// Single-quote one argument for `sh -c`.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// Runs the CLI with `args` on a pseudo-terminal; returns everything the terminal showed.
fn on_a_terminal(args: &[String]) -> String {
    let line = std::iter::once(exe().to_string())
        .chain(args.iter().cloned())
        .map(|a| quote(&a))
        .collect::<Vec<_>>()
        .join(" ");
    let out = Command::new("script")
        .args(["-qec", &line, "/dev/null"])
        .output()
        .expect("util-linux `script` is needed to run a command on a pseudo-terminal");
    let shown = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "exit {:?}: {shown}",
        out.status.code()
    );
    shown
}

/// Runs the CLI with stdout and stderr as pipes; returns stderr.
fn piped_stderr(args: &[String]) -> String {
    let out = Command::new(exe()).args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "exit {:?}: {err}", out.status.code());
    err
}

/// Whether `text` holds `label` followed by a space and a digit (a spinner's elapsed time or a
/// bar's position), as the progress templates draw them.
fn drawn(text: &str, label: &str) -> bool {
    text.match_indices(label).any(|(i, m)| {
        let rest = &text[i + m.len()..];
        rest.starts_with(' ') && rest[1..].starts_with(|c: char| c.is_ascii_digit() || c == '[')
    })
}

#[test]
fn calibrate_shows_a_spinner_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = samples().join("suppression/recipe.toml");
    let args = |name: &str| -> Vec<String> {
        vec![
            "calibrate".into(),
            recipe.display().to_string(),
            "--json".into(),
            dir.path().join(name).display().to_string(),
        ]
    };
    let shown = on_a_terminal(&args("t.json"));
    assert!(
        drawn(&shown, "calibrate"),
        "no spinner on the terminal: {shown:?}"
    );
    let err = piped_stderr(&args("p.json"));
    assert!(err.is_empty(), "stderr not a terminal, yet: {err:?}");
}

#[test]
fn simulate_sweep_shows_a_bar_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = samples().join("original/recipe.toml");
    let args = |name: &str| -> Vec<String> {
        vec![
            "simulate".into(),
            recipe.display().to_string(),
            "--sweep-rpm".into(),
            "--out".into(),
            dir.path().join(name).display().to_string(),
        ]
    };
    let shown = on_a_terminal(&args("t"));
    assert!(
        drawn(&shown, "simulate"),
        "no progress on the terminal: {shown:?}"
    );
    let err = piped_stderr(&args("p"));
    assert!(err.is_empty(), "stderr not a terminal, yet: {err:?}");
}

#[test]
fn spots_shows_a_bar_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let made = Command::new(exe())
        .args(["spots", "--make-sample"])
        .arg(d.join("in"))
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let args = |name: &str| -> Vec<String> {
        vec![
            "spots".into(),
            d.join("in/manifest.toml").display().to_string(),
            "--out".into(),
            d.join(name).display().to_string(),
        ]
    };
    let shown = on_a_terminal(&args("t"));
    assert!(
        drawn(&shown, "reading spot maps"),
        "no progress on the terminal: {shown:?}"
    );
    let err = piped_stderr(&args("p"));
    assert!(err.is_empty(), "stderr not a terminal, yet: {err:?}");
}
