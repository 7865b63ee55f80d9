//! The layering of the `bonnetlab` crate, enforced on its source (issue 14; the way prysm keeps
//! a test for an architectural rule). Data flows one way: the CLI parses arguments, calls one
//! pipeline and writes its outputs; a pipeline reads its inputs and computes, returning typed
//! results; `report` renders results. The rules, checked on the source text with comments,
//! string literals and `#[cfg(test)]` modules left out:
//!
//! 1. `src/report/` reads no file: none of [`READS`] appears (no `std::fs`, no map, path-log,
//!    recipe or manifest reader). Its inputs are result structs.
//! 2. `src/pipeline/` neither renders nor knows the CLI: none of [`PIPELINE_FORBIDDEN`]
//!    (`crate::cli`, `crate::report`, printing, progress bars, clap).
//! 3. `src/cli/` does no arithmetic on maps: it names no `ndarray` item and no height array
//!    ([`CLI_FORBIDDEN`]), and it calls no free function of the analysis crates
//!    (`bonnetlab-surface`, `-spectrum`, `-process`, `-vibration`, `-calibrate`, `-spots`):
//!    every `pub fn` declared at the top level of a module of those crates is a computing
//!    entry point, except the parsers and number formatters listed in [`CLI_MAY_CALL`]. A
//!    call is `NAME(` not preceded by `.` (a method) or by `Type::` (an associated function);
//!    names the file defines itself or imports from `crate::`/`super::` are its own, and so
//!    are calls through a module imported from this crate (`bonnets::compare_runs(`).
//!    Files in [`CLI_NOT_YET`] hold pipeline code that has not moved yet; each must still
//!    violate the rule (so the list only shrinks) and each is named with what is left.
//!
//! Each rule's scanner is unit-tested below on planted text: it reports the violation, and
//! nothing for the same text inside a test module, a comment or a string.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Rule 1: what reading a file looks like.
const READS: [&str; 12] = [
    "std::fs",
    "fs::",
    "File::open",
    "read_to_string",
    "read_dir",
    "read_surface",
    "read_path_csv",
    "read_map",
    "read_text_input",
    "load_recipe",
    "Recipe::load",
    "RecipeDoc::load",
];

/// Rule 2: what rendering or knowing the CLI looks like.
const PIPELINE_FORBIDDEN: [&str; 8] = [
    "crate::cli",
    "crate::report",
    "println!",
    "eprintln!",
    "print!",
    "indicatif",
    "clap::",
    "super::super",
];

/// Rule 3a: array arithmetic on maps.
const CLI_FORBIDDEN: [&str; 5] = ["ndarray", "Array2", "heights_nm", "with_heights", "Zip::"];

/// Rule 3b: top-level functions of the analysis crates that read, parse or format and may be
/// called from the CLI.
const CLI_MAY_CALL: [&str; 7] = [
    // number formatting (bonnetlab_surface::format)
    "sig",
    "fixed",
    "f32_value",
    // writing a fitted model as a recipe table (bonnetlab_spots::export)
    "model_toml",
    // parsing inputs
    "parse_manifest",
    "read_path_csv",
    "fmt_sig",
];

/// CLI files that still compute (pipelines not moved yet), with what is left in them.
const CLI_NOT_YET: [(&str, &str); 0] = [];

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(&d)
            .unwrap_or_else(|e| panic!("{}: {e}", d.display()))
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    assert!(!out.is_empty(), "no source under {}", dir.display());
    out
}

/// The code of a file without comments, string and char literals (replaced by spaces or
/// empty literals) and without `#[cfg(test)]` items (a test module may read its fixtures).
fn code_of(text: &str) -> String {
    let b: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            i += 2;
            while i + 1 < b.len() && !(b[i] == '*' && b[i + 1] == '/') {
                i += 1;
            }
            i += 2;
        } else if c == 'r' && (next == Some('"') || next == Some('#')) && !ident_char_before(&b, i)
        {
            // Raw string r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while j < b.len() && b[j] == '#' {
                hashes += 1;
                j += 1;
            }
            if j < b.len() && b[j] == '"' {
                j += 1;
                loop {
                    if j >= b.len() {
                        break;
                    }
                    if b[j] == '"' && (0..hashes).all(|k| b.get(j + 1 + k) == Some(&'#')) {
                        j += 1 + hashes;
                        break;
                    }
                    j += 1;
                }
                out.push_str("\"\"");
                i = j;
            } else {
                out.push(c);
                i += 1;
            }
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                if b[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("\"\"");
        } else if c == '\'' && b.get(i + 2) == Some(&'\'') {
            out.push_str("' '");
            i += 3;
        } else if c == '\'' && next == Some('\\') {
            let mut j = i + 2;
            while j < b.len() && b[j] != '\'' {
                j += 1;
            }
            out.push_str("' '");
            i = j + 1;
        } else {
            out.push(c);
            i += 1;
        }
    }
    strip_cfg_test(&out)
}

