//! Dwell case files: the TOML of `shared/data/dwell/*.toml` (surface, Gaussian TIF, clear
//! aperture in pixel rows / columns, optional reference results). The surface path is relative
//! to the case file; the map is read by the caller (`bonnetlab_io`), so this crate stays free of
//! file formats.
//!
//! Unknown keys are rejected (a typo must never be silently ignored), naming the key and the
//! nearest valid key by edit distance; `[reference]` is free-form. An optional `[machine]` table
//! gives the speed and acceleration limits of the feed realisation ([`Limits`]; defaults:
//! `Limits::default()`).

use std::path::{Path, PathBuf};

use bonnetlab_surface::Surface;
use ndarray::{s, Array2};
use toml::{Table, Value};

use super::DwellProblem;
use crate::error::ProcessError;
use crate::path::kinematics::Limits;
use crate::tif::{GaussianTif, Tif};

/// A parsed dwell case.
#[derive(Debug, Clone, PartialEq)]
pub struct DwellCase {
    pub file: PathBuf,
    pub surface: PathBuf,
    /// Pixel size the case states (overrides the map's own, which may be rounded to f32).
    pub pixel_mm: f64,
    pub tif: GaussianTif,
    /// Clear aperture rows and columns, end exclusive.
    pub ca_rows: (usize, usize),
    pub ca_cols: (usize, usize),
    /// The `[reference]` table, kept raw.
    pub reference: Option<Table>,
    /// Machine limits for the feed realisation (`[machine]`).
    pub limits: Limits,
}

/// Keys each table may hold (`None`: the top level); `[reference]` is free-form.
const SCHEMA: [(&str, &[&str]); 4] = [
    (
        "",
        &[
            "surface",
            "pixel_mm",
            "tif",
            "clear_aperture",
            "reference",
            "machine",
        ],
    ),
    (
        "tif",
        &["kind", "sigma_mm", "diameter_mm", "peak_rate_nm_per_s"],
    ),
    ("clear_aperture", &["rows", "cols", "x_mm", "y_mm"]),
    (
        "machine",
        &[
            "v_min_mm_per_s",
            "v_max_mm_per_s",
            "a_max_mm_per_s2",
            "stop_angle_deg",
        ],
    ),
];

/// Levenshtein distance (for the nearest valid key).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            cur[j + 1] = (prev[j] + usize::from(ca != *cb))
                .min(prev[j + 1] + 1)
                .min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

/// Edit distance to a valid key, or to its prefix of the same length plus one (so a
/// shortened key such as `a_max` finds `a_max_mm_per_s2`).
fn key_distance(key: &str, valid: &str) -> usize {
    let n = key.chars().count();
    let prefix: String = valid.chars().take(n).collect();
    let p = if prefix.len() < valid.len() {
        edit_distance(key, &prefix) + 1
    } else {
        usize::MAX
    };
    edit_distance(key, valid).min(p)
}

/// The first unknown key of `root` (table path, key, nearest valid key).
fn unknown_key(root: &Table) -> Option<(String, String, &'static str)> {
    for (table, keys) in SCHEMA {
        let t = if table.is_empty() {
            root
        } else {
            match root.get(table).and_then(Value::as_table) {
                Some(t) => t,
                None => continue,
            }
        };
        for k in t.keys() {
            if !keys.contains(&k.as_str()) {
                let near = keys
                    .iter()
                    .min_by_key(|c| key_distance(k, c))
                    .copied()
                    .unwrap_or("");
                let path = if table.is_empty() {
                    k.clone()
                } else {
                    format!("[{table}] {k}")
                };
                return Some((path, k.clone(), near));
            }
        }
    }
    None
}

