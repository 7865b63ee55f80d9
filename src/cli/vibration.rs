//! `bonnetlab vibration [RECIPE.toml] [--bonnet original|suppression|both] [--json OUT] [--out DIR]`
//! (contract: shared/spec/interfaces.md).
//!
//! The two-degree-of-freedom forced response (DOMAIN.md section 2) for the bonnet named in the
//! recipe's `[process]` (or `--bonnet`), with parameters from the optional `[vibration]` table;
//! every default is documented in `bonnetlab_vibration::params`. Only the `[process]`,
//! `[vibration]`, `[tif]` and `[path]` tables are read, so a recipe holding just those works.
//!
//! `--json OUT` writes one JSON object (`-` for stdout); with `--bonnet both` it writes a JSON
//! array of two such objects, original first. `--out DIR` writes the FRF plots of both bonnets
//! (`frf_x1.svg/.png`, `frf_x2.svg/.png`, the paper's figures 10 and 15 as curves over the spindle
//! band) and `timeseries.csv` (tool-tip displacement for `--duration-s` seconds at 1 kHz,
//! including ring-down after the reversals of the recipe's path log when it has one).

use super::CliError;
use crate::report;
use crate::report::format::fixed;
use crate::report::plot::{LinePlot, Series};
use bonnetlab_process::recipe::RecipeDoc;
use bonnetlab_vibration::modal::{crossed_modes, Crossing, MODES, SPINDLE_BAND_RPM};
use bonnetlab_vibration::params::{Bonnet, LateralAxis, VibrationParams};
use bonnetlab_vibration::response::{
    forced_response, resonance_peaks, spindle_band_frf, spindle_harmonics, FrfPoint, Peak, Response,
};
use bonnetlab_vibration::timeseries::{
    tool_tip_displacement, velocity_change_pulses, AccelPulse, Excitations,
};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Run recipe (TOML); its [process] names the bonnet and spindle speed, [vibration] overrides defaults.
    pub recipe: Option<PathBuf>,
    /// Bonnet to model: original, suppression or both (default: the recipe's [process] bonnet, else original).
    #[arg(long)]
    pub bonnet: Option<String>,
    /// Write the JSON result to this file ("-" for stdout).
    #[arg(long, value_name = "OUT")]
    pub json: Option<PathBuf>,
    /// Directory for the FRF plots and the tool-tip time series.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Length of the time series written to DIR, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub duration_s: f64,
    /// Seed of the broadband force noise in the time series.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// One harmonic of the spindle frequency in the JSON.
#[derive(Debug, Serialize)]
struct HarmonicOut {
    harmonic: usize,
    freq_hz: f64,
    x1_amplitude_mm: f64,
    x2_amplitude_mm: f64,
    normal_amplitude_mm: f64,
    lateral_amplitude_mm: f64,
}

