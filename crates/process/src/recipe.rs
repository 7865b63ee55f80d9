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
//! - `[vibration]` is kept as a raw table for the vibration model, which reads it typed and
//!   strictly (bonnetlab_vibration::params).
//! - Every table and key is typed ([`RecipeDoc`], read with serde through [`crate::config`]):
//!   an unknown table or key is an error naming the nearest valid name, a wrong type says what
//!   was expected, a TOML syntax error gives the parser's cause with line and column.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use toml::Table;

use crate::error::ProcessError;
use crate::pixel::PixelSampling;
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
    /// How the maps' and the spot's pixels sample the surface (`[measurement] pixels`).
    pub pixels: PixelSampling,
    /// The instrument's repeatability (`[measurement] repeatability_nm`): the RMS (nm, piston
    /// and tilt removed) of the difference between two measurements of an unchanged part,
    /// when the lab declares it.
    pub repeatability_nm: Option<f64>,
}

/// The recipe document as written, every table typed and strict (unknown tables and keys are
/// errors naming the nearest valid name, see [`crate::config`]); every table and key is
/// optional here, [`Recipe::parse`] checks what a run needs. Commands that read only part of a
/// recipe (`bonnetlab vibration`) read this.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecipeDoc {
    pub measurement: Option<MeasurementTable>,
    pub tif: Option<TifTable>,
    pub path: Option<PathTable>,
    pub process: Option<ProcessTable>,
    /// Read by the vibration model (bonnetlab_vibration::params, typed and strict there).
    pub vibration: Option<Table>,
    /// Informative: the physical parameters behind a `[tif]` model exported by `bonnetlab
    /// spots` (`model_*.toml`, pasted whole into a recipe); not read.
    pub spots_fit: Option<Table>,
}

/// `[measurement]`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasurementTable {
    pub before: Option<String>,
    pub after: Option<String>,
    /// How the instrument's pixels sample the surface: `point` (the default) or `area`.
    pub pixels: Option<String>,
    /// RMS (nm) of the difference between two measurements of an unchanged part.
    pub repeatability_nm: Option<f64>,
}

/// `[tif]`: a measured spot (`spot`, `dwell_s`) or a `model`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TifTable {
    pub spot: Option<String>,
    pub dwell_s: Option<f64>,
    pub model: Option<ModelTable>,
}

/// `[tif] model = { kind = ... }`: the keys of both kinds (a key of the other kind is an error).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelTable {
    pub kind: Option<String>,
    pub sigma_mm: Option<f64>,
    pub diameter_mm: Option<f64>,
    pub peak_rate_nm_per_s: Option<f64>,
    pub volume_rate_nm_mm2_per_s: Option<f64>,
    pub radius_mm: Option<f64>,
    pub offset_mm: Option<f64>,
    pub precession_deg: Option<f64>,
    pub spindle_rpm: Option<f64>,
    pub pressure: Option<String>,
    pub precession_steps: Option<f64>,
}

/// `[path]`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathTable {
    pub log: Option<String>,
    pub pitch_mm: Option<f64>,
}

/// `[process]`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessTable {
    pub bonnet: Option<String>,
    pub spindle_rpm: Option<f64>,
    pub offset_mm: Option<f64>,
    pub precession_deg: Option<f64>,
    pub inner_pressure_mpa: Option<f64>,
}

impl RecipeDoc {
    /// Reads recipe text strictly; errors name `file` and the key.
    pub fn parse(text: &str, file: &Path) -> Result<RecipeDoc, ProcessError> {
        crate::config::from_toml(text).map_err(|e| ProcessError::Recipe {
            file: file.to_path_buf(),
            key: e.key,
            what: e.what,
        })
    }

    /// Reads a recipe file strictly.
    pub fn load(path: &Path) -> Result<RecipeDoc, ProcessError> {
        RecipeDoc::parse(&read_recipe_text(path)?, path)
    }

    /// `[process] bonnet` lower-cased, checked to be "original" or "suppression".
    pub fn bonnet(&self, file: &Path) -> Result<Option<String>, ProcessError> {
        let Some(b) = self.process.as_ref().and_then(|p| p.bonnet.as_ref()) else {
            return Ok(None);
        };
        let b = b.to_ascii_lowercase();
        if b != "original" && b != "suppression" {
            return Err(ProcessError::Recipe {
                file: file.to_path_buf(),
                key: "[process] bonnet".into(),
                what: format!("must be \"original\" or \"suppression\", got \"{b}\""),
            });
        }
        Ok(Some(b))
    }

