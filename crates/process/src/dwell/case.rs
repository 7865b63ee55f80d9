//! Dwell case files: the TOML of `shared/data/dwell/*.toml` (surface, Gaussian TIF, clear
//! aperture in pixel rows / columns, optional reference results). The surface path is relative
//! to the case file; the map is read by the caller (`bonnetlab_io`), so this crate stays free of
//! file formats.
//!
//! Read with serde into typed tables through [`crate::config`]: unknown tables and keys are
//! rejected (a typo must never be silently ignored), naming the key and the nearest valid key;
//! a wrong type says what was expected; `[reference]` is free-form. An optional `[machine]` table
//! gives the speed and acceleration limits of the feed realisation ([`Limits`]; defaults:
//! `Limits::default()`).

use std::path::{Path, PathBuf};

use bonnetlab_surface::Surface;
use ndarray::{s, Array2};
use serde::Deserialize;
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

/// The case file as written: typed and strict (an unknown table or key is an error naming the
/// nearest valid name, [`crate::config`]); `[reference]` is free-form.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseDoc {
    surface: Option<String>,
    pixel_mm: Option<f64>,
    tif: Option<CaseTif>,
    clear_aperture: Option<CaseAperture>,
    reference: Option<Table>,
    machine: Option<CaseMachine>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseTif {
    kind: Option<String>,
    sigma_mm: Option<f64>,
    diameter_mm: Option<f64>,
    peak_rate_nm_per_s: Option<f64>,
}

/// Relative difference allowed between a case's `pixel_mm` and the pixel size its map
/// carries (MetroPro stores it in single precision: 2.5e-8 of 0.1 mm).
const PIXEL_TOLERANCE: f64 = 1e-6;

/// `rows` / `cols` are the clear aperture; `x_mm` / `y_mm` (optional) the same in mm: the
/// centres of its first and last columns (rows), `[start * pixel_mm, (end - 1) * pixel_mm]`,
/// checked against `rows` / `cols` to half a pixel.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseAperture {
    rows: Option<[i64; 2]>,
    cols: Option<[i64; 2]>,
    x_mm: Option<[f64; 2]>,
    y_mm: Option<[f64; 2]>,
}

