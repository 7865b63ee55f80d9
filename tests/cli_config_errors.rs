//! Every configuration file (run recipe, dwell case, spot manifest, `[vibration]` table) is read
//! strictly through the CLI: an unknown key, a misspelt table, a wrong type and a TOML syntax
//! error each exit with code 2 and one line on stderr naming the file, the key with its table
//! and the nearest valid name (or what was expected, or the parser's cause with line/column).

use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

const RECIPE: &str = "[measurement]\nbefore = \"before.dat\"\n\n[tif]\nmodel = { kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0 }\n\n[path]\nlog = \"path.csv\"\npitch_mm = 3.0\n\n[process]\nspindle_rpm = 1000.0\n";

const CASE: &str = "surface = \"s.dat\"\npixel_mm = 0.5\n[tif]\nkind = \"gaussian\"\nsigma_mm = 1.0\ndiameter_mm = 6.0\npeak_rate_nm_per_s = 1.0\n[clear_aperture]\nrows = [10, 20]\ncols = [10, 30]\n";

const MANIFEST: &str = "[defaults]\ndwell_s = 120.0\nprecession_deg = 20.0\noffset_mm = 0.8\nspindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n\n[[spot]]\nfile = \"a.dat\"\nbonnet = \"original\"\n";

const VIBRATION: &str = "[process]\nspindle_rpm = 1000.0\n\n[vibration]\nfn_n = 3.0\nmu = 0.3\n";