    /// The bonnet TIF model's radius, when the recipe gives one.
    pub fn bonnet_radius_mm(&self) -> Option<f64> {
        let m = self.tif.as_ref()?.model.as_ref()?;
        if m.kind.as_deref().map(str::to_ascii_lowercase).as_deref() == Some("bonnet") {
            m.radius_mm
        } else {
            None
        }
    }
}

fn read_recipe_text(path: &Path) -> Result<String, ProcessError> {
    bonnetlab_io::input::read_text(path, bonnetlab_io::input::TEXT_LIMIT, "a recipe (TOML)")
        .map_err(|e| ProcessError::Io {
            file: path.to_path_buf(),
            what: e.to_string(),
        })
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

    fn finite(&self, v: Option<f64>, key: &str) -> Result<Option<f64>, ProcessError> {
        match v {
            Some(x) if !x.is_finite() => Err(self.err(key, "must be a finite number")),
            other => Ok(other),
        }
    }

    fn positive(&self, v: Option<f64>, key: &str) -> Result<Option<f64>, ProcessError> {
        match self.finite(v, key)? {
            Some(x) if x <= 0.0 => Err(self.err(
                key,
                format!(
                    "must be positive, got {}",
                    bonnetlab_surface::format::sig(x, 6)
                ),
            )),
            other => Ok(other),
        }
    }

    fn req_positive(&self, v: Option<f64>, key: &str) -> Result<f64, ProcessError> {
        self.positive(v, key)?
            .ok_or_else(|| self.err(key, "missing"))
    }

    fn file_path(&self, s: Option<&String>) -> Option<PathBuf> {
        s.map(|s| {
            let p = Path::new(s);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                self.dir.join(p)
            }
        })
    }
}

/// Which key of which recipe names a map, said after an error about that map (a missing or
/// unreadable file is then traced to the line that asked for it): `" (named by [measurement]
/// before in run.toml)"`.
pub fn named_by(recipe_file: &Path, key: &str) -> String {
    format!(" (named by {key} in {})", recipe_file.display())
}

/// Reads the path log a recipe names (`[path] log`): an error about it (missing, unreadable, a
/// bad line) ends with [`named_by`], as the maps' errors do.
pub fn read_named_path_log(log: &Path, recipe_file: &Path) -> Result<crate::PathLog, ProcessError> {
    crate::path::read_path_csv(log).map_err(|e| traced(e, recipe_file, "[path] log"))
}

/// An error about a file a recipe names, with [`named_by`] appended to what it says.
pub fn traced(e: ProcessError, recipe_file: &Path, key: &str) -> ProcessError {
    let by = named_by(recipe_file, key);
    match e {
        ProcessError::Io { file, what } => ProcessError::Io {
            file,
            what: what + &by,
        },
        ProcessError::PathLog { file, line, what } => ProcessError::PathLog {
            file,
            line,
            what: what + &by,
        },
        other => other,
    }
}

/// Checks that a run's two maps record a removal: maps whose valid pixels coincide and hold
/// the same heights (the same file named twice, or one measurement saved twice) leave nothing to
/// compare or calibrate, and every model fitted to them would report a zero rate as a result.
/// The error is the sentence to report against the after map (bad input).
pub fn check_measured_removal(
    before: &bonnetlab_surface::Surface,
    after: &bonnetlab_surface::Surface,
) -> Result<(), &'static str> {
    let same = before.dim() == after.dim()
        && before.valid() == after.valid()
        && before
            .heights_nm()
            .iter()
            .zip(after.heights_nm())
            .zip(before.valid())
            .all(|((a, b), &v)| !v || a == b);
    if same {
        Err(
            "the after map holds the same heights as the before map on every valid pixel: \
             there is no measured removal (the same measurement named twice?)",
        )
    } else {
        Ok(())
    }
}

impl Recipe {
    /// Reads the path log this recipe names; errors say so ([`read_named_path_log`]).
    pub fn read_path_log(&self) -> Result<crate::PathLog, ProcessError> {
        read_named_path_log(&self.path_log, &self.file)
    }

    /// Reads and validates a recipe file.
    pub fn load(path: &Path) -> Result<Recipe, ProcessError> {
        Recipe::parse(&read_recipe_text(path)?, path)
    }

