//! `vibration`: the two-degree-of-freedom forced response (DOMAIN.md section 2) of one or both
//! bonnets for a recipe's `[process]` and `[vibration]` tables (defaults in
//! `bonnetlab_vibration::params`), its resonance peaks and spindle-band FRF; and, for the
//! output directory, the FRF curves of both bonnets and the tool-tip time series (with the
//! ring-down after the reversals of the recipe's path log when it names one).

use std::path::{Path, PathBuf};

use bonnetlab_process::recipe::RecipeDoc;
use bonnetlab_vibration::modal::{crossed_modes, Crossing, SPINDLE_BAND_RPM};
use bonnetlab_vibration::params::{Bonnet, LateralAxis, VibrationParams};
use bonnetlab_vibration::response::{
    forced_response, resonance_peaks, spindle_band_frf, spindle_harmonics, FrfPoint, Peak, Response,
};
use bonnetlab_vibration::timeseries::{
    tool_tip_displacement, velocity_change_pulses, AccelPulse, Excitations, TimeSeries,
};
use serde::Serialize;

use super::error::vibration_error;
use super::Error;

/// Sampling rate of the tool-tip time series, Hz.
pub const TIMESERIES_HZ: f64 = 1000.0;

/// One harmonic of the spindle frequency in the JSON.
#[derive(Debug, Serialize)]
pub struct HarmonicOut {
    pub harmonic: usize,
    pub freq_hz: f64,
    pub x1_amplitude_mm: f64,
    pub x2_amplitude_mm: f64,
    pub normal_amplitude_mm: f64,
    pub lateral_amplitude_mm: f64,
}

/// One bonnet's response (the JSON object of `bonnetlab vibration`).
#[derive(Debug, Serialize)]
pub struct BonnetOut {
    #[serde(flatten)]
    pub response: Response,
    /// Fraction of a normal holder displacement reaching the contact as an offset change.
    pub offset_transfer: f64,
    pub harmonics: Vec<HarmonicOut>,
    pub peaks: Vec<Peak>,
    pub modes_crossed: Vec<Crossing>,
    pub frf: Vec<FrfPoint>,
    pub params: VibrationParams,
}

/// The response of the bonnets asked for.
pub struct Vibration {
    /// The recipe (empty when none was given).
    pub doc: RecipeDoc,
    /// The recipe file, if one was given.
    pub recipe: Option<PathBuf>,
    pub params: VibrationParams,
    /// The bonnets modelled (original first when both).
    pub bonnets: Vec<Bonnet>,
    /// Their responses, in the order of `bonnets`.
    pub outs: Vec<BonnetOut>,
}

/// What the output directory holds: the spindle-band FRF of both bonnets (in `Bonnet::ALL`
/// order) and the tool-tip time series of the first bonnet modelled.
pub struct Outputs {
    pub frf: Vec<(Bonnet, Vec<FrfPoint>)>,
    pub timeseries: TimeSeries,
}

fn bonnet_out(p: &VibrationParams, bonnet: Bonnet) -> BonnetOut {
    let harmonics = spindle_harmonics(p, bonnet, p.spindle_rpm)
        .iter()
        .enumerate()
        .map(|(i, h)| HarmonicOut {
            harmonic: i + 1,
            freq_hz: h.freq_hz,
            x1_amplitude_mm: h.x[0].norm(),
            x2_amplitude_mm: h.x[1].norm(),
            normal_amplitude_mm: h.tn[1].norm(),
            lateral_amplitude_mm: h.tn[0].norm(),
        })
        .collect();
    BonnetOut {
        response: forced_response(p, bonnet, p.spindle_rpm),
        offset_transfer: p.offset_transfer(bonnet),
        harmonics,
        peaks: resonance_peaks(p, bonnet),
        modes_crossed: crossed_modes(
            SPINDLE_BAND_RPM.0,
            SPINDLE_BAND_RPM.1,
            p.harmonics.len() as u32,
        ),
        frf: spindle_band_frf(p, bonnet),
        params: p.clone(),
    }
}

/// The recipe error without the file name (`Error::input` adds it).
fn recipe_error(e: bonnetlab_process::ProcessError) -> String {
    match e {
        bonnetlab_process::ProcessError::Recipe { key, what, .. } => format!("{key}: {what}"),
        other => other.to_string(),
    }
}