fn ident_char_before(b: &[char], i: usize) -> bool {
    i > 0 && (b[i - 1].is_alphanumeric() || b[i - 1] == '_')
}

/// Removes every item that follows `#[cfg(test)]` (up to its matching closing brace, or its
/// semicolon).
fn strip_cfg_test(code: &str) -> String {
    let mut out = String::new();
    let mut rest = code;
    while let Some(k) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..k]);
        let after = &rest[k..];
        let mut depth = 0i32;
        let mut end = after.len();
        for (j, ch) in after.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = j + 1;
                        break;
                    }
                }
                ';' if depth == 0 => {
                    end = j + 1;
                    break;
                }
                _ => {}
            }
        }
        rest = &after[end..];
    }
    out.push_str(rest);
    out
}

/// Rule 1 and 2 scanner: the forbidden tokens that occur in the code, with their lines.
fn forbidden_tokens(text: &str, tokens: &[&str]) -> Vec<String> {
    let code = code_of(text);
    let mut hits = Vec::new();
    for (n, line) in code.lines().enumerate() {
        for t in tokens {
            if line.contains(t) {
                hits.push(format!("line {}: `{t}`", n + 1));
            }
        }
    }
    hits
}

/// The names of the top-level `pub fn`s of the analysis crates.
fn analysis_functions() -> BTreeSet<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates");
    let mut names = BTreeSet::new();
    for krate in [
        "surface",
        "spectrum",
        "process",
        "vibration",
        "calibrate",
        "spots",
    ] {
        for f in rust_files(&root.join(krate).join("src")) {
            let text = std::fs::read_to_string(&f).unwrap();
            for line in code_of(&text).lines() {
                if let Some(rest) = line.strip_prefix("pub fn ") {
                    let name: String = rest
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    names.insert(name);
                }
            }
        }
    }
    names
}

/// Identifiers of a code text (with the char before and the text after each).
fn idents(code: &str) -> Vec<(usize, String)> {
    let b: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if (b[i].is_alphabetic() || b[i] == '_') && !ident_char_before(&b, i) {
            let s = i;
            while i < b.len() && (b[i].is_alphanumeric() || b[i] == '_') {
                i += 1;
            }
            out.push((s, b[s..i].iter().collect()));
        } else {
            i += 1;
        }
    }
    out
}

/// Rule 3 scanner: the array tokens and the calls of `compute` functions in a CLI file's text.
fn cli_violations(text: &str, compute: &BTreeSet<String>) -> Vec<String> {
    let mut hits = forbidden_tokens(text, &CLI_FORBIDDEN);
    let code = code_of(text);
    let chars: Vec<char> = code.chars().collect();
    let ids = idents(&code);
    // Names the file defines or imports from this crate are its own.
    let mut own: BTreeSet<String> = BTreeSet::new();
    for w in ids.windows(2) {
        if w[0].1 == "fn" {
            own.insert(w[1].1.clone());
        }
    }
    for stmt in code.split(';') {
        let s = stmt.trim_start();
        let s = s.strip_prefix("pub ").unwrap_or(s);
        let s = s.strip_prefix("pub(crate) ").unwrap_or(s);
        if let Some(u) = s.strip_prefix("use ") {
            if u.starts_with("crate::") || u.starts_with("super::") || u.starts_with("self::") {
                for (_, n) in idents(u) {
                    own.insert(n);
                }
            }
        }
    }
    for (pos, name) in &ids {
        let end = pos + name.chars().count();
        if chars.get(end) != Some(&'(') || !compute.contains(name) {
            continue;
        }
        if CLI_MAY_CALL.contains(&name.as_str()) || own.contains(name) {
            continue;
        }
        let before: String = chars[pos.saturating_sub(80)..*pos].iter().collect();
        let before = before.trim_end();
        if before.ends_with('.') || before.ends_with("fn") {
            continue;
        }
        if let Some(path) = before.strip_suffix("::") {
            // `Type::name(` is an associated function, not a free one.
            let seg: String = path
                .chars()
                .rev()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            if seg.chars().next().is_some_and(char::is_uppercase) {
                continue;
            }
            // `crate::…::name(` or `module::name(` with the module imported from this crate
            // is a pipeline call.
            if seg == "crate" || seg == "super" || seg == "self" || own.contains(&seg) {
                continue;
            }
        }
        let line = chars[..*pos].iter().filter(|&&c| c == '\n').count() + 1;
        hits.push(format!("line {line}: calls `{name}(`"));
    }
    hits
}