    /// Parses recipe text; `path` names the file in errors and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Recipe, ProcessError> {
        Recipe::from_doc(RecipeDoc::parse(text, path)?, path)
    }

    /// Validates a typed recipe document; `path` names the file and anchors relative paths.
    pub fn from_doc(doc: RecipeDoc, path: &Path) -> Result<Recipe, ProcessError> {
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let cx = Ctx { file: path, dir };
        let bonnet = doc.bonnet(path)?.unwrap_or_else(|| "original".into());
        let m = doc
            .measurement
            .as_ref()
            .ok_or_else(|| cx.err("[measurement]", "missing table"))?;
        let before = cx
            .file_path(m.before.as_ref())
            .ok_or_else(|| cx.err("[measurement] before", "missing"))?;
        let after = cx.file_path(m.after.as_ref());
        let pixels = match m.pixels.as_deref() {
            None => PixelSampling::Point,
            Some(name) => PixelSampling::from_name(name).ok_or_else(|| {
                cx.err(
                    "[measurement] pixels",
                    format!("must be \"point\" or \"area\", got \"{name}\""),
                )
            })?,
        };
        let repeatability_nm = cx.positive(m.repeatability_nm, "[measurement] repeatability_nm")?;

        let pt = doc.process.clone().unwrap_or_default();
        let process = ProcessParams {
            bonnet,
            spindle_rpm: cx.positive(pt.spindle_rpm, "[process] spindle_rpm")?,
            offset_mm: cx.positive(pt.offset_mm, "[process] offset_mm")?,
            precession_deg: cx.finite(pt.precession_deg, "[process] precession_deg")?,
            inner_pressure_mpa: cx
                .positive(pt.inner_pressure_mpa, "[process] inner_pressure_mpa")?,
        };

        let t = doc
            .tif
            .as_ref()
            .ok_or_else(|| cx.err("[tif]", "missing table"))?;
        let tif = match (&t.spot, &t.model) {
            (Some(_), Some(_)) => {
                return Err(cx.err("[tif]", "give either spot + dwell_s or model, not both"))
            }
            (None, None) => return Err(cx.err("[tif]", "missing spot (with dwell_s) or model")),
            (Some(_), None) => {
                let p = cx
                    .file_path(t.spot.as_ref())
                    .ok_or_else(|| cx.err("[tif] spot", "missing"))?;
                let dwell_s = cx.req_positive(t.dwell_s, "[tif] dwell_s")?;
                TifSource::Spot { path: p, dwell_s }
            }
            (None, Some(mt)) => parse_model(&cx, mt, &process)?,
        };

        let pt = doc
            .path
            .as_ref()
            .ok_or_else(|| cx.err("[path]", "missing table"))?;
        let path_log = cx
            .file_path(pt.log.as_ref())
            .ok_or_else(|| cx.err("[path] log", "missing"))?;
        let pitch_mm = cx.positive(pt.pitch_mm, "[path] pitch_mm")?;

        Ok(Recipe {
            file: path.to_path_buf(),
            before,
            after,
            tif,
            path_log,
            pitch_mm,
            process,
            vibration: doc.vibration,
            pixels,
            repeatability_nm,
        })
    }
}