/// The response for a recipe (its file and text; none: every default) and the bonnet asked
/// for (`bonnet`, from the command line: `original`, `suppression` or `both`; otherwise the
/// recipe's `[process]` bonnet, else original). `duration_s` is the time series' length, checked
/// here (0 to 3600 s) so nothing is computed for a bad one.
pub fn response(
    recipe: Option<(&Path, &str)>,
    bonnet: Option<&str>,
    duration_s: f64,
) -> Result<Vibration, Error> {
    let doc = match recipe {
        Some((path, text)) => {
            RecipeDoc::parse(text, path).map_err(|e| Error::input(path, recipe_error(e)))?
        }
        None => RecipeDoc::default(),
    };
    let name = recipe
        .map(|(p, _)| p.to_path_buf())
        .unwrap_or_else(|| PathBuf::from("(defaults)"));
    let params = VibrationParams::from_recipe(&doc)
        .map_err(|e| vibration_error(&name, doc.vibration.as_ref(), e))?;
    let recipe_bonnet = doc
        .bonnet(&name)
        .map_err(|e| Error::input(&name, recipe_error(e)))?;
    let choice = bonnet.or(recipe_bonnet.as_deref()).unwrap_or("original");
    let bonnets: Vec<Bonnet> = if choice.eq_ignore_ascii_case("both") {
        Bonnet::ALL.to_vec()
    } else {
        let b = choice.parse::<Bonnet>().map_err(|e| match bonnet {
            // The command line also takes `both`, which a recipe's [process] bonnet does not.
            Some(b) => Error::usage(format!(
                "--bonnet: unknown bonnet '{}' (expected original, suppression or both)",
                b.trim()
            )),
            None => Error::input(&name, format!("[process] bonnet: {e}")),
        })?;
        vec![b]
    };
    if !(duration_s.is_finite() && duration_s > 0.0 && duration_s <= 3600.0) {
        return Err(Error::usage("--duration-s must be in (0, 3600]"));
    }
    let outs = bonnets.iter().map(|&b| bonnet_out(&params, b)).collect();
    Ok(Vibration {
        doc,
        recipe: recipe.map(|(p, _)| p.to_path_buf()),
        params,
        bonnets,
        outs,
    })
}

impl Vibration {
    /// The FRF curves of both bonnets and `duration_s` of the first bonnet's tool-tip
    /// displacement at [`TIMESERIES_HZ`] (force noise seeded by `seed`), with the reversal
    /// pulses of the recipe's path log. `timeseries_file` names the series in an error.
    pub fn outputs(
        &self,
        duration_s: f64,
        seed: u64,
        timeseries_file: &Path,
    ) -> Result<Outputs, Error> {
        let pulses = self.path_pulses(duration_s)?;
        let frf = Bonnet::ALL
            .iter()
            .map(|&b| (b, spindle_band_frf(&self.params, b)))
            .collect();
        let timeseries = tool_tip_displacement(
            &self.params,
            self.bonnets[0],
            duration_s,
            TIMESERIES_HZ,
            pulses,
            Excitations::ALL,
            seed,
        )
        .map_err(|e| Error::processing(timeseries_file, e))?;
        Ok(Outputs { frf, timeseries })
    }

    /// Reversal pulses from the first `duration_s` of the recipe's path log, if it names one.
    fn path_pulses(&self, duration_s: f64) -> Result<Vec<AccelPulse>, Error> {
        let p = &self.params;
        let (Some(recipe), Some(log)) = (
            self.recipe.as_deref(),
            self.doc.path.as_ref().and_then(|p| p.log.as_deref()),
        ) else {
            return Ok(Vec::new());
        };
        let file = recipe.parent().unwrap_or(Path::new(".")).join(log);
        let path = bonnetlab_process::recipe::read_named_path_log(&file, recipe)
            .map_err(|e| Error::input(&file, e))?;
        let n = path
            .t_s
            .iter()
            .take_while(|&&t| t - path.t_s[0] <= duration_s)
            .count();
        let t0 = path.t_s.first().copied().unwrap_or(0.0);
        let t: Vec<f64> = path.t_s[..n].iter().map(|t| t - t0).collect();
        let pos = match p.lateral_axis {
            LateralAxis::X => &path.x_mm[..n],
            LateralAxis::Y => &path.y_mm[..n],
        };
        Ok(velocity_change_pulses(&t, pos, p.accel_max_mm_per_s2))
    }
}
