//! The spot-sweep manifest: which spot maps, polished by which bonnet, for how long, at which
//! settings. TOML (any extension but `.csv`) or CSV. Paths are relative to the manifest file.
//!
//! TOML:
//! ```toml
//! [defaults]                 # optional; every key may also be given per spot
//! dwell_s = 120.0
//! precession_deg = 20.0
//! offset_mm = 0.8
//! spindle_rpm = 500.0
//! inner_pressure_mpa = 0.25
//! kind = "height"            # "height" (a dip, default) or "removal"
//! ring_inner_mm = 8.0        # optional overrides of the background ring (default 1.4 / 1.9 R5)
//! ring_outer_mm = 11.0
//!
//! [[spot]]
//! file = "original_h0.2.dat"
//! bonnet = "original"        # or "suppression", or any name of letters, digits, '-', '_'
//! offset_mm = 0.2
//! sweep = "offset_mm"        # optional: the sweep this spot belongs to (else inferred)
//! ```
//! CSV: a header naming the columns `file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,
//! inner_pressure_mpa` (all required) and optionally `kind`, `sweep`; one spot per line.
//! Errors name the line and the key.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::background::MapKind;
use crate::error::SpotsError;
use crate::model::{Factor, Factors};

/// One spot of the manifest, fully resolved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpotEntry {
    /// Line of the manifest where the spot is declared (1-based).
    pub line: usize,
    /// The path as written in the manifest.
    pub file: String,
    /// The path resolved against the manifest's directory.
    pub path: PathBuf,
    pub bonnet: String,
    pub dwell_s: f64,
    pub factors: Factors,
    pub kind: MapKind,
    pub sweep: Option<Factor>,
}