/// Line and column (1-based) of byte offset `at` in `text`.
fn line_col(text: &str, at: usize) -> (usize, usize) {
    let before = &text[..at.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// A case's problem and where its dwell grid sits in the map.
#[derive(Debug, Clone)]
pub struct CaseProblem {
    pub problem: DwellProblem,
    /// Map (row, col) of the dwell grid's pixel (0, 0).
    pub offset: (usize, usize),
}

impl DwellCase {
    pub fn load(path: &Path) -> Result<DwellCase, ProcessError> {
        let text = bonnetlab_io::input::read_text(
            path,
            bonnetlab_io::input::TEXT_LIMIT,
            "a dwell case (TOML)",
        )
        .map_err(|e| ProcessError::Io {
            file: path.to_path_buf(),
            what: e.to_string(),
        })?;
        DwellCase::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<DwellCase, ProcessError> {
        let err = |key: &str, what: String| ProcessError::Recipe {
            file: path.to_path_buf(),
            key: key.to_string(),
            what,
        };
        let root: Table = text.parse().map_err(|e: toml::de::Error| {
            let at = e
                .span()
                .map(|r| {
                    let (l, c) = line_col(text, r.start);
                    format!("line {l} column {c}: ")
                })
                .unwrap_or_default();
            err("TOML syntax", format!("{at}{}", e.message().trim()))
        })?;
        if let Some((path, key, near)) = unknown_key(&root) {
            return Err(err(
                &path,
                format!("unknown key `{key}` (did you mean `{near}`?)"),
            ));
        }
        let num = |t: &Table, key: &str, name: &str| -> Result<f64, ProcessError> {
            match t.get(key) {
                Some(Value::Float(f)) if f.is_finite() && *f > 0.0 => Ok(*f),
                Some(Value::Integer(i)) if *i > 0 => Ok(*i as f64),
                Some(_) => Err(err(name, "must be a positive number".into())),
                None => Err(err(name, "missing".into())),
            }
        };
        let range = |t: &Table, key: &str, name: &str| -> Result<(usize, usize), ProcessError> {
            let bad = || {
                err(
                    name,
                    "must be [start, end) with 0 <= start < end integers".into(),
                )
            };
            let a = t.get(key).and_then(Value::as_array).ok_or_else(bad)?;
            match a.as_slice() {
                [Value::Integer(x), Value::Integer(y)] if *x >= 0 && y > x => {
                    Ok((*x as usize, *y as usize))
                }
                _ => Err(bad()),
            }
        };
        let surface = match root.get("surface") {
            Some(Value::String(s)) => path.parent().unwrap_or(Path::new("")).join(s),
            _ => return Err(err("surface", "missing or not a string".into())),
        };
        let pixel_mm = num(&root, "pixel_mm", "pixel_mm")?;
        let tif_t = root
            .get("tif")
            .and_then(Value::as_table)
            .ok_or_else(|| err("[tif]", "missing table".into()))?;
        match tif_t.get("kind").and_then(Value::as_str) {
            Some("gaussian") => {}
            other => {
                return Err(err(
                    "[tif] kind",
                    format!("must be \"gaussian\", got {other:?}"),
                ))
            }
        }
        let tif = GaussianTif::new(
            num(tif_t, "sigma_mm", "[tif] sigma_mm")?,
            num(tif_t, "diameter_mm", "[tif] diameter_mm")?,
            num(tif_t, "peak_rate_nm_per_s", "[tif] peak_rate_nm_per_s")?,
        )
        .map_err(|e| err("[tif]", e.to_string()))?;
        let ca = root
            .get("clear_aperture")
            .and_then(Value::as_table)
            .ok_or_else(|| err("[clear_aperture]", "missing table".into()))?;
        Ok(DwellCase {
            file: path.to_path_buf(),
            surface,
            pixel_mm,
            tif,
            ca_rows: range(ca, "rows", "[clear_aperture] rows")?,
            ca_cols: range(ca, "cols", "[clear_aperture] cols")?,
            reference: root.get("reference").and_then(Value::as_table).cloned(),
            limits: machine_limits(&root, &err)?,
        })
    }

    /// The case's dwell grid in the map frame (mm): the CA grown by the TIF radius.
    pub fn dwell_grid(&self, cp: &CaseProblem) -> Result<crate::grid::Grid, ProcessError> {
        let (r, c) = cp.problem.dim();
        crate::grid::Grid::new(
            r,
            c,
            self.pixel_mm,
            self.pixel_mm,
            cp.offset.1 as f64 * self.pixel_mm,
            cp.offset.0 as f64 * self.pixel_mm,
        )
    }

    /// The TIF sampled at the case's pixel (point samples inside the disc, as the cases' own
    /// reference scripts do).
    pub fn sampled_tif(&self) -> Result<Tif, ProcessError> {
        Tif::sample(&self.tif, self.pixel_mm, self.pixel_mm)
    }

    /// Builds the problem from the case's map: desired removal = surface - min over the CA,
    /// dwell grid = CA grown by the TIF half-width. Every dwell-grid pixel must be valid.
    pub fn problem(&self, map: &Surface) -> Result<CaseProblem, ProcessError> {
        let tif = self.sampled_tif()?;
        let (h0, h1) = tif.half_widths();
        let (r0, r1) = self.ca_rows;
        let (c0, c1) = self.ca_cols;
        let (rows, cols) = map.dim();
        if r0 < h0 || c0 < h1 || r1 + h0 > rows || c1 + h1 > cols {
            return Err(ProcessError::invalid(format!(
                "{}: the clear aperture grown by the TIF radius ({h0} x {h1} px) leaves the {rows} x {cols} map",
                self.file.display()
            )));
        }
        let (dr0, dc0) = (r0 - h0, c0 - h1);
        let (dr1, dc1) = (r1 + h0, c1 + h1);
        let window = s![dr0..dr1, dc0..dc1];
        if map.valid().slice(window).iter().any(|v| !v) {
            return Err(ProcessError::Processing(format!(
                "{}: the map has invalid pixels inside the dwell grid",
                self.file.display()
            )));
        }
        let h = map.heights_nm().slice(window).to_owned();
        let ca_min = map
            .heights_nm()
            .slice(s![r0..r1, c0..c1])
            .iter()
            .fold(f64::INFINITY, |m, &v| m.min(v));
        let desired = h.mapv(|v| v - ca_min);
        let aperture = Array2::from_shape_fn(desired.dim(), |(i, j)| {
            (h0..h0 + (r1 - r0)).contains(&i) && (h1..h1 + (c1 - c0)).contains(&j)
        });
        Ok(CaseProblem {
            problem: DwellProblem::new(desired, aperture, tif)?,
            offset: (dr0, dc0),
        })
    }

    /// A reference figure, e.g. `reference_value("rifta_repo_script", "residual_rms_nm")`.
    pub fn reference_value(&self, entry: &str, key: &str) -> Option<f64> {
        let v = self.reference.as_ref()?.get(entry)?;
        match v {
            Value::Table(t) => t
                .get(key)
                .and_then(|x| x.as_float().or(x.as_integer().map(|i| i as f64))),
            Value::Float(f) if key.is_empty() => Some(*f),
            _ => None,
        }
    }
}

/// The `[machine]` limits (defaults for absent keys), checked.
fn machine_limits(
    root: &Table,
    err: &dyn Fn(&str, String) -> ProcessError,
) -> Result<Limits, ProcessError> {
    let mut l = Limits::default();
    let Some(v) = root.get("machine") else {
        return Ok(l);
    };
    let t = v
        .as_table()
        .ok_or_else(|| err("[machine]", "must be a table".into()))?;
    for (key, slot) in [
        ("v_min_mm_per_s", &mut l.v_min_mm_per_s),
        ("v_max_mm_per_s", &mut l.v_max_mm_per_s),
        ("a_max_mm_per_s2", &mut l.a_max_mm_per_s2),
        ("stop_angle_deg", &mut l.stop_angle_deg),
    ] {
        match t.get(key) {
            None => {}
            Some(Value::Float(f)) if f.is_finite() && *f > 0.0 => *slot = *f,
            Some(Value::Integer(i)) if *i > 0 => *slot = *i as f64,
            Some(_) => {
                return Err(err(
                    &format!("[machine] {key}"),
                    "must be a positive number".into(),
                ))
            }
        }
    }
    if l.v_min_mm_per_s > l.v_max_mm_per_s {
        return Err(err(
            "[machine]",
            "v_min_mm_per_s must not exceed v_max_mm_per_s".into(),
        ));
    }
    Ok(l)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "surface = \"s.dat\"\npixel_mm = 0.5\n[tif]\nkind = \"gaussian\"\nsigma_mm = 1.0\ndiameter_mm = 6.0\npeak_rate_nm_per_s = 1.0\n[clear_aperture]\nrows = [10, 20]\ncols = [10, 30]\n";

    fn parse(text: &str) -> Result<DwellCase, ProcessError> {
        DwellCase::parse(text, Path::new("case.toml"))
    }

    #[test]
    fn unknown_keys_name_the_key_and_the_nearest_valid_one() {
        assert!(parse(GOOD).is_ok());
        let e = parse(&GOOD.replace("sigma_mm", "sigma_nm"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("case.toml: [tif] sigma_nm: unknown key") && e.contains("`sigma_mm`"),
            "{e}"
        );
        let e = parse(&format!("{GOOD}[machine]\na_max = 5.0\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[machine] a_max") && e.contains("`a_max_mm_per_s2`"),
            "{e}"
        );
        let e = parse(&format!("pixle_mm = 1\n{GOOD}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("pixle_mm") && e.contains("`pixel_mm`"), "{e}");
        let c = parse(&format!("{GOOD}[machine]\nv_max_mm_per_s = 20\n")).unwrap();
        assert_eq!(c.limits.v_max_mm_per_s, 20.0);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
    }

    #[test]
    fn syntax_errors_carry_the_cause_and_place() {
        let e = parse("surface = \"s.dat\nbad").unwrap_err().to_string();
        assert!(
            e.starts_with("case.toml: TOML syntax: line 2 column 4: ") && e.contains("expected"),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }
}