/// Checks an aperture's extent in mm (`key`, the centres of its first and last pixels) against
/// its pixel range [start, end) at `pixel_mm`, to half a pixel.
fn check_extent_mm(
    mm: Option<[f64; 2]>,
    (start, end): (usize, usize),
    pixel_mm: f64,
) -> Result<(), String> {
    let Some([a, b]) = mm else { return Ok(()) };
    let sig = bonnetlab_surface::format::sig;
    let want = [start as f64 * pixel_mm, (end - 1) as f64 * pixel_mm];
    if (a - want[0]).abs() > 0.5 * pixel_mm || (b - want[1]).abs() > 0.5 * pixel_mm {
        return Err(format!(
            "[{}, {}] mm disagrees with pixels [{start}, {end}) at {} mm, whose first and last \
             centres are [{}, {}] mm",
            sig(a, 7),
            sig(b, 7),
            sig(pixel_mm, 7),
            sig(want[0], 7),
            sig(want[1], 7)
        ));
    }
    Ok(())
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseMachine {
    v_min_mm_per_s: Option<f64>,
    v_max_mm_per_s: Option<f64>,
    a_max_mm_per_s2: Option<f64>,
    stop_angle_deg: Option<f64>,
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
        let doc: CaseDoc = crate::config::from_toml(text).map_err(|e| err(&e.key, e.what))?;
        let num = |v: Option<f64>, name: &str| -> Result<f64, ProcessError> {
            let (lo, hi) = plausible(name);
            match v {
                Some(f) if f.is_finite() && f > 0.0 && (lo..=hi).contains(&f) => Ok(f),
                Some(f) if f.is_finite() && f > 0.0 => Err(err(
                    name,
                    format!("{f} is outside the plausible range {lo:e} ..= {hi:e}"),
                )),
                Some(_) => Err(err(name, "must be a positive number".into())),
                None => Err(err(name, "missing".into())),
            }
        };
        let range = |v: Option<[i64; 2]>, name: &str| -> Result<(usize, usize), ProcessError> {
            match v {
                Some([x, y]) if x >= 0 && y > x && y <= MAX_PIXELS as i64 => {
                    Ok((x as usize, y as usize))
                }
                _ => Err(err(
                    name,
                    format!("must be [start, end) with 0 <= start < end <= {MAX_PIXELS} integers"),
                )),
            }
        };
        let surface = match &doc.surface {
            Some(s) => path.parent().unwrap_or(Path::new("")).join(s),
            None => return Err(err("surface", "missing".into())),
        };
        let pixel_mm = num(doc.pixel_mm, "pixel_mm")?;
        let tif_t = doc
            .tif
            .as_ref()
            .ok_or_else(|| err("[tif]", "missing table".into()))?;
        match tif_t.kind.as_deref() {
            Some(k) if TIF_MODELS.contains(&k) => {}
            other => return Err(err("[tif] kind", tif_model_error(other))),
        }
        let tif = GaussianTif::new(
            num(tif_t.sigma_mm, "[tif] sigma_mm")?,
            num(tif_t.diameter_mm, "[tif] diameter_mm")?,
            num(tif_t.peak_rate_nm_per_s, "[tif] peak_rate_nm_per_s")?,
        )
        .map_err(|e| err("[tif]", e.to_string()))?;
        // The sampled TIF is diameter / pixel_mm pixels wide: bound it before anything is
        // allocated.
        let across = tif.diameter_mm / pixel_mm;
        if across > MAX_TIF_PIXELS {
            return Err(err(
                "[tif] diameter_mm",
                format!(
                    "{} mm is {across:.3e} pixels of {pixel_mm} mm (at most {MAX_TIF_PIXELS})",
                    tif.diameter_mm
                ),
            ));
        }
        let ca = doc
            .clear_aperture
            .as_ref()
            .ok_or_else(|| err("[clear_aperture]", "missing table".into()))?;
        let ca_rows = range(ca.rows, "[clear_aperture] rows")?;
        let ca_cols = range(ca.cols, "[clear_aperture] cols")?;
        check_extent_mm(ca.x_mm, ca_cols, pixel_mm).map_err(|e| err("[clear_aperture] x_mm", e))?;
        check_extent_mm(ca.y_mm, ca_rows, pixel_mm).map_err(|e| err("[clear_aperture] y_mm", e))?;
        Ok(DwellCase {
            file: path.to_path_buf(),
            surface,
            pixel_mm,
            tif,
            ca_rows,
            ca_cols,
            limits: machine_limits(doc.machine.as_ref(), &err)?,
            reference: doc.reference,
        })
    }

    /// The case's dwell grid in the map frame (mm): the CA grown by the TIF radius.
    pub fn dwell_grid(&self, cp: &CaseProblem) -> Result<crate::grid::Grid, ProcessError> {
        let (r, c) = cp.problem.dim();
        Ok(crate::grid::Grid::new(
            r,
            c,
            self.pixel_mm,
            self.pixel_mm,
            cp.offset.1 as f64 * self.pixel_mm,
            cp.offset.0 as f64 * self.pixel_mm,
        )?)
    }

    /// The TIF sampled at the case's pixel (point samples inside the disc, as the cases' own
    /// reference scripts do).
    pub fn sampled_tif(&self) -> Result<Tif, ProcessError> {
        Tif::sample(&self.tif, self.pixel_mm, self.pixel_mm)
    }

    /// Builds the problem from the case's map: desired removal = surface - min over the CA,
    /// dwell grid = CA grown by the TIF half-width. Invalid pixels of the dwell grid (at most
    /// 10 %) are filled from their valid neighbours and left out of the clear aperture.
    pub fn problem(&self, map: &Surface) -> Result<CaseProblem, ProcessError> {
        // A pixel size the map carries wins over any other (conventions.md): a case that
        // says another one describes a different map.
        for (axis, d) in [("x", map.dx_mm), ("y", map.dy_mm)] {
            if let Some(d) = d {
                if (d - self.pixel_mm).abs() > PIXEL_TOLERANCE * self.pixel_mm {
                    return Err(ProcessError::invalid(format!(
                        "{}: pixel_mm = {} but the map {} carries {} mm along {axis}; give the \
                         map's pixel size",
                        self.file.display(),
                        bonnetlab_surface::format::sig(self.pixel_mm, 7),
                        self.surface.display(),
                        bonnetlab_surface::format::sig(d, 7)
                    )));
                }
            }
        }
        let tif = self.sampled_tif()?;
        let (h0, h1) = tif.half_widths();
        let (r0, r1) = self.ca_rows;
        let (c0, c1) = self.ca_cols;
        let (rows, cols) = map.dim();
        if r0 < h0 || c0 < h1 || r1 + h0 > rows || c1 + h1 > cols {
            return Err(ProcessError::invalid(format!(
                "{}: [clear_aperture] rows [{r0}, {r1}), cols [{c0}, {c1}) grown by the TIF \
                 half-width ({h0} rows, {h1} cols) reaches past the {rows} x {cols} map; keep \
                 the clear aperture at least that far inside the map",
                self.file.display()
            )));
        }
        let (dr0, dc0) = (r0 - h0, c0 - h1);
        let (dr1, dc1) = (r1 + h0, c1 + h1);
        let window = s![dr0..dr1, dc0..dc1];
        // Dropouts inside the dwell grid (a measured map always has a few) are filled from
        // their valid neighbours for the desired removal and left out of the clear aperture,
        // where the residual is evaluated; beyond MAX_INVALID_FRACTION of the grid the map is
        // refused.
        let valid = map.valid().slice(window).to_owned();
        let invalid = valid.iter().filter(|v| !**v).count();
        if invalid as f64 > MAX_INVALID_FRACTION * valid.len() as f64 {
            return Err(ProcessError::Processing(format!(
                "{}: {invalid} of the dwell grid's {} pixels are invalid in the map (at most {} % may be)",
                self.file.display(),
                valid.len(),
                100.0 * MAX_INVALID_FRACTION
            )));
        }
        let h = bonnetlab_surface::fill::fill_invalid(
            &map.heights_nm().slice(window).to_owned(),
            &valid,
        );
        let ca_min = map
            .heights_nm()
            .slice(s![r0..r1, c0..c1])
            .iter()
            .zip(map.valid().slice(s![r0..r1, c0..c1]))
            .filter(|(_, &ok)| ok)
            .fold(f64::INFINITY, |m, (&v, _)| m.min(v));
        if !ca_min.is_finite() {
            return Err(ProcessError::Processing(format!(
                "{}: the clear aperture has no valid pixel in the map",
                self.file.display()
            )));
        }
        let desired = h.mapv(|v| v - ca_min);
        let aperture = Array2::from_shape_fn(desired.dim(), |(i, j)| {
            valid[(i, j)] && (h0..h0 + (r1 - r0)).contains(&i) && (h1..h1 + (c1 - c0)).contains(&j)
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

/// Largest fraction of the dwell grid's pixels that may be invalid in the map (filled from their
/// neighbours and left out of the residual).
const MAX_INVALID_FRACTION: f64 = 0.1;

/// The TIF models a case may name in `[tif] kind`.
const TIF_MODELS: [&str; 1] = ["gaussian"];

/// The error of a `[tif] kind` that is missing or names no model: the models there are and,
/// for a misspelt name, the nearest (`unknown TIF model "gausian"; expected one of
/// "gaussian" (did you mean "gaussian"?)`).
fn tif_model_error(kind: Option<&str>) -> String {
    let expected: Vec<String> = TIF_MODELS.iter().map(|m| format!("{m:?}")).collect();
    let expected = expected.join(", ");
    let Some(kind) = kind else {
        return format!("missing; expected one of {expected}");
    };
    let n = kind.chars().count();
    let shown = if n > 64 {
        let start: String = kind.chars().take(40).collect();
        format!("{start:?}…({n} characters)")
    } else {
        format!("{kind:?}")
    };
    let hint = crate::config::nearest(kind, &TIF_MODELS)
        .filter(|m| crate::config::edit_distance(&kind.to_lowercase(), m) <= 3)
        .map(|m| format!(" (did you mean {m:?}?)"))
        .unwrap_or_default();
    format!("unknown TIF model {shown}; expected one of {expected}{hint}")
}

/// Largest clear-aperture row / column index (end exclusive) a case may name.
const MAX_PIXELS: usize = 1_000_000;

/// Largest sampled TIF width (pixels across its disc).
const MAX_TIF_PIXELS: f64 = 4001.0;

/// The plausible range of a positive case number (units of its key): far wider than any lab
/// uses, narrow enough that a typo in an exponent (1e300, 1e-300) is caught by name.
fn plausible(key: &str) -> (f64, f64) {
    match key {
        "pixel_mm" => (1e-6, 1e3),
        "[tif] sigma_mm" | "[tif] diameter_mm" => (1e-6, 1e4),
        "[tif] peak_rate_nm_per_s" => (1e-9, 1e9),
        "[machine] v_min_mm_per_s" | "[machine] v_max_mm_per_s" => (1e-9, 1e6),
        "[machine] a_max_mm_per_s2" => (1e-9, 1e9),
        "[machine] stop_angle_deg" => (1e-9, 180.0),
        _ => (f64::MIN_POSITIVE, f64::MAX),
    }
}

/// The `[machine]` limits (defaults for absent keys), checked.
fn machine_limits(
    m: Option<&CaseMachine>,
    err: &dyn Fn(&str, String) -> ProcessError,
) -> Result<Limits, ProcessError> {
    let mut l = Limits::default();
    let Some(m) = m else {
        return Ok(l);
    };
    for (key, v, slot) in [
        ("v_min_mm_per_s", m.v_min_mm_per_s, &mut l.v_min_mm_per_s),
        ("v_max_mm_per_s", m.v_max_mm_per_s, &mut l.v_max_mm_per_s),
        ("a_max_mm_per_s2", m.a_max_mm_per_s2, &mut l.a_max_mm_per_s2),
        ("stop_angle_deg", m.stop_angle_deg, &mut l.stop_angle_deg),
    ] {
        let name = format!("[machine] {key}");
        let (lo, hi) = plausible(&name);
        match v {
            None => {}
            Some(f) if f.is_finite() && f > 0.0 && (lo..=hi).contains(&f) => *slot = f,
            Some(f) if f.is_finite() && f > 0.0 => {
                return Err(err(
                    &name,
                    format!("{f} is outside the plausible range {lo:e} ..= {hi:e}"),
                ))
            }
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
    }

    /// An unknown TIF model names the models there are and the nearest; a missing one says so.
    #[test]
    fn unknown_tif_model_names_the_models_and_the_nearest() {
        let e = parse(&GOOD.replace("\"gaussian\"", "\"gausian\""))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "case.toml: [tif] kind: unknown TIF model \"gausian\"; expected one of \"gaussian\" \
             (did you mean \"gaussian\"?)"
        );
        let e = parse(&GOOD.replace("\"gaussian\"", "\"zernike\""))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "case.toml: [tif] kind: unknown TIF model \"zernike\"; expected one of \"gaussian\""
        );
        let e = parse(&GOOD.replace("kind = \"gaussian\"\n", ""))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "case.toml: [tif] kind: missing; expected one of \"gaussian\""
        );
        let long = "x".repeat(1000);
        let e = parse(&GOOD.replace("gaussian", &long))
            .unwrap_err()
            .to_string();
        assert!(e.contains("(1000 characters)") && e.len() < 200, "{e}");
    }

    /// Absurd finite numbers (issue #18) are errors naming the key, before anything is sized
    /// from them.
    #[test]
    fn absurd_numbers_name_the_key() {
        for (from, to, key) in [
            (
                "peak_rate_nm_per_s = 1.0",
                "peak_rate_nm_per_s = 1e300",
                "[tif] peak_rate_nm_per_s",
            ),
            (
                "peak_rate_nm_per_s = 1.0",
                "peak_rate_nm_per_s = 1e-300",
                "[tif] peak_rate_nm_per_s",
            ),
            (
                "peak_rate_nm_per_s = 1.0",
                "peak_rate_nm_per_s = -2.0",
                "[tif] peak_rate_nm_per_s",
            ),
            ("pixel_mm = 0.5", "pixel_mm = 1e300", "pixel_mm"),
            ("sigma_mm = 1.0", "sigma_mm = 1e-300", "[tif] sigma_mm"),
            (
                "diameter_mm = 6.0",
                "diameter_mm = 9000.0",
                "[tif] diameter_mm",
            ),
            (
                "rows = [10, 20]",
                "rows = [10, 9000000000000]",
                "[clear_aperture] rows",
            ),
        ] {
            let e = parse(&GOOD.replace(from, to)).unwrap_err().to_string();
            assert!(e.starts_with(&format!("case.toml: {key}: ")), "{to}: {e}");
            assert!(!e.contains('\n'));
        }
        let e = parse(&format!("{GOOD}[machine]\na_max_mm_per_s2 = 1e300\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("[machine] a_max_mm_per_s2"), "{e}");
        // Ordinary lab values stay accepted.
        assert!(parse(&format!("{GOOD}[machine]\nv_max_mm_per_s = 500\n")).is_ok());
    }

    #[test]
    fn syntax_errors_carry_the_cause_and_place() {
        let e = parse("surface = \"s.dat\nbad").unwrap_err().to_string();
        assert!(
            e.starts_with("case.toml: TOML: syntax error: ")
                && e.ends_with("at line 2, column 4")
                && e.contains("expected"),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }

    /// Dropouts inside the dwell grid: filled from their neighbours for the desired removal (a
    /// dropout in a plane gets the plane's height), left out of the clear aperture; more than
    /// 10 % of the grid invalid is refused with the counts.
    #[test]
    fn dropouts_in_the_dwell_grid_are_filled_and_left_out_of_the_aperture() {
        let c = parse(GOOD).unwrap();
        // A tilted plane, 40 x 50 at 0.5 mm, lowest inside the aperture at (10, 10).
        let z = Array2::from_shape_fn((40, 50), |(i, j)| 2.0 * i as f64 + 3.0 * j as f64);
        let mut valid = Array2::from_elem((40, 50), true);
        for &(i, j) in &[(15, 20), (12, 25), (22, 12), (5, 5)] {
            valid[(i, j)] = false;
        }
        let mut z_bad = z.clone();
        for ((i, j), v) in valid.indexed_iter() {
            if !v {
                z_bad[(i, j)] = 1e6; // garbage where the map has no data
            }
        }
        let map = Surface::with_mask(z_bad, valid.clone(), Some(0.5), Some(0.5)).unwrap();
        let cp = c.problem(&map).unwrap();
        let (o0, o1) = cp.offset;
        let ca_min = 2.0 * 10.0 + 3.0 * 10.0;
        for &(i, j) in &[(15usize, 20usize), (12, 25), (22, 12)] {
            let (gi, gj) = (i - o0, j - o1);
            let d = cp.problem.desired_nm[(gi, gj)];
            // The mean of the 8 neighbours of a plane is the plane.
            assert!((d - (z[(i, j)] - ca_min)).abs() < 1e-9, "{i} {j}: {d}");
            assert!(!cp.problem.aperture[(gi, gj)]);
        }
        assert!(cp
            .problem
            .desired_nm
            .iter()
            .all(|v| v.is_finite() && *v < 1e5));
        // 10 % of the grid and more: refused, naming the counts.
        let mut sparse = Array2::from_elem((40, 50), true);
        for (k, v) in sparse.iter_mut().enumerate() {
            if k % 5 == 0 {
                *v = false;
            }
        }
        let map = Surface::with_mask(z, sparse, Some(0.5), Some(0.5)).unwrap();
        let e = c.problem(&map).unwrap_err().to_string();
        assert!(e.contains("pixels are invalid in the map"), "{e}");
    }

    /// The aperture in mm must say what its pixel range says (reviewer: `x_mm = [500, 600]`
    /// on a 210 mm map was accepted); the public cases' own values pass.
    #[test]
    fn an_aperture_in_mm_that_contradicts_its_pixels_is_refused() {
        // cols [10, 30) at 0.5 mm: first and last centres 5.0 and 14.5 mm.
        assert!(parse(&format!("{GOOD}x_mm = [5.0, 14.5]\ny_mm = [5.0, 9.5]\n")).is_ok());
        assert!(parse(&format!("{GOOD}x_mm = [5.2, 14.3]\n")).is_ok());
        let e = parse(&format!("{GOOD}x_mm = [500.0, 600.0]\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("case.toml") && e.contains("[clear_aperture] x_mm"),
            "{e}"
        );
        assert!(e.contains("[5, 14.5] mm"), "{e}");
        let e = parse(&format!("{GOOD}y_mm = [5.0, 10.0]\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("[clear_aperture] y_mm"), "{e}");
    }

    /// A map that carries its pixel size decides it: a case saying another is refused, a
    /// single-precision copy of the same value is not.
    #[test]
    fn a_case_pixel_size_the_map_contradicts_is_refused() {
        let c = parse(GOOD).unwrap();
        let h = Array2::from_shape_fn((40, 50), |(i, j)| ((i * 7 + j * 3) % 11) as f64);
        let same = Surface::new(h.clone(), Some(0.5f32 as f64), Some(0.5f32 as f64)).unwrap();
        assert!(c.problem(&same).is_ok());
        let other = Surface::new(h, Some(0.36), Some(0.36)).unwrap();
        let e = c.problem(&other).unwrap_err().to_string();
        assert!(
            e.contains("case.toml") && e.contains("pixel_mm = 0.5") && e.contains("0.36"),
            "{e}"
        );
    }
}
