//! Regression tests for what the structured fuzzing of recipes, path logs, spot manifests and
//! dwell cases found (issue 18; reports/reliability.md section 8). Each goes through the
//! library entry point the CLI uses, and fails on the old behaviour:
//!
//! - a key or value of a million characters was echoed whole in the error (a "one-line"
//!   message of a megabyte), and finding the nearest valid key for it compared every prefix of
//!   every candidate with the whole name (seconds per error: `fuzz_readers --reader recipe-x
//!   --seed 7 --replay 2748`, and 736 for a `[vibration]` key);
//! - a manifest of 100 000 `[[spot]]` tables (7.9 MB, under the 16 MiB limit) counted the line
//!   of every spot from the start of the text: minutes (`--reader manifest-x --seed 7
//!   --replay 289`);
//! - the inputs of the earlier byte-mutation runs in `tests/corpus/fuzz-findings/` (a quoted
//!   CSV field or a recipe string holding line breaks) still give one line naming the file.
//!
//! The million-character inputs are built here rather than stored (the harness rebuilds the
//! exact ones with `--replay`).

use std::path::{Path, PathBuf};

use bonnetlab::process::dwell::case::DwellCase;
use bonnetlab::process::path::log::read_path_from;
use bonnetlab::process::recipe::RecipeDoc;
use bonnetlab::process::Recipe;
use bonnetlab::spots::manifest::parse_manifest;
use bonnetlab::vibration::params::VibrationParams;

const MODEL_RECIPE: &str = "[measurement]\nbefore = \"b.csv\"\n[tif]\n\
model = { kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0, diameter_mm = 10.0 }\n\
[path]\nlog = \"p.csv\"\n";

const CASE: &str = "surface = \"case.dat\"\npixel_mm = 0.36\n\n[tif]\nkind = \"gaussian\"\n\
sigma_mm = 1.0\ndiameter_mm = 10.0\npeak_rate_nm_per_s = 10.0\n\n[clear_aperture]\n\
rows = [19, 62]\ncols = [31, 558]\n";

const MANIFEST_HEAD: &str = "[defaults]\ndwell_s = 120.0\nprecession_deg = 20.0\n\
spindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n";

const N: usize = 1_000_000;

fn findings() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/fuzz-findings")
}

/// One line, short, naming `file`, with the long word cut to its length.
fn short(msg: &str, file: &str) {
    assert!(!msg.contains('\n'), "{msg}");
    assert!(msg.len() < 400, "{} bytes: {}", msg.len(), &msg[..400]);
    assert!(msg.contains(file), "{msg}");
    assert!(msg.contains(" characters)"), "{msg}");
}

#[test]
fn a_million_character_key_or_value_is_cut_in_every_strict_reader() {
    let long = "k".repeat(N);
    // Recipe: an unknown key in a typed table, and a string where a number belongs.
    let text = format!("{MODEL_RECIPE}[process]\n{long} = 1\n");
    let e = Recipe::parse(&text, Path::new("r.toml")).unwrap_err();
    short(&e.to_string(), "r.toml");
    assert!(e.to_string().contains("(1000000 characters)"), "{e}");
    let text = MODEL_RECIPE.replace(
        "log = \"p.csv\"",
        &format!("log = \"p.csv\"\npitch_mm = \"{long}\""),
    );
    let e = Recipe::parse(&text, Path::new("r.toml")).unwrap_err();
    short(&e.to_string(), "r.toml");
    // The raw [vibration] table, read strictly by the vibration model (`vibration RECIPE`).
    let text = format!("{MODEL_RECIPE}[vibration]\n{long} = 1\n");
    let doc = RecipeDoc::parse(&text, Path::new("r.toml")).unwrap();
    let e = VibrationParams::from_recipe(&doc).unwrap_err().to_string();
    assert!(!e.contains('\n') && e.len() < 400, "{} bytes", e.len());
    assert!(e.contains(" characters)"), "{e}");
    // Dwell case.
    let text = format!("{CASE}{long} = 1\n");
    let e = DwellCase::parse(&text, Path::new("case.toml")).unwrap_err();
    short(&e.to_string(), "case.toml");
    // Spot manifest.
    let text = format!("{MANIFEST_HEAD}{long} = 2\n[[spot]]\nfile = \"a.dat\"\nbonnet = \"original\"\noffset_mm = 0.2\n");
    let e = parse_manifest(Path::new("m.toml"), &text).unwrap_err();
    let msg = e.to_string();
    assert!(
        !msg.contains('\n') && msg.len() < 400,
        "{} bytes",
        msg.len()
    );
    assert!(msg.contains(" characters)"), "{msg}");
}

#[test]
fn a_manifest_of_100000_spots_is_read_and_names_the_right_line() {
    // 100000 different maps (one map listed twice is refused).
    let mut text = String::from(MANIFEST_HEAD);
    for k in 0..100_000 {
        text.push_str(&format!(
            "[[spot]]\nfile = \"b{k}.dat\"\nbonnet = \"suppression\"\noffset_mm = 0.4\n"
        ));
    }
    let m = parse_manifest(Path::new("m.toml"), &text).unwrap();
    assert_eq!(m.spots.len(), 100_000);
    // Spot k (0-based) starts on line 6 + 4 k.
    assert_eq!(m.spots[0].line, 6);
    assert_eq!(m.spots[99_999].line, 6 + 4 * 99_999);
    // A bad value in the last spot is named at its line.
    text.push_str("[[spot]]\nfile = \"c.dat\"\nbonnet = \"original\"\noffset_mm = -1\n");
    let e = parse_manifest(Path::new("m.toml"), &text)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!(
            "line {}: spot[100001] key 'offset_mm'",
            6 + 4 * 100_000
        )),
        "{e}"
    );
}

#[test]
fn earlier_byte_mutation_findings_give_one_line_naming_the_file() {
    let p = findings().join("path-multiline-error.csv");
    let e = read_path_from(&std::fs::read(&p).unwrap()[..], &p)
        .unwrap_err()
        .to_string();
    assert!(!e.contains('\n'), "{e}");
    assert!(e.contains("path-multiline-error.csv"), "{e}");
    let p = findings().join("recipe-multiline-error.toml");
    let e = Recipe::load(&p).unwrap_err().to_string();
    assert!(!e.contains('\n'), "{e}");
    assert!(e.contains("recipe-multiline-error.toml"), "{e}");
}
