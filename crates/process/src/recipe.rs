//! Run recipes: the TOML of `shared/spec/interfaces.md` (`[measurement]`, `[tif]`, `[path]`,
//! `[process]`, `[vibration]`). Paths are resolved relative to the recipe file. Errors name the
//! recipe file and the key (`[tif] dwell_s: ...`).
//!
//! Decisions where the spec is silent (documented here so users can rely on them):
//! - `[measurement] before` is required; `after` is optional (only `calibrate` needs it).
//! - `[tif]` holds either `spot` + `dwell_s` or `model = { kind = ... }`, not both.
//! - A bonnet model's `offset_mm`, `precession_deg` and `spindle_rpm` default to `[process]`'s
//!   values; `radius_mm` defaults to 20 mm (the paper's bonnet); `pressure` to "hertz";
//!   `precession_steps` to 4; the rate is `peak_rate_nm_per_s` or `volume_rate_nm_mm2_per_s`.
//! - `[process] bonnet` must be "original" or "suppression" when given (default "original").
//! - `[vibration]` is kept as a raw table for the vibration model.

use std::path::{Path, PathBuf};

use serde::Serialize;
use toml::{Table, Value};

use crate::error::ProcessError;
use crate::tif::{BonnetTifParams, GaussianTif, PressureProfile, RateScale};

/// Where the TIF comes from.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum TifSource {
    /// A measured spot map polished for `dwell_s` seconds.
    Spot {
        path: PathBuf,
        dwell_s: f64,
    },
    Gaussian(GaussianTif),
    Bonnet(BonnetTifParams),
}

/// The informative `[process]` parameters (all optional).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ProcessParams {
    /// "original" or "suppression".
    pub bonnet: String,
    pub spindle_rpm: Option<f64>,
    pub offset_mm: Option<f64>,
    pub precession_deg: Option<f64>,
    pub inner_pressure_mpa: Option<f64>,
}

/// A parsed run recipe.
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe {
    /// The recipe file as given.
    pub file: PathBuf,
    pub before: PathBuf,
    pub after: Option<PathBuf>,
    pub tif: TifSource,
    pub path_log: PathBuf,
    pub pitch_mm: Option<f64>,
    pub process: ProcessParams,
    /// The raw `[vibration]` table, when present.
    pub vibration: Option<Table>,
}

struct Ctx<'a> {
    file: &'a Path,
    dir: PathBuf,
}

impl Ctx<'_> {
    fn err(&self, key: &str, what: impl Into<String>) -> ProcessError {
        ProcessError::Recipe {
            file: self.file.to_path_buf(),
            key: key.to_string(),
            what: what.into(),
        }
    }

    fn table<'t>(
        &self,
        root: &'t Table,
        name: &str,
        required: bool,
    ) -> Result<Option<&'t Table>, ProcessError> {
        match root.get(name) {
            None if required => Err(self.err(&format!("[{name}]"), "missing table")),
            None => Ok(None),
            Some(Value::Table(t)) => Ok(Some(t)),
            Some(_) => Err(self.err(&format!("[{name}]"), "must be a table")),
        }
    }

    fn num(&self, t: &Table, tname: &str, key: &str) -> Result<Option<f64>, ProcessError> {
        let k = format!("[{tname}] {key}");
        match t.get(key) {
            None => Ok(None),
            Some(Value::Float(f)) if f.is_finite() => Ok(Some(*f)),
            Some(Value::Integer(i)) => Ok(Some(*i as f64)),
            Some(Value::Float(_)) => Err(self.err(&k, "must be a finite number")),
            Some(v) => Err(self.err(&k, format!("must be a number, got {}", v.type_str()))),
        }
    }

    fn positive(&self, t: &Table, tname: &str, key: &str) -> Result<Option<f64>, ProcessError> {
        match self.num(t, tname, key)? {
            Some(v) if v <= 0.0 => Err(self.err(
                &format!("[{tname}] {key}"),
                format!("must be positive, got {v}"),
            )),
            other => Ok(other),
        }
    }

    fn req_positive(&self, t: &Table, tname: &str, key: &str) -> Result<f64, ProcessError> {
        self.positive(t, tname, key)?
            .ok_or_else(|| self.err(&format!("[{tname}] {key}"), "missing"))
    }

    fn string<'t>(
        &self,
        t: &'t Table,
        tname: &str,
        key: &str,
    ) -> Result<Option<&'t str>, ProcessError> {
        match t.get(key) {
            None => Ok(None),
            Some(Value::String(s)) => Ok(Some(s.as_str())),
            Some(v) => Err(self.err(
                &format!("[{tname}] {key}"),
                format!("must be a string, got {}", v.type_str()),
            )),
        }
    }

    fn file_path(
        &self,
        t: &Table,
        tname: &str,
        key: &str,
    ) -> Result<Option<PathBuf>, ProcessError> {
        Ok(self.string(t, tname, key)?.map(|s| {
            let p = Path::new(s);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                self.dir.join(p)
            }
        }))
    }
}