/// A parsed manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub spots: Vec<SpotEntry>,
    pub ring_inner_mm: Option<f64>,
    pub ring_outer_mm: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDefaults {
    dwell_s: Option<f64>,
    precession_deg: Option<f64>,
    offset_mm: Option<f64>,
    spindle_rpm: Option<f64>,
    inner_pressure_mpa: Option<f64>,
    kind: Option<MapKind>,
    bonnet: Option<String>,
    ring_inner_mm: Option<f64>,
    ring_outer_mm: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSpot {
    file: Option<String>,
    bonnet: Option<String>,
    dwell_s: Option<f64>,
    precession_deg: Option<f64>,
    offset_mm: Option<f64>,
    spindle_rpm: Option<f64>,
    inner_pressure_mpa: Option<f64>,
    kind: Option<MapKind>,
    sweep: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    #[serde(default)]
    defaults: Option<RawDefaults>,
    #[serde(default)]
    spot: Vec<toml::Spanned<RawSpot>>,
}

/// 1-based line of byte offsets, from the newline positions counted once (counting from the
/// start for every spot was quadratic: 100 000 `[[spot]]` tables in 8 MB took minutes).
struct Lines(Vec<usize>);

impl Lines {
    fn of(text: &str) -> Lines {
        Lines(
            text.bytes()
                .enumerate()
                .filter(|&(_, b)| b == b'\n')
                .map(|(i, _)| i)
                .collect(),
        )
    }

    fn line_of(&self, offset: usize) -> usize {
        self.0.partition_point(|&nl| nl < offset) + 1
    }
}

fn err(line: usize, what: impl Into<String>) -> SpotsError {
    SpotsError::Manifest {
        at: format!("line {line}"),
        what: what.into(),
    }
}

/// Parses a manifest from its text; `path` gives the format (by extension) and the directory
/// spot paths are relative to.
pub fn parse_manifest(path: &Path, text: &str) -> Result<Manifest, SpotsError> {
    let base = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let is_csv = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
    let m = if is_csv {
        parse_csv(text, &base)?
    } else {
        parse_toml(text, &base)?
    };
    if m.spots.is_empty() {
        return Err(SpotsError::Manifest {
            at: "manifest".into(),
            what: "lists no spot".into(),
        });
    }
    // One measured spot is one polishing setting: the same map listed twice (with other
    // settings) would enter the sweep twice as two different spots.
    // The file itself, not its spelling (`a.dat`, `./a.dat` and a link to it are one map).
    let mut seen: std::collections::HashMap<std::path::PathBuf, usize> =
        std::collections::HashMap::with_capacity(m.spots.len());
    for (k, e) in m.spots.iter().enumerate() {
        let id = std::fs::canonicalize(&e.path).unwrap_or_else(|_| e.path.clone());
        if let Some(first) = seen.insert(id, k).map(|j| &m.spots[j]) {
            return Err(SpotsError::Manifest {
                at: format!("line {}", e.line),
                what: format!(
                    "{} is listed again (first at line {}): each spot map is one setting",
                    e.path.display(),
                    first.line
                ),
            });
        }
    }
    Ok(m)
}

/// Reads and parses a manifest file.
pub fn read_manifest(path: &Path) -> Result<Manifest, SpotsError> {
    let text = bonnetlab_io::input::read_text(
        path,
        bonnetlab_io::input::TEXT_LIMIT,
        "a spot manifest (TOML or CSV)",
    )
    .map_err(|e| SpotsError::Manifest {
        at: "file".into(),
        what: format!("cannot read: {e}"),
    })?;
    parse_manifest(path, &text)
}

fn parse_toml(text: &str, base: &Path) -> Result<Manifest, SpotsError> {
    // Typed and strict: unknown tables / keys name the nearest valid name, wrong types what
    // was expected, syntax errors the parser's cause (bonnetlab_process::config).
    let raw: RawManifest =
        bonnetlab_process::config::from_toml(text).map_err(|e| SpotsError::Manifest {
            at: e.key,
            what: e.what,
        })?;
    let d = raw.defaults.unwrap_or_default();
    let mut spots = Vec::with_capacity(raw.spot.len());
    let lines = Lines::of(text);
    for (k, sp) in raw.spot.iter().enumerate() {
        let line = lines.line_of(sp.span().start);
        let s = sp.get_ref();
        let at = |key: &str| format!("line {line}: spot[{}] key '{key}'", k + 1);
        let need = |v: Option<f64>, dv: Option<f64>, key: &str| -> Result<f64, SpotsError> {
            let v = v.or(dv).ok_or_else(|| SpotsError::Manifest {
                at: at(key),
                what: "missing (give it in the spot or in [defaults])".into(),
            })?;
            check_number(v, key).map_err(|what| SpotsError::Manifest { at: at(key), what })
        };
        let file = s.file.clone().ok_or_else(|| SpotsError::Manifest {
            at: at("file"),
            what: "missing".into(),
        })?;
        let bonnet = s
            .bonnet
            .clone()
            .or(d.bonnet.clone())
            .ok_or_else(|| SpotsError::Manifest {
                at: at("bonnet"),
                what: "missing".into(),
            })?;
        check_bonnet(&bonnet).map_err(|what| SpotsError::Manifest {
            at: at("bonnet"),
            what,
        })?;
        let sweep = match &s.sweep {
            None => None,
            Some(name) => Some(Factor::from_key(name).ok_or_else(|| SpotsError::Manifest {
                at: at("sweep"),
                what: format!("unknown factor '{name}' (precession_deg, offset_mm, spindle_rpm, inner_pressure_mpa)"),
            })?),
        };
        spots.push(SpotEntry {
            line,
            path: base.join(&file),
            file,
            bonnet,
            dwell_s: need(s.dwell_s, d.dwell_s, "dwell_s")?,
            factors: Factors {
                precession_deg: need(s.precession_deg, d.precession_deg, "precession_deg")?,
                offset_mm: need(s.offset_mm, d.offset_mm, "offset_mm")?,
                spindle_rpm: need(s.spindle_rpm, d.spindle_rpm, "spindle_rpm")?,
                inner_pressure_mpa: need(
                    s.inner_pressure_mpa,
                    d.inner_pressure_mpa,
                    "inner_pressure_mpa",
                )?,
            },
            kind: s.kind.or(d.kind).unwrap_or_default(),
            sweep,
        });
    }
    for (key, v) in [
        ("ring_inner_mm", d.ring_inner_mm),
        ("ring_outer_mm", d.ring_outer_mm),
    ] {
        if let Some(v) = v {
            check_number(v, key).map_err(|what| SpotsError::Manifest {
                at: format!("[defaults] key '{key}'"),
                what,
            })?;
        }
    }
    if let (Some(a), Some(b)) = (d.ring_inner_mm, d.ring_outer_mm) {
        if a >= b {
            return Err(SpotsError::Manifest {
                at: "[defaults] key 'ring_outer_mm'".into(),
                what: format!("{b} must be larger than ring_inner_mm = {a}"),
            });
        }
    }
    Ok(Manifest {
        spots,
        ring_inner_mm: d.ring_inner_mm,
        ring_outer_mm: d.ring_outer_mm,
    })
}

fn check_number(v: f64, key: &str) -> Result<f64, String> {
    let ok = match key {
        "inner_pressure_mpa" => v.is_finite() && v >= 0.0,
        "precession_deg" => v.is_finite() && v > 0.0 && v < 90.0,
        _ => v.is_finite() && v > 0.0,
    };
    if ok {
        Ok(v)
    } else if key == "precession_deg" {
        Err(format!("{v} is not an angle in (0, 90) degrees"))
    } else if key == "inner_pressure_mpa" {
        Err(format!("{v} must be a finite number >= 0"))
    } else {
        Err(format!("{v} must be a finite positive number"))
    }
}

fn check_bonnet(name: &str) -> Result<(), String> {
    if !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        Ok(())
    } else {
        Err(format!(
            "'{name}' is not a bonnet name (letters, digits, '-', '_')"
        ))
    }
}