#[derive(Debug, Serialize)]
struct BonnetOut {
    #[serde(flatten)]
    response: Response,
    /// Fraction of a normal holder displacement reaching the contact as an offset change.
    offset_transfer: f64,
    harmonics: Vec<HarmonicOut>,
    peaks: Vec<Peak>,
    modes_crossed: Vec<Crossing>,
    frf: Vec<FrfPoint>,
    params: VibrationParams,
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

fn read_recipe(path: &Path) -> Result<RecipeDoc, CliError> {
    let text = super::read_text_input(path, "a recipe (TOML)")?;
    RecipeDoc::parse(&text, path).map_err(|e| CliError::input(path, recipe_error(e)))
}

/// The recipe error without the file name (CliError::input adds it).
fn recipe_error(e: bonnetlab_process::ProcessError) -> String {
    match e {
        bonnetlab_process::ProcessError::Recipe { key, what, .. } => format!("{key}: {what}"),
        other => other.to_string(),
    }
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let doc = match &args.recipe {
        Some(p) => read_recipe(p)?,
        None => RecipeDoc::default(),
    };
    let name = args
        .recipe
        .clone()
        .unwrap_or_else(|| PathBuf::from("(defaults)"));
    let params = VibrationParams::from_recipe(&doc)
        .map_err(|e| super::vibration_error(&name, doc.vibration.as_ref(), e))?;
    let recipe_bonnet = doc
        .bonnet(&name)
        .map_err(|e| CliError::input(&name, recipe_error(e)))?;
    let choice = args
        .bonnet
        .as_deref()
        .or(recipe_bonnet.as_deref())
        .unwrap_or("original");
    let bonnets: Vec<Bonnet> = if choice.eq_ignore_ascii_case("both") {
        Bonnet::ALL.to_vec()
    } else {
        let b = choice.parse::<Bonnet>().map_err(|e| match args.bonnet {
            Some(_) => CliError::usage(format!("--bonnet: {e}")),
            None => CliError::input(&name, format!("[process] bonnet: {e}")),
        })?;
        vec![b]
    };
    if !(args.duration_s.is_finite() && args.duration_s > 0.0 && args.duration_s <= 3600.0) {
        return Err(CliError::usage("--duration-s must be in (0, 3600]"));
    }

    let outs: Vec<BonnetOut> = bonnets.iter().map(|&b| bonnet_out(&params, b)).collect();

    if let Some(dir) = &args.out {
        // Written before the JSON or summary, so a failure here emits nothing. Everything is
        // computed first, then the files are published as one set
        // (`report::write::Set`): a failure part-way leaves the directory as it was, and two
        // runs into one directory never mix their files.
        let pulses = path_pulses(&doc, args.recipe.as_deref(), &params, args.duration_s)?;
        let mut set = report::write::Set::begin(dir).map_err(werr)?;
        write_plots(&params, &mut set)?;
        write_timeseries(
            &params,
            bonnets[0],
            &mut set,
            args.duration_s,
            pulses,
            args.seed,
        )?;
        set.commit().map_err(werr)?;
    }

    if let Some(json_path) = &args.json {
        let text = if outs.len() == 1 {
            serde_json::to_string_pretty(&outs[0])
        } else {
            serde_json::to_string_pretty(&outs)
        }
        .map_err(|e| CliError::processing(json_path, e))?;
        super::emit(json_path, format!("{text}\n").as_bytes())?;
        if !super::is_stdout(json_path) {
            let mut wrote = vec![json_path.display().to_string()];
            wrote.extend(args.out.iter().map(|d| format!("{}/", d.display())));
            super::println_stdout(&written_line(&wrote, &outs))?;
        }
    } else {
        let mut text = summary(&params, &outs);
        if let Some(dir) = &args.out {
            text += &format!(
                "vibration: wrote {}/ (FRF plots and the tool-tip time series)\n",
                dir.display()
            );
        }
        super::write_stdout(text.as_bytes())?;
    }
    Ok(())
}

/// `vibration: wrote FILES: original offset A mm, suppression offset B mm at N rpm`: the
/// success line when the JSON went to a file.
fn written_line(wrote: &[String], outs: &[BonnetOut]) -> String {
    use crate::report::format::sig;
    let per: Vec<String> = outs
        .iter()
        .map(|o| {
            format!(
                "{} offset amplitude {} mm (transfer {})",
                o.response.bonnet.name(),
                sig(o.response.offset_amplitude_mm, 4),
                sig(o.offset_transfer, 3)
            )
        })
        .collect();
    format!(
        "vibration: wrote {}: {}",
        wrote.join(" and "),
        per.join(", ")
    )
}

fn summary(p: &VibrationParams, outs: &[BonnetOut]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let f = p.natural_freq_hz();
    let _ = writeln!(
        s,
        "principal frame: k1 {:.1} N/mm, k2 {:.1} N/mm, theta {:.2} deg, m {:.2} kg -> f1 {:.2} Hz, f2 {:.2} Hz",
        p.k1_n_per_mm, p.k2_n_per_mm, p.theta_deg, p.mass_kg, f[0], f[1]
    );
    let _ = writeln!(
        s,
        "force: Fn {:.3} N, mu {:.3}; spindle {:.0} rpm = {:.3} Hz",
        p.fn_n,
        p.mu,
        p.spindle_rpm,
        p.excitation_hz()
    );
    for o in outs {
        let r = &o.response;
        let _ = writeln!(
            s,
            "{:<12} zeta ({:.4}, {:.4})  X1 {:.3e} mm @ {:.1} deg  X2 {:.3e} mm @ {:.1} deg  offset {:.3e} mm (transfer {:.3})",
            r.bonnet.name(),
            r.zeta1_effective,
            r.zeta2_effective,
            r.x1_amplitude_mm,
            r.x1_phase_deg,
            r.x2_amplitude_mm,
            r.x2_phase_deg,
            r.offset_amplitude_mm,
            o.offset_transfer
        );
        for pk in &o.peaks {
            let _ = writeln!(
                s,
                "             peak x{} {:.3e} mm at {:.2} Hz ({:.0} rpm)",
                pk.direction,
                pk.amplitude_mm,
                pk.freq_hz,
                pk.freq_hz * 60.0
            );
        }
    }
    let modes: Vec<String> = MODES
        .iter()
        .map(|m| format!("{}:{} Hz", m.order, fixed(m.best_hz(), 2)))
        .collect();
    let _ = writeln!(
        s,
        "robot modes (measured where available): {}",
        modes.join(", ")
    );
    s
}

fn write_plots(p: &VibrationParams, set: &mut report::write::Set) -> Result<(), CliError> {
    let curves: Vec<Vec<FrfPoint>> = Bonnet::ALL
        .iter()
        .map(|&b| spindle_band_frf(p, b))
        .collect();
    for dof in 0..2 {
        let mut plot = LinePlot::new(
            format!(
                "Steady response along x{} (Fn {} N, mu {})",
                dof + 1,
                p.fn_n,
                p.mu
            ),
            "excitation frequency n/60 (Hz)",
            format!("x{} amplitude (mm)", dof + 1),
        );
        for (b, c) in Bonnet::ALL.iter().zip(&curves) {
            let x: Vec<f64> = c.iter().map(|q| q.freq_hz).collect();
            let y: Vec<f64> = c
                .iter()
                .map(|q| {
                    if dof == 0 {
                        q.x1_amplitude_mm
                    } else {
                        q.x2_amplitude_mm
                    }
                })
                .collect();
            plot = plot.series(Series::new(format!("{} bonnet", b.name()), x, y));
        }
        plot = plot.marker(
            p.excitation_hz(),
            format!("spindle {} rpm", fixed(p.spindle_rpm, 0)),
        );
        for m in MODES.iter() {
            plot = plot.marker(m.best_hz(), format!("mode {}", m.order));
        }
        let stem = format!("frf_x{}", dof + 1);
        let svg = plot
            .to_svg()
            .map_err(|e| CliError::processing(set.path(&stem), e))?;
        set.bytes(&format!("{stem}.svg"), svg.as_bytes())
            .map_err(werr)?;
        let png = plot
            .to_png()
            .map_err(|e| CliError::processing(set.path(&stem), e))?;
        set.bytes(&format!("{stem}.png"), &png).map_err(werr)?;
    }
    Ok(())
}

/// Reversal pulses from the first `duration_s` of the recipe's path log, if it names one.
fn path_pulses(
    doc: &RecipeDoc,
    recipe: Option<&Path>,
    p: &VibrationParams,
    duration_s: f64,
) -> Result<Vec<AccelPulse>, CliError> {
    let (Some(recipe), Some(log)) = (recipe, doc.path.as_ref().and_then(|p| p.log.as_deref()))
    else {
        return Ok(Vec::new());
    };
    let file = recipe.parent().unwrap_or(Path::new(".")).join(log);
    let path = bonnetlab_process::read_path_csv(&file).map_err(|e| CliError::input(&file, e))?;
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

fn write_timeseries(
    p: &VibrationParams,
    bonnet: Bonnet,
    set: &mut report::write::Set,
    duration_s: f64,
    pulses: Vec<AccelPulse>,
    seed: u64,
) -> Result<(), CliError> {
    let file = set.path("timeseries.csv");
    let ts = tool_tip_displacement(
        p,
        bonnet,
        duration_s,
        1000.0,
        pulses,
        Excitations::ALL,
        seed,
    )
    .map_err(|e| CliError::processing(&file, e))?;
    let mut buf = Vec::with_capacity(ts.t_s.len() * 80);
    let _ = writeln!(buf, "t_s,x1_mm,x2_mm,normal_mm,lateral_mm,offset_change_mm");
    for k in 0..ts.t_s.len() {
        let _ = writeln!(
            buf,
            "{:.4},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e}",
            ts.t_s[k],
            ts.x1_mm[k],
            ts.x2_mm[k],
            ts.normal_mm[k],
            ts.lateral_mm[k],
            ts.offset_change_mm[k]
        );
    }
    set.bytes("timeseries.csv", &buf).map_err(werr)
}

/// A write failure of the output set, naming the file (exit 2).
fn werr(e: report::write::WriteError) -> CliError {
    super::write_error(e)
}