/// Runs `args` with the config file (written as `name`) and returns (exit code, stderr).
fn run(dir: &Path, name: &str, text: &str, args: &[&str]) -> (Option<i32>, String) {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    let out = dir.join("out");
    let mut cmd = bin();
    for a in args {
        match *a {
            "FILE" => cmd.arg(&p),
            "OUT" => cmd.arg(&out),
            a if a.contains("FILE") => cmd.arg(a.replace("FILE", p.to_str().unwrap())),
            a => cmd.arg(a),
        };
    }
    let o = cmd.output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// (file text, what stderr must contain).
type Case = (String, Vec<&'static str>);

fn check(kind: &str, name: &str, args: &[&str], good: &str, cases: Vec<Case>) {
    let dir = tempfile::tempdir().unwrap();
    for (text, needles) in cases {
        assert_ne!(text, good, "{kind}: the case must change the file");
        let (code, err) = run(dir.path(), name, &text, args);
        assert_eq!(code, Some(2), "{kind}: {err}");
        let line = err.trim_end();
        assert_eq!(line.lines().count(), 1, "{kind}: one line: {err}");
        assert!(line.contains(name), "{kind}: names the file: {err}");
        for n in needles {
            assert!(line.contains(n), "{kind}: `{n}` missing in: {err}");
        }
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn run_recipe_errors_name_file_key_and_nearest_name() {
    let r = |a: &str, b: &str| RECIPE.replace(a, b);
    check(
        "recipe",
        "run.toml",
        &["simulate", "FILE", "--out", "OUT"],
        RECIPE,
        vec![
            (
                r("pitch_mm = 3.0", "pich = 3.0"),
                vec!["[path] pich", "unknown key", "did you mean `pitch_mm`?"],
            ),
            (
                r("[process]", "[proces]"),
                vec!["[proces]", "unknown table", "did you mean [process]?"],
            ),
            (
                r("sigma_mm = 1.0", "sigmma = 1.0"),
                vec!["[tif.model] sigmma", "did you mean `sigma_mm`?"],
            ),
            (
                r("pitch_mm = 3.0", "pitch_mm = \"3\""),
                vec!["[path] pitch_mm", "expected a number", "found string"],
            ),
            (
                r("[path]", "[path"),
                vec![
                    "TOML",
                    "syntax error",
                    "unclosed table, expected `]`",
                    "line 7, column",
                ],
            ),
        ],
    );
}

#[test]
fn dwell_case_errors_name_file_key_and_nearest_name() {
    let r = |a: &str, b: &str| CASE.replace(a, b);
    check(
        "dwell case",
        "case.toml",
        &["dwell", "FILE", "--out", "OUT"],
        CASE,
        vec![
            (
                r("sigma_mm", "sigma_nm"),
                vec!["[tif] sigma_nm", "unknown key", "did you mean `sigma_mm`?"],
            ),
            (
                r("[clear_aperture]", "[clear_apperture]"),
                vec!["[clear_apperture]", "did you mean [clear_aperture]?"],
            ),
            (
                r("pixel_mm = 0.5", "pixel_mm = \"0.5\""),
                vec!["pixel_mm", "expected a number"],
            ),
            (
                r("\"gaussian\"", "\"gausian\""),
                vec![
                    "[tif] kind",
                    "unknown TIF model \"gausian\"",
                    "expected one of \"gaussian\"",
                    "did you mean \"gaussian\"?",
                ],
            ),
            (
                r("rows = [10, 20]", "rows = [10, 20"),
                vec!["TOML", "syntax error", "expected `,` at line 10, column 1"],
            ),
        ],
    );
}

#[test]
fn spot_manifest_errors_name_file_key_and_nearest_name() {
    let r = |a: &str, b: &str| MANIFEST.replace(a, b);
    check(
        "manifest",
        "manifest.toml",
        &["spots", "FILE", "--out", "OUT"],
        MANIFEST,
        vec![
            (
                r("bonnet = ", "bonet = "),
                vec!["[spot] bonet", "unknown key", "did you mean `bonnet`?"],
            ),
            (
                r("[defaults]", "[defualts]"),
                vec!["[defualts]", "did you mean [defaults]?"],
            ),
            (
                r("offset_mm = 0.8", "offset_mm = \"0.8\""),
                vec!["[defaults] offset_mm", "expected a number"],
            ),
            (
                r("file = \"a.dat\"", "file = \"a.dat"),
                vec!["TOML", "syntax error", "line 9"],
            ),
        ],
    );
}

#[test]
fn vibration_table_errors_name_file_key_and_nearest_name() {
    let r = |a: &str, b: &str| VIBRATION.replace(a, b);
    check(
        "vibration",
        "vib.toml",
        &["vibration", "FILE", "--json", "-"],
        VIBRATION,
        vec![
            (
                r("fn_n = 3.0", "fn_nn = 3.0"),
                vec!["[vibration] fn_nn", "unknown key", "did you mean `fn_n`?"],
            ),
            (
                r("[vibration]", "[vibraton]"),
                vec!["[vibraton]", "did you mean [vibration]?"],
            ),
            (
                r("mu = 0.3", "mu = \"high\""),
                vec!["[vibration] mu", "expected a number"],
            ),
            (
                r("mu = 0.3", "mu = "),
                vec!["TOML", "syntax error", "line 6"],
            ),
        ],
    );
}

/// The commands that read a run recipe (FILE: the recipe, OUT: an output directory).
const RECIPE_READERS: [&[&str]; 4] = [
    &["simulate", "FILE", "--out", "OUT"],
    &["calibrate", "FILE", "--out", "OUT"],
    &[
        "compare", "--run", "a=FILE", "--run", "b=FILE", "--out", "OUT",
    ],
    &["vibration", "FILE", "--json", "-"],
];

/// Every command that reads a run recipe (`simulate`, `calibrate`, `compare --run`,
/// `vibration`) rejects the same unknown table, unknown key and syntax error the same way:
/// exit 2, one line naming the file, the key and the nearest valid name, or the parser's cause.
#[test]
fn every_recipe_reader_rejects_unknown_tables_and_keys() {
    let r = |a: &str, b: &str| RECIPE.replace(a, b);
    for args in RECIPE_READERS {
        check(
            args[0],
            "run.toml",
            args,
            RECIPE,
            vec![
                (
                    r("[process]", "[proces]"),
                    vec!["[proces]", "unknown table", "did you mean [process]?"],
                ),
                (
                    r("spindle_rpm", "spindel_rpm"),
                    vec![
                        "[process] spindel_rpm",
                        "unknown key",
                        "did you mean `spindle_rpm`?",
                    ],
                ),
                (
                    r("[path]", "[path"),
                    vec!["TOML", "unclosed table, expected `]`", "line 7, column"],
                ),
            ],
        );
    }
}

/// A typo in a recipe's `[vibration]` table is an error in every command that reads the recipe,
/// including `calibrate`, which does not model vibration (it was ignored there), and is named
/// once (`compare` named the table twice). The run is the bundled sample's, so each command
/// gets as far as the table.
#[test]
fn a_vibration_typo_in_a_run_recipe_is_an_error_everywhere() {
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/original");
    let text = std::fs::read_to_string(sample.join("recipe.toml")).unwrap();
    let mut good = text.clone();
    for f in ["before.dat", "after.dat", "spot.dat", "path.csv"] {
        let abs = format!("{:?}", sample.join(f).to_str().unwrap());
        good = good.replace(&format!("\"{f}\""), &abs);
    }
    assert_ne!(good, text, "the sample recipe names its files");
    assert!(good.contains("\nzeta1 = "), "the sample sets zeta1: {good}");
    let typo = good.replace("\nzeta1 = ", "\nzeta_1 = ");
    for args in RECIPE_READERS {
        check(
            args[0],
            "run.toml",
            args,
            &good,
            vec![(
                typo.clone(),
                vec![
                    "run.toml: [vibration] zeta_1: unknown key",
                    "did you mean `zeta1`?",
                ],
            )],
        );
    }
}
