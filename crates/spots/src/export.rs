//! A fitted bonnet model as a recipe's `[tif] model` (spec/interfaces.md) and as
//! `bonnetlab_process` parameters.
//!
//! The recipe's bonnet model fixes the absolute rate by `peak_rate_nm_per_s`, so the export is
//! the fitted model evaluated at one set of settings (the sweep's baseline unless given):
//! geometry (radius), pressure profile and the predicted peak rate there. The physical
//! parameters behind it (Preston coefficient, effective modulus) are written in a `[spots_fit]`
//! table beside it, which recipe readers ignore when the `[tif]` table is pasted into a recipe.

use bonnetlab_process::tif::{BonnetTifParams, PressureProfile, RateScale};

use crate::error::SpotsError;
use crate::model::{BonnetModel, Factors};
use crate::sweep::BonnetFit;

/// The process crate's pressure profile equal to the model's exponent, if there is one.
pub fn pressure_profile(model: &BonnetModel) -> Option<PressureProfile> {
    let g = model.pressure_exponent;
    if (g - 0.5).abs() < 1e-12 {
        Some(PressureProfile::Hertz)
    } else if (g - 1.0).abs() < 1e-12 {
        Some(PressureProfile::Parabolic)
    } else {
        None
    }
}

/// `bonnetlab_process` bonnet-TIF parameters reproducing the model at `factors` (four-step).
pub fn process_params(
    model: &BonnetModel,
    factors: &Factors,
) -> Result<BonnetTifParams, SpotsError> {
    let pressure = pressure_profile(model).ok_or_else(|| {
        SpotsError::Model(format!(
            "pressure exponent {} has no bonnetlab_process profile (0.5 hertz, 1 parabolic)",
            model.pressure_exponent
        ))
    })?;
    let m = model.metrics(factors)?;
    Ok(BonnetTifParams {
        radius_mm: model.radius_mm,
        offset_mm: factors.offset_mm,
        precession_deg: factors.precession_deg,
        spindle_rpm: factors.spindle_rpm,
        pressure,
        scale: RateScale::PeakNmPerS(m.peak_rate_nm_per_s),
        precession_steps: 4,
    })
}

fn name(p: PressureProfile) -> &'static str {
    match p {
        PressureProfile::Hertz => "hertz",
        PressureProfile::Parabolic => "parabolic",
        PressureProfile::Uniform => "uniform",
    }
}

/// The TOML text of a fitted bonnet model; `None` when the bonnet has no fit.
pub fn model_toml(fit: &BonnetFit) -> Result<String, SpotsError> {
    let f = fit
        .fit
        .as_ref()
        .ok_or_else(|| SpotsError::Fit(format!("bonnet '{}' has no fitted model", fit.bonnet)))?;
    let b = &fit.baseline;
    let p = process_params(&f.model, b)?;
    let peak = match p.scale {
        RateScale::PeakNmPerS(v) => v,
        RateScale::VolumeNmMm2PerS(v) => v,
    };
    let list = |v: &[String]| {
        v.iter()
            .map(|s| format!("{s:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    Ok(format!(
        "# Bonnet TIF model fitted by `bonnetlab spots` to {n} spot(s) of bonnet \"{bonnet}\".\n\
         # Paste the [tif] table into a run recipe (spec/interfaces.md). The peak rate is the fitted\n\
         # model's prediction at these settings (inner pressure {pin} MPa); at other settings use\n\
         # the physical parameters in the spots_fit table (rate = k p |v|, bonnetlab_spots::model).\n\
         [tif]\n\
         model = {{ kind = \"bonnet\", radius_mm = {r}, offset_mm = {h}, precession_deg = {t}, \
         spindle_rpm = {n_rpm}, pressure = \"{pr}\", peak_rate_nm_per_s = {peak} }}\n\
         \n\
         [spots_fit]\n\
         bonnet = \"{bonnet}\"\n\
         radius_mm = {r}\n\
         preston_nm_per_mpa_mm = {k}\n\
         preston_m2_per_n = {k_si:e}\n\
         modulus_mpa = {e}\n\
         pressure_exponent = {g}\n\
         inner_pressure_mpa = {pin}\n\
         fitted = [{fitted}]\n\
         held = [{held}]\n\
         rel_std_err = [{se}]\n\
         rms_log_residual = {res}\n",
        n = f.n_spots,
        bonnet = fit.bonnet,
        pin = b.inner_pressure_mpa,
        r = f.model.radius_mm,
        h = b.offset_mm,
        t = b.precession_deg,
        n_rpm = b.spindle_rpm,
        pr = name(p.pressure),
        k = f.model.preston_nm_per_mpa_mm,
        k_si = f.model.preston_nm_per_mpa_mm * 1e-12,
        e = f.model.modulus_mpa,
        g = f.model.pressure_exponent,
        fitted = list(&f.fitted),
        held = list(&f.held),
        se = f.rel_std_err.iter().map(|v| format!("{v}")).collect::<Vec<_>>().join(", "),
        res = f.rms_log_residual,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_process::tif::bonnet::BonnetTif;
    use bonnetlab_process::RateField;

    #[test]
    fn the_process_crate_bonnet_tif_reproduces_the_model() {
        // Two independent implementations of the same geometry must agree point by point.
        for (g, f) in [
            (1.0, Factors::PAPER_BASELINE),
            (
                0.5,
                Factors {
                    precession_deg: 12.0,
                    offset_mm: 0.4,
                    ..Factors::PAPER_BASELINE
                },
            ),
        ] {
            let m = BonnetModel {
                pressure_exponent: g,
                ..BonnetModel::new(22.0, 0.04, 1.0)
            };
            let p = process_params(&m, &f).unwrap();
            let t = BonnetTif::new(&p).unwrap();
            let peak = m.metrics(&f).unwrap().peak_rate_nm_per_s;
            for k in 0..200 {
                let (x, y) = (-5.0 + 0.05 * k as f64, 2.5 - 0.021 * k as f64);
                let ours = m.rate_nm_per_s(&f, x, y).unwrap();
                let theirs = t.rate_at_mm(x, y);
                // The process crate scales to its grid maximum: allow its 1e-3 grid error.
                assert!(
                    (ours - theirs).abs() < 2e-3 * peak,
                    "({x}, {y}): {ours} vs {theirs}"
                );
            }
        }
        let odd = BonnetModel {
            pressure_exponent: 1.5,
            ..BonnetModel::new(20.0, 0.04, 1.0)
        };
        assert!(process_params(&odd, &Factors::PAPER_BASELINE).is_err());
    }
}