fn parse_model(
    cx: &Ctx,
    mt: &ModelTable,
    process: &ProcessParams,
) -> Result<TifSource, ProcessError> {
    let kind = mt
        .kind
        .as_deref()
        .ok_or_else(|| cx.err("[tif.model] kind", "missing"))?
        .to_ascii_lowercase();
    // Keys of the other kind are errors, not silently ignored.
    let given = |pairs: &[(&str, bool)]| -> Result<(), ProcessError> {
        match pairs.iter().find(|p| p.1) {
            Some((k, _)) => Err(cx.err(
                &format!("[tif.model] {k}"),
                format!("is not a key of a {kind} model"),
            )),
            None => Ok(()),
        }
    };
    match kind.as_str() {
        "gaussian" => {
            given(&[
                (
                    "volume_rate_nm_mm2_per_s",
                    mt.volume_rate_nm_mm2_per_s.is_some(),
                ),
                ("radius_mm", mt.radius_mm.is_some()),
                ("offset_mm", mt.offset_mm.is_some()),
                ("precession_deg", mt.precession_deg.is_some()),
                ("spindle_rpm", mt.spindle_rpm.is_some()),
                ("pressure", mt.pressure.is_some()),
                ("precession_steps", mt.precession_steps.is_some()),
            ])?;
            let sigma = cx.req_positive(mt.sigma_mm, "[tif.model] sigma_mm")?;
            let peak = cx.req_positive(mt.peak_rate_nm_per_s, "[tif.model] peak_rate_nm_per_s")?;
            let d = cx
                .positive(mt.diameter_mm, "[tif.model] diameter_mm")?
                .unwrap_or(6.0 * sigma);
            GaussianTif::new(sigma, d, peak)
                .map(TifSource::Gaussian)
                .map_err(|e| cx.err("[tif.model]", e.to_string()))
        }
        "bonnet" => {
            given(&[
                ("sigma_mm", mt.sigma_mm.is_some()),
                ("diameter_mm", mt.diameter_mm.is_some()),
            ])?;
            let or = |v: Option<f64>, from: Option<f64>, key: &str| {
                v.or(from).ok_or_else(|| {
                    cx.err(
                        &format!("[tif.model] {key}"),
                        "missing (and not in [process])",
                    )
                })
            };
            let pressure = match mt.pressure.as_deref() {
                None => PressureProfile::Hertz,
                Some(s) => PressureProfile::parse(s).ok_or_else(|| {
                    cx.err(
                        "[tif.model] pressure",
                        format!("must be hertz, parabolic or uniform, got \"{s}\""),
                    )
                })?,
            };
            let scale = match (
                cx.positive(mt.peak_rate_nm_per_s, "[tif.model] peak_rate_nm_per_s")?,
                cx.positive(
                    mt.volume_rate_nm_mm2_per_s,
                    "[tif.model] volume_rate_nm_mm2_per_s",
                )?,
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
            let steps = match mt.precession_steps {
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
                radius_mm: cx
                    .positive(mt.radius_mm, "[tif.model] radius_mm")?
                    .unwrap_or(20.0),
                offset_mm: or(
                    cx.positive(mt.offset_mm, "[tif.model] offset_mm")?,
                    process.offset_mm,
                    "offset_mm",
                )?,
                precession_deg: or(
                    cx.finite(mt.precession_deg, "[tif.model] precession_deg")?,
                    process.precession_deg,
                    "precession_deg",
                )?,
                spindle_rpm: or(
                    cx.positive(mt.spindle_rpm, "[tif.model] spindle_rpm")?,
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
        other => {
            let hint = crate::config::nearest(other, &["gaussian", "bonnet"])
                .map(|n| format!("; did you mean \"{n}\"?"))
                .unwrap_or_default();
            Err(cx.err(
                "[tif.model] kind",
                format!("must be \"gaussian\" or \"bonnet\", got \"{other}\"{hint}"),
            ))
        }
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
    fn pixels_default_to_points_and_read_area() {
        let r = Recipe::parse(FULL, Path::new("r.toml")).unwrap();
        assert_eq!(r.pixels, PixelSampling::Point);
        let text = FULL.replace(
            "before = \"before.dat\"",
            "before = \"before.dat\"\npixels = \"area\"",
        );
        assert_ne!(text, FULL);
        let r = Recipe::parse(&text, Path::new("r.toml")).unwrap();
        assert_eq!(r.pixels, PixelSampling::Area);
    }

    #[test]
    fn repeatability_is_optional_and_positive() {
        let r = Recipe::parse(FULL, Path::new("r.toml")).unwrap();
        assert_eq!(r.repeatability_nm, None);
        let with = |v: &str| {
            FULL.replace(
                "before = \"before.dat\"",
                &format!("before = \"before.dat\"\nrepeatability_nm = {v}"),
            )
        };
        let r = Recipe::parse(&with("1.25"), Path::new("r.toml")).unwrap();
        assert_eq!(r.repeatability_nm, Some(1.25));
        for bad in ["0.0", "-1.0", "\"x\""] {
            let e = Recipe::parse(&with(bad), Path::new("r.toml")).unwrap_err();
            let msg = e.to_string();
            assert!(msg.contains("r.toml"), "{msg}");
            assert!(msg.contains("repeatability_nm"), "{msg}");
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
            (
                FULL.replace(
                    "before = \"before.dat\"",
                    "before = \"before.dat\"\npixels = \"mean\"",
                ),
                "[measurement] pixels",
            ),
        ];
        for (text, key) in cases {
            let e = Recipe::parse(&text, Path::new("runs/r.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("runs/r.toml: ") && e.contains(key), "{e}");
        }
    }
}
