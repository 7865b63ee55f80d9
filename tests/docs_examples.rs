//! The worked examples of docs/ run as written: the spots manifest of docs/formats.md against
//! the maps `spots --make-sample` writes, and the `compare` command docs/cli.md gives as the
//! demo's equivalent against freshly generated samples (same runs and numbers as `demo`).

use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn doc(name: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("docs")
            .join(name),
    )
    .unwrap()
}

/// The fenced block right after `<!-- example: NAME -->`.
fn example(text: &str, name: &str) -> String {
    let tag = format!("<!-- example: {name} -->");
    let rest = &text[text
        .find(&tag)
        .unwrap_or_else(|| panic!("no example {name}"))..];
    let start = rest.find("```").unwrap();
    let body = &rest[start..];
    let body = &body[body.find('\n').unwrap() + 1..];
    body[..body.find("```").unwrap()].to_string()
}

#[test]
fn spots_manifest_example_runs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("sweep");
    let o = bin()
        .args(["spots", "--make-sample"])
        .arg(&d)
        .output()
        .unwrap();
    assert!(o.status.success());
    std::fs::write(
        d.join("manifest.toml"),
        example(&doc("formats.md"), "spots-manifest"),
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = bin()
        .arg("spots")
        .arg(d.join("manifest.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["spots"].as_array().unwrap().len(), 6);
}

#[test]
fn demo_equivalent_compare_command_gives_the_demo_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = bin()
        .args(["demo", "--generate-samples", "samples"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(o.status.success());
    // The command as printed in docs/cli.md (line continuations joined).
    let text = doc("cli.md");
    let start = text.find("    bonnetlab compare --pitch-mm 3").unwrap();
    let block: String = text[start..]
        .lines()
        .take_while(|l| l.starts_with("    "))
        .collect::<Vec<_>>()
        .join(" ")
        .replace('\\', " ");
    let words: Vec<&str> = block.split_whitespace().skip(1).collect();
    let o = bin().args(&words).current_dir(d).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = bin()
        .args(["demo", "--out", "demo_report"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let read = |p: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join(p)).unwrap()).unwrap()
    };
    let (c, m) = (
        read("reports/demo/report.json"),
        read("demo_report/report.json"),
    );
    assert_eq!(
        c["runs"], m["runs"],
        "compare and demo disagree on the runs"
    );
}