fn rel(p: &Path) -> String {
    p.strip_prefix(src()).unwrap_or(p).display().to_string()
}

#[test]
fn report_reads_no_file() {
    let mut bad = Vec::new();
    for f in rust_files(&src().join("report")) {
        let text = std::fs::read_to_string(&f).unwrap();
        for h in forbidden_tokens(&text, &READS) {
            bad.push(format!("src/{}: {h}", rel(&f)));
        }
    }
    assert!(bad.is_empty(), "report/ reads files:\n{}", bad.join("\n"));
}

#[test]
fn pipelines_render_nothing_and_know_no_cli() {
    let mut bad = Vec::new();
    for f in rust_files(&src().join("pipeline")) {
        let text = std::fs::read_to_string(&f).unwrap();
        for h in forbidden_tokens(&text, &PIPELINE_FORBIDDEN) {
            bad.push(format!("src/{}: {h}", rel(&f)));
        }
    }
    assert!(
        bad.is_empty(),
        "pipeline/ renders or calls the CLI:\n{}",
        bad.join("\n")
    );
}

#[test]
fn cli_does_no_arithmetic_on_maps() {
    let compute = analysis_functions();
    // The scan must see the analysis crates' entry points, or it checks nothing.
    for must in ["psd_xy", "ripple_from_psds", "remove_terms", "height_stats"] {
        assert!(
            compute.contains(must),
            "{must} not found in the analysis crates"
        );
    }
    let mut bad = Vec::new();
    let mut still = Vec::new();
    for f in rust_files(&src().join("cli")) {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        let text = std::fs::read_to_string(&f).unwrap();
        let hits = cli_violations(&text, &compute);
        match CLI_NOT_YET.iter().find(|(n, _)| *n == name) {
            Some(_) if hits.is_empty() => still.push(name),
            Some(_) => {}
            None => bad.extend(hits.into_iter().map(|h| format!("src/cli/{name}: {h}"))),
        }
    }
    assert!(
        bad.is_empty(),
        "cli/ computes on maps (move it into a pipeline):\n{}",
        bad.join("\n")
    );
    assert!(
        still.is_empty(),
        "{still:?} no longer compute: take them off CLI_NOT_YET"
    );
}

/// The scanners on planted text: each rule fails on a planted violation.
#[test]
fn scanners_find_planted_violations() {
    let reads = "use std::path::Path;\nfn f(p: &Path) -> String {\n    std::fs::read_to_string(p).unwrap()\n}\n";
    let hits = forbidden_tokens(reads, &READS);
    assert!(hits.iter().any(|h| h.starts_with("line 3")), "{hits:?}");
    // The same read in a test module, a comment or a string is not code of the layer.
    let exempt = "// std::fs::read_to_string\nconst S: &str = \"File::open\";\n#[cfg(test)]\nmod tests {\n    fn f() { std::fs::read_to_string(\"x\").unwrap(); }\n}\n";
    assert!(forbidden_tokens(exempt, &READS).is_empty());

    let render = "pub fn run() {\n    println!(\"done\");\n    crate::report::psd::summary();\n}\n";
    assert_eq!(forbidden_tokens(render, &PIPELINE_FORBIDDEN).len(), 2); // println!, report

    let compute: BTreeSet<String> = ["psd_xy", "sig", "predict"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let planted = "use bonnetlab_spectrum::psd_xy;\nfn run() {\n    let (x, y) = psd_xy(&s, &o);\n    let z = bonnetlab_process::simulate::predict(a);\n}\n";
    let hits = cli_violations(planted, &compute);
    assert_eq!(hits.len(), 2, "{hits:?}");
    assert!(hits[0].starts_with("line 3") && hits[1].starts_with("line 4"));
    let arrays = "fn run(a: ndarray::Array2<f64>) {}\n";
    assert!(!cli_violations(arrays, &compute).is_empty());
    // Calling the pipeline, a method, an associated function or a formatter is not computing.
    let clean = "use crate::pipeline::psd::psd_xy;\nuse crate::pipeline::sim;\nfn run() {\n    psd_xy(&a);\n    sim::predict(&b);\n    s.predict(1);\n    Model::predict(2);\n    let t = sig(1.0, 3);\n}\n";
    let hits = cli_violations(clean, &compute);
    assert!(hits.is_empty(), "{hits:?}");
}
