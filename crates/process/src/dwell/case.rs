//! Dwell case files: the TOML of `shared/data/dwell/*.toml` (surface, Gaussian TIF, clear
//! aperture in pixel rows / columns, optional reference results). The surface path is relative
//! to the case file; the map is read by the caller (`bonnetlab_io`), so this crate stays free of
//! file formats.

use std::path::{Path, PathBuf};

use bonnetlab_surface::Surface;
use ndarray::{s, Array2};
use toml::{Table, Value};

use super::DwellProblem;
use crate::error::ProcessError;
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
            err(
                "TOML",
                e.to_string()
                    .lines()
                    .next()
                    .unwrap_or("invalid TOML")
                    .to_string(),
            )
        })?;
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
        })
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