impl Recipe {
    /// Reads and validates a recipe file.
    pub fn load(path: &Path) -> Result<Recipe, ProcessError> {
        let text = bonnetlab_io::input::read_text(
            path,
            bonnetlab_io::input::TEXT_LIMIT,
            "a recipe (TOML)",
        )
        .map_err(|e| ProcessError::Io {
            file: path.to_path_buf(),
            what: e.to_string(),
        })?;
        Recipe::parse(&text, path)
    }

    /// Parses recipe text; `path` names the file in errors and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Recipe, ProcessError> {
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let cx = Ctx { file: path, dir };
        let root: Table = text.parse::<Table>().map_err(|e| {
            let msg = e
                .to_string()
                .lines()
                .next()
                .unwrap_or("invalid TOML")
                .to_string();
            cx.err("TOML", msg)
        })?;
        let m = cx
            .table(&root, "measurement", true)?
            .ok_or_else(|| cx.err("[measurement]", "missing table"))?;
        let before = cx
            .file_path(m, "measurement", "before")?
            .ok_or_else(|| cx.err("[measurement] before", "missing"))?;
        let after = cx.file_path(m, "measurement", "after")?;

        let empty = Table::new();
        let proc_t = cx.table(&root, "process", false)?.unwrap_or(&empty);
        let bonnet = cx
            .string(proc_t, "process", "bonnet")?
            .unwrap_or("original")
            .to_ascii_lowercase();
        if bonnet != "original" && bonnet != "suppression" {
            return Err(cx.err(
                "[process] bonnet",
                format!("must be \"original\" or \"suppression\", got \"{bonnet}\""),
            ));
        }
        let process = ProcessParams {
            bonnet,
            spindle_rpm: cx.positive(proc_t, "process", "spindle_rpm")?,
            offset_mm: cx.positive(proc_t, "process", "offset_mm")?,
            precession_deg: cx.num(proc_t, "process", "precession_deg")?,
            inner_pressure_mpa: cx.positive(proc_t, "process", "inner_pressure_mpa")?,
        };

        let t = cx
            .table(&root, "tif", true)?
            .ok_or_else(|| cx.err("[tif]", "missing table"))?;
        let tif = match (t.get("spot"), t.get("model")) {
            (Some(_), Some(_)) => {
                return Err(cx.err("[tif]", "give either spot + dwell_s or model, not both"))
            }
            (None, None) => return Err(cx.err("[tif]", "missing spot (with dwell_s) or model")),
            (Some(_), None) => {
                let p = cx
                    .file_path(t, "tif", "spot")?
                    .ok_or_else(|| cx.err("[tif] spot", "missing"))?;
                let dwell_s = cx.req_positive(t, "tif", "dwell_s")?;
                TifSource::Spot { path: p, dwell_s }
            }
            (None, Some(Value::Table(mt))) => parse_model(&cx, mt, &process)?,
            (None, Some(_)) => {
                return Err(cx.err("[tif] model", "must be an inline table { kind = ... }"))
            }
        };