fn parse_csv(text: &str, base: &Path) -> Result<Manifest, SpotsError> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let headers = rdr
        .headers()
        .map_err(|e| err(1, format!("unreadable header: {e}")))?
        .clone();
    let col = |name: &str| headers.iter().position(|h| h == name);
    const KNOWN: [&str; 9] = [
        "file",
        "bonnet",
        "dwell_s",
        "precession_deg",
        "offset_mm",
        "spindle_rpm",
        "inner_pressure_mpa",
        "kind",
        "sweep",
    ];
    if let Some(h) = headers.iter().find(|h| !KNOWN.contains(h)) {
        return Err(err(
            1,
            format!("unknown column '{h}' (known: {})", KNOWN.join(", ")),
        ));
    }
    let mut idx = Vec::new();
    for name in &KNOWN[..7] {
        idx.push(col(name).ok_or_else(|| err(1, format!("missing column '{name}'")))?);
    }
    let (kind_col, sweep_col) = (col("kind"), col("sweep"));
    let mut spots = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map(|p| p.line() as usize).unwrap_or(0);
            err(line, format!("unreadable record: {e}"))
        })?;
        let line = rec.position().map(|p| p.line() as usize).unwrap_or(0);
        let field = |c: usize| rec.get(c).unwrap_or("");
        let at = |key: &str| format!("line {line}: column '{key}'");
        let num = |k: usize| -> Result<f64, SpotsError> {
            let key = KNOWN[k];
            let v: f64 = field(idx[k]).parse().map_err(|_| SpotsError::Manifest {
                at: at(key),
                what: format!("'{}' is not a number", field(idx[k])),
            })?;
            check_number(v, key).map_err(|what| SpotsError::Manifest { at: at(key), what })
        };
        let file = field(idx[0]).to_string();
        if file.is_empty() {
            return Err(SpotsError::Manifest {
                at: at("file"),
                what: "empty".into(),
            });
        }
        let bonnet = field(idx[1]).to_string();
        check_bonnet(&bonnet).map_err(|what| SpotsError::Manifest {
            at: at("bonnet"),
            what,
        })?;
        let kind = match kind_col.map(field).unwrap_or("") {
            "" | "height" => MapKind::Height,
            "removal" => MapKind::Removal,
            other => {
                return Err(SpotsError::Manifest {
                    at: at("kind"),
                    what: format!("'{other}' is not 'height' or 'removal'"),
                })
            }
        };
        let sweep = match sweep_col.map(field).unwrap_or("") {
            "" => None,
            name => Some(Factor::from_key(name).ok_or_else(|| SpotsError::Manifest {
                at: at("sweep"),
                what: format!("unknown factor '{name}'"),
            })?),
        };
        spots.push(SpotEntry {
            line,
            path: base.join(&file),
            file,
            bonnet,
            dwell_s: num(2)?,
            factors: Factors {
                precession_deg: num(3)?,
                offset_mm: num(4)?,
                spindle_rpm: num(5)?,
                inner_pressure_mpa: num(6)?,
            },
            kind,
            sweep,
        });
    }
    Ok(Manifest {
        spots,
        ring_inner_mm: None,
        ring_outer_mm: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOML: &str = r#"
[defaults]
dwell_s = 120.0
precession_deg = 20.0
offset_mm = 0.8
spindle_rpm = 500.0
inner_pressure_mpa = 0.25

[[spot]]
file = "a.dat"
bonnet = "original"
offset_mm = 0.2

[[spot]]
file = "sub/b.dat"
bonnet = "suppression"
sweep = "offset_mm"
"#;

    #[test]
    fn toml_manifest_resolves_defaults_paths_and_lines() {
        let m = parse_manifest(Path::new("/data/sweep/manifest.toml"), TOML).unwrap();
        assert_eq!(m.spots.len(), 2);
        assert_eq!(m.spots[0].factors.offset_mm, 0.2);
        assert_eq!(m.spots[0].factors.precession_deg, 20.0);
        assert_eq!(m.spots[0].line, 9);
        assert_eq!(m.spots[1].path, PathBuf::from("/data/sweep/sub/b.dat"));
        assert_eq!(m.spots[1].sweep, Some(Factor::OffsetMm));
    }

    #[test]
    fn toml_errors_name_line_and_key() {
        let bad = TOML.replace("offset_mm = 0.2", "offset_mm = -0.2");
        let e = parse_manifest(Path::new("m.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 9") && e.contains("offset_mm"), "{e}");
        let bad = TOML.replace("dwell_s = 120.0\n", "");
        let e = parse_manifest(Path::new("m.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("dwell_s") && e.contains("missing"), "{e}");
        let bad = TOML.replace("bonnet = \"original\"", "bonet = \"original\"");
        let e = parse_manifest(Path::new("m.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 11") && e.contains("bonet"), "{e}");
        assert!(
            e.contains("[spot] bonet") && e.contains("did you mean `bonnet`?"),
            "{e}"
        );
        let bad = TOML.replace("[defaults]", "[defualts]");
        let e = parse_manifest(Path::new("m.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[defualts]") && e.contains("did you mean [defaults]?"),
            "{e}"
        );
        let bad = TOML.replace("offset_mm = 0.2", "offset_mm = \"0.2\"");
        let e = parse_manifest(Path::new("m.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("[spot] offset_mm: expected a number"), "{e}");
        assert!(!e.contains('\n'));
    }

    /// The same map listed twice is named at its second line.
    #[test]
    fn a_map_listed_twice_is_refused() {
        let text = "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,inner_pressure_mpa\n\
                    a.dat,original,120,20,0.2,500,0.25\n\
                    a.dat,original,120,20,0.4,500,0.25\n";
        let e = parse_manifest(Path::new("m.csv"), text)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 3") && e.contains("a.dat is listed again (first at line 2)"),
            "{e}"
        );
    }

    /// The same file spelt two ways (`a.dat`, `./a.dat`) is one map.
    #[test]
    fn one_file_spelt_two_ways_is_one_map() {
        let dir = std::env::temp_dir().join(format!("bonnetlab-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("a.dat"), b"x").unwrap();
        let text = "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,inner_pressure_mpa\n\
                    a.dat,original,120,20,0.2,500,0.25\n\
                    ./a.dat,original,120,20,0.4,500,0.25\n";
        let e = parse_manifest(&dir.join("m.csv"), text).map(|m| m.spots.len());
        let _ = std::fs::remove_dir_all(&dir);
        let e = e.unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("listed again"), "{e}");
    }

    #[test]
    fn csv_manifest_and_its_errors() {
        let text = "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,inner_pressure_mpa\n\
                    a.dat,original,120,20,0.2,500,0.25\n\
                    b.dat,suppression,120,20,0.4,500,0.25\n";
        let m = parse_manifest(Path::new("dir/m.csv"), text).unwrap();
        assert_eq!(m.spots.len(), 2);
        assert_eq!(m.spots[1].line, 3);
        assert_eq!(m.spots[1].path, PathBuf::from("dir/b.dat"));
        let bad = text.replace("0.4,500", "abc,500");
        let e = parse_manifest(Path::new("m.csv"), &bad)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 3") && e.contains("offset_mm") && e.contains("abc"),
            "{e}"
        );
        let bad = text.replace("spindle_rpm", "spindle");
        let e = parse_manifest(Path::new("m.csv"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && e.contains("spindle"), "{e}");
    }
}