        let pt = cx
            .table(&root, "path", true)?
            .ok_or_else(|| cx.err("[path]", "missing table"))?;
        let path_log = cx
            .file_path(pt, "path", "log")?
            .ok_or_else(|| cx.err("[path] log", "missing"))?;
        let pitch_mm = cx.positive(pt, "path", "pitch_mm")?;

        let vibration = cx.table(&root, "vibration", false)?.cloned();
        Ok(Recipe {
            file: path.to_path_buf(),
            before,
            after,
            tif,
            path_log,
            pitch_mm,
            process,
            vibration,
        })
    }
}

fn parse_model(cx: &Ctx, mt: &Table, process: &ProcessParams) -> Result<TifSource, ProcessError> {
    let tn = "tif.model";
    let kind = cx
        .string(mt, tn, "kind")?
        .ok_or_else(|| cx.err("[tif.model] kind", "missing"))?;
    match kind.to_ascii_lowercase().as_str() {
        "gaussian" => {
            let sigma = cx.req_positive(mt, tn, "sigma_mm")?;
            let peak = cx.req_positive(mt, tn, "peak_rate_nm_per_s")?;
            let d = cx.positive(mt, tn, "diameter_mm")?.unwrap_or(6.0 * sigma);
            GaussianTif::new(sigma, d, peak)
                .map(TifSource::Gaussian)
                .map_err(|e| cx.err("[tif.model]", e.to_string()))
        }
        "bonnet" => {
            let or = |v: Option<f64>, from: Option<f64>, key: &str| {
                v.or(from).ok_or_else(|| {
                    cx.err(
                        &format!("[tif.model] {key}"),
                        "missing (and not in [process])",
                    )
                })
            };
            let pressure = match cx.string(mt, tn, "pressure")? {
                None => PressureProfile::Hertz,
                Some(s) => PressureProfile::parse(s).ok_or_else(|| {
                    cx.err(
                        "[tif.model] pressure",
                        format!("must be hertz, parabolic or uniform, got \"{s}\""),
                    )
                })?,
            };
            let scale = match (
                cx.positive(mt, tn, "peak_rate_nm_per_s")?,
                cx.positive(mt, tn, "volume_rate_nm_mm2_per_s")?,
            ) {
                (Some(p), None) => RateScale::PeakNmPerS(p),
                (None, Some(v)) => RateScale::VolumeNmMm2PerS(v),
                _ => {
                    return Err(cx.err(
                        "[tif.model] peak_rate_nm_per_s",
                        "give exactly one of peak_rate_nm_per_s or volume_rate_nm_mm2_per_s",
                    ))
                }
            };
            let steps = match cx.num(mt, tn, "precession_steps")? {
                None => 4,
                Some(v) if (1.0..=360.0).contains(&v) && v.fract() == 0.0 => v as usize,
                Some(v) => {
                    return Err(cx.err(
                        "[tif.model] precession_steps",
                        format!("must be an integer 1..360, got {v}"),
                    ))
                }
            };
            let p = BonnetTifParams {
                radius_mm: cx.positive(mt, tn, "radius_mm")?.unwrap_or(20.0),
                offset_mm: or(
                    cx.positive(mt, tn, "offset_mm")?,
                    process.offset_mm,
                    "offset_mm",
                )?,
                precession_deg: or(
                    cx.num(mt, tn, "precession_deg")?,
                    process.precession_deg,
                    "precession_deg",
                )?,
                spindle_rpm: or(
                    cx.positive(mt, tn, "spindle_rpm")?,
                    process.spindle_rpm,
                    "spindle_rpm",
                )?,
                pressure,
                scale,
                precession_steps: steps,
            };
            crate::tif::bonnet::BonnetTif::new(&p)
                .map_err(|e| cx.err("[tif.model]", e.to_string()))?;
            Ok(TifSource::Bonnet(p))
        }
        other => Err(cx.err(
            "[tif.model] kind",
            format!("must be \"gaussian\" or \"bonnet\", got \"{other}\""),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FULL: &str = r#"
[measurement]
before = "before.dat"
after = "sub/after.dat"

[tif]
spot = "spot.dat"
dwell_s = 30.0

[path]
log = "path.csv"
pitch_mm = 3.0

[process]
bonnet = "suppression"
spindle_rpm = 1000.0
offset_mm = 0.6
precession_deg = 20.0
inner_pressure_mpa = 0.25

[vibration]
k1_n_per_mm = 1476.0
"#;

    #[test]
    fn parses_the_spec_example_and_resolves_paths() {
        let r = Recipe::parse(FULL, Path::new("/runs/a/recipe.toml")).unwrap();
        assert_eq!(r.before, PathBuf::from("/runs/a/before.dat"));
        assert_eq!(r.after, Some(PathBuf::from("/runs/a/sub/after.dat")));
        assert_eq!(
            r.tif,
            TifSource::Spot {
                path: "/runs/a/spot.dat".into(),
                dwell_s: 30.0
            }
        );
        assert_eq!(r.path_log, PathBuf::from("/runs/a/path.csv"));
        assert_eq!(r.pitch_mm, Some(3.0));
        assert_eq!(r.process.bonnet, "suppression");
        assert_eq!(r.process.offset_mm, Some(0.6));
        assert_eq!(
            r.vibration
                .as_ref()
                .and_then(|v| v.get("k1_n_per_mm"))
                .and_then(|v| v.as_float()),
            Some(1476.0)
        );
    }

    #[test]
    fn models_parse_with_process_defaults() {
        let g = FULL.replace(
            "spot = \"spot.dat\"\ndwell_s = 30.0",
            "model = { kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0, diameter_mm = 10.0 }",
        );
        let r = Recipe::parse(&g, Path::new("r.toml")).unwrap();
        assert_eq!(
            r.tif,
            TifSource::Gaussian(GaussianTif::new(1.0, 10.0, 10.0).unwrap())
        );
        let b = FULL.replace(
            "spot = \"spot.dat\"\ndwell_s = 30.0",
            "model = { kind = \"bonnet\", radius_mm = 20.0, offset_mm = 0.3, peak_rate_nm_per_s = 20.0 }",
        );
        let r = Recipe::parse(&b, Path::new("r.toml")).unwrap();
        match r.tif {
            TifSource::Bonnet(p) => {
                assert_eq!(p.offset_mm, 0.3);
                assert_eq!(p.precession_deg, 20.0);
                assert_eq!(p.spindle_rpm, 1000.0);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn errors_name_file_and_key() {
        let cases = [
            (
                FULL.replace("dwell_s = 30.0", "dwell_s = -1.0"),
                "[tif] dwell_s",
            ),
            (
                FULL.replace("dwell_s = 30.0", "dwell_s = \"x\""),
                "[tif] dwell_s",
            ),
            (
                FULL.replace("before = \"before.dat\"", ""),
                "[measurement] before",
            ),
            (FULL.replace("log = \"path.csv\"", ""), "[path] log"),
            (
                FULL.replace("\"suppression\"", "\"soft\""),
                "[process] bonnet",
            ),
            (
                FULL.replace("spot = \"spot.dat\"", "model = { kind = \"cone\" }"),
                "[tif",
            ),
            (FULL.replace("[path]", "[path"), "TOML"),
        ];
        for (text, key) in cases {
            let e = Recipe::parse(&text, Path::new("runs/r.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("runs/r.toml: ") && e.contains(key), "{e}");
        }
    }
}
