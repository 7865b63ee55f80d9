//! `bonnetlab demo`: the bundled two-bonnet example.
//!
//! - `bonnetlab demo --generate-samples samples/` writes the sample maps (MetroPro `.dat`,
//!   two repeat measurements before and after for each bonnet; `crate::report::samples`), the
//!   recipe run of each bonnet (`recipe.toml`, `path.csv`, `spot.dat`, `before.dat`,
//!   `after.dat`; `crate::pipeline::recipe_samples`) and their README, from seeds;
//! - `bonnetlab demo --out reports/demo` runs `compare` on the repeat maps (default `samples/`,
//!   pitch 3 mm, piston + tilt removed) and writes the report, showing its progress; the report
//!   also carries the vibration coupling's predicted MSF per bonnet on a run matching the sample
//!   ([`predicted_msf`]: the paper's bonnet and process parameters, 3 mm raster, sample grid);
//!   then it runs `compare --run original=samples/original/recipe.toml --run
//!   suppression=samples/suppression/recipe.toml --out reports/demo/bonnets` (the bonnet
//!   comparison: measured vs predicted ripple, calibrated effects, inferred vibration forcing,
//!   attribution of the difference).

use crate::report::format::fixed;
use std::path::{Path, PathBuf};

use super::compare::compare_with_progress;
use super::CliError;
use crate::pipeline::recipe_samples::{self, RECIPE_SEED};
use crate::report::compare_report::write_report_with;
use crate::report::comparison::{RunSpec, Settings};
use crate::report::msf_prediction::{PredictedMsf, PredictionRun};
use crate::report::samples::{
    generate, paper_bonnets, SAMPLE_N, SAMPLE_PITCH_MM, SAMPLE_PIXEL_MM, SAMPLE_SEED,
};
use bonnetlab_process::path::RasterSpec;
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::bonnet::BonnetTifParams;
use bonnetlab_process::Grid;
use bonnetlab_vibration::coupling::{predict_both, CouplingInput, CouplingOptions};
use bonnetlab_vibration::params::VibrationParams;

/// A stage message of the demo, on stderr only when stderr is a terminal: redirected or
/// captured, stderr holds nothing but a failure's one line (the result is the stdout line).
macro_rules! stage {
    ($($arg:tt)*) => {
        if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            eprintln!($($arg)*);
        }
    };
}

/// What `demo --help` says.
pub const ABOUT: &str = "Run the bundled two-bonnet example: compare the sample maps \
(samples/original, samples/suppression; repeat measurements before and after) and write \
OUT/report.html, report.json and PSD CSVs (default OUT reports/demo), then compare the two \
sample recipe runs (samples/*/recipe.toml: maps, measured spot, path log, vibration model) \
and write the bonnet comparison (measured vs predicted ripple, calibrated effects, inferred \
vibration forcing, what explains the difference) to OUT/bonnets/. With --generate-samples DIR \
it writes the samples instead (and the report too when --out is given). Never changes \
samples/ unless told to.";

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Write the sample maps and README into this directory.
    #[arg(long, value_name = "DIR")]
    pub generate_samples: Option<PathBuf>,
    /// Write the reports into this directory: the map comparison in DIR, the bonnet (recipe)
    /// comparison in DIR/bonnets (default `reports/demo` when neither this nor
    /// --generate-samples is given).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Where the samples are read from for the report; when the folder does not exist the
    /// samples are generated into OUT/samples first.
    #[arg(long, value_name = "DIR", default_value = "samples")]
    pub samples: PathBuf,
    /// Seed of the generated sample maps (the recipe runs have their own fixed seed, 16).
    #[arg(long, default_value_t = SAMPLE_SEED)]
    pub seed: u64,
    /// Repeat measurements per map in the generated sample (1 to 10000).
    #[arg(long, default_value_t = 2, value_parser = super::num::repeats)]
    pub repeats: usize,
}

/// Repeats found on disk for one bonnet and state (`before_1.dat`, `before_2.dat`, ...).
fn repeats_on_disk(dir: &Path, bonnet: &str, state: &str) -> Vec<PathBuf> {
    (1..100)
        .map(|k| dir.join(bonnet).join(format!("{state}_{k}.dat")))
        .take_while(|p| p.is_file())
        .collect()
}

/// The runs of the bundled sample: one per bonnet, original first (the reference).
pub fn sample_runs(dir: &Path) -> Result<Vec<RunSpec>, CliError> {
    let mut runs = Vec::new();
    for b in paper_bonnets() {
        let before = repeats_on_disk(dir, b.name, "before");
        let after = repeats_on_disk(dir, b.name, "after");
        if before.is_empty() || after.is_empty() {
            return Err(CliError::input(
                dir.join(b.name),
                "sample maps missing (before_1.dat / after_1.dat); create them with \
                 `bonnetlab demo --generate-samples DIR`",
            ));
        }
        runs.push(RunSpec {
            name: b.name.to_string(),
            before,
            after,
        });
    }
    Ok(runs)
}

/// Peak removal rate of the paper-bonnet TIF in the prediction, nm/s (scales every band RMS
/// linearly; chosen so a 100 mm raster removes of the order of a micrometre).
pub const PREDICTION_TIF_PEAK_NM_PER_S: f64 = 10.0;
/// Feed of the prediction's raster, mm/s (the paper's).
pub const PREDICTION_FEED_MM_PER_S: f64 = 1.6;

/// The vibration coupling for both bonnets on a run matching the sample: the 100 x 100 mm part
/// on the sample's grid, the paper's bonnet TIF (R 20 mm, offset 0.6 mm, precession 20 deg,
/// 1000 rpm), a 3 mm bidirectional raster and the vibration crate's defaults at 0.25 MPa.
pub fn predicted_msf() -> Result<Vec<PredictedMsf>, CliError> {
    let perr = |e: &dyn std::fmt::Display| CliError {
        code: 1,
        message: format!("demo: predicted MSF: {e}"),
    };
    let (n, d) = (SAMPLE_N, SAMPLE_PIXEL_MM);
    let part_mm = n as f64 * d;
    let grid = Grid::new(n, n, d, d, 0.5 * d, 0.5 * d).map_err(|e| perr(&e))?;
    let tif_params = BonnetTifParams::paper(PREDICTION_TIF_PEAK_NM_PER_S);
    let tool = ToolModel::from_source(&TifSource::Bonnet(tif_params.clone()), None, d, d)
        .map_err(|e| perr(&e))?;
    let path = RasterSpec::over_rect(
        (0.0, part_mm),
        (0.0, part_mm),
        SAMPLE_PITCH_MM,
        PREDICTION_FEED_MM_PER_S,
    )
    .generate()
    .map_err(|e| perr(&e))?;
    let inner_pressure_mpa = 0.25;
    let params = VibrationParams::from_parts(
        None,
        Some(tif_params.spindle_rpm),
        Some(tif_params.offset_mm),
        Some(inner_pressure_mpa),
        None,
    )
    .map_err(|e| perr(&e))?;
    let input = CouplingInput {
        grid,
        valid: None,
        tool: &tool,
        path: &path,
        params: &params,
        pitch_mm: Some(SAMPLE_PITCH_MM),
    };
    let opts = CouplingOptions::default();
    let preds = predict_both(&input, &opts).map_err(|e| perr(&e))?;
    let run = PredictionRun {
        part_mm: (part_mm, part_mm),
        rows: n,
        cols: n,
        dx_mm: d,
        dy_mm: d,
        tif: "paper bonnet (R 20 mm, Hertz pressure, four-step precession)".into(),
        tif_peak_rate_nm_per_s: PREDICTION_TIF_PEAK_NM_PER_S,
        pitch_mm: SAMPLE_PITCH_MM,
        feed_mm_per_s: PREDICTION_FEED_MM_PER_S,
        spindle_rpm: tif_params.spindle_rpm,
        offset_mm: tif_params.offset_mm,
        precession_deg: tif_params.precession_deg,
        inner_pressure_mpa,
        sample_hz: opts.sample_hz,
        seed: opts.seed,
    };
    Ok(preds
        .iter()
        .map(|p| PredictedMsf::new(run.clone(), p))
        .collect())
}

fn readme(seed: u64, repeats: usize) -> String {
    let mut s = String::new();
    s.push_str("# Two-bonnet sample\n\n");
    s.push_str(
        "Synthetic before/after height maps of two whole-surface polishing runs of a 100 mm x 100 mm SiC \
         part, one with the original bonnet and one with the vibration-suppression bonnet. They are \
         generated by bonnetlab itself (`src/report/samples.rs`), so they can be rebuilt bit for bit:\n\n",
    );
    s.push_str(&format!(
        "    cargo run --release -- demo --generate-samples samples --seed {seed} --repeats {repeats}\n\n"
    ));
    s.push_str("Then write the demo report from them (what the README's first command does):\n\n");
    s.push_str("    cargo run --release -- demo\n\n");
    s.push_str(
        "(`demo --out DIR` writes it elsewhere; `demo` never changes `samples/`). Its report is the\n\
         report of\n\n",
    );
    s.push_str(
        "    bonnetlab compare --pitch-mm 3 --out reports/demo \\\n      \
         --run original=samples/original/before_1.dat+samples/original/before_2.dat,samples/original/after_1.dat+samples/original/after_2.dat \\\n      \
         --run suppression=samples/suppression/before_1.dat+samples/suppression/before_2.dat,samples/suppression/after_1.dat+samples/suppression/after_2.dat\n\n",
    );
    s.push_str(
        "with one more section: the MSF each bonnet is predicted to leave (the vibration coupling on a\n\
         run matching the sample), which `compare` on maps alone cannot give. The `runs` of both\n\
         `report.json` files are identical (`tests/docs_examples.rs`).\n\n",
    );
    s.push_str("## What is in the maps\n\n");
    s.push_str(&format!(
        "- grid {n} x {n}, pixel {d} mm (MetroPro `.dat`, heights in nm after conversion); X along columns \
         (scan), Y along rows (feed);\n",
        n = SAMPLE_N,
        d = SAMPLE_PIXEL_MM
    ));
    s.push_str(
        "- figure error (periods 35-150 mm), mid-spatial-frequency error (4-30 mm) and fine texture \
         (0.8-4 mm) from seeded random sinusoids, scaled so the RMS after piston + tilt matches the \
         paper's table (DOMAIN.md section 4) before measurement noise:\n\n",
    );
    s.push_str("| bonnet | RMS before (nm) | RMS after (nm) | raster ripple amplitude at 3 mm (nm) |\n|---|---|---|---|\n");
    for b in paper_bonnets() {
        s.push_str(&format!(
            "| {} | {} | {} | {} |\n",
            b.name, b.rms_before_nm, b.rms_after_nm, b.ripple_amplitude_nm
        ));
    }
    s.push_str(&format!(
        "\n- polishing keeps part of the figure and MSF error, adds vibration-driven MSF error (more for \
         the original bonnet) and leaves the raster ripple along Y at the {p} mm grating spacing \
         (second harmonic 30 %), weaker for the suppression bonnet;\n",
        p = SAMPLE_PITCH_MM
    ));
    s.push_str(&format!(
        "- each map is measured {repeats} times (`before_1.dat`, `before_2.dat`, ...) with 1.5 nm white \
         noise, a random set-up piston and tilt and about 0.3 % dropout pixels, so the report can show \
         the repeat spread and whether the difference between the bonnets is beyond the noise.\n\n"
    ));
    s.push_str(
        "PV is not set: it follows from the random fields (PV / RMS about 5, as in the paper).\n",
    );
    s.push_str(&recipe_readme());
    s
}

/// The README part on the recipe runs.
fn recipe_readme() -> String {
    use recipe_samples as rs;
    let mut s = String::new();
    s.push_str("\n## The recipe runs (`original/recipe.toml`, `suppression/recipe.toml`)\n\n");
    s.push_str(
        "One run per bonnet as a lab gives it: `recipe.toml`, `path.csv` (the robot's log, \
         `t_s,x_mm,y_mm` at 50 Hz), `spot.dat` (the measured spot), `before.dat` and `after.dat` \
         (MetroPro). The formats are in docs/formats.md. `bonnetlab demo` compares them with\n\n",
    );
    s.push_str(
        "    bonnetlab compare --run original=samples/original/recipe.toml \\\n      \
         --run suppression=samples/suppression/recipe.toml --out reports/demo/bonnets\n\n",
    );
    s.push_str(&format!(
        "They are made by the project's synthetic-run generator (`bonnetlab_calibrate::synth`, \
         seed {seed}) with its deposition replaced by the exact time-domain deposition of the \
         instantaneous TIF under each bonnet's vibration model (`src/pipeline/recipe_samples.rs`):\n\n\
         - part: {n} x {n} pixels of {d} mm, a power-law textured surface (one-sided 1-D PSD ~ \
         f^-{ex}, {trms} nm RMS) down to half the pixel, the same part for both bonnets;\n\
         - tool: Gaussian spot, sigma {sig} mm, truncated at {dia} mm, {peak} nm/s peak; the \
         measured spot is that TIF dwelled {dwell} s, with 0.3 nm noise;\n\
         - path: raster along x, {p} mm pitch, feed {v0} to {v1} mm/s realising a dwell map \
         (more dwell where the part is high), acceleration-limited;\n\
         - process where the vibration matters: spindle {rpm} rpm (second harmonic near the \
         robot's resonance), normal-force fluctuation {fnn} N at the spindle harmonics and \
         {nf} N broadband, robot damping ratio {z}; the suppression run adds the \
         suppression element (the vibration model's suppression bonnet); at the paper's 1.6 mm/s \
         and 1000 rpm the spindle imprint is filtered out by the spot and nothing could be \
         inferred;\n\
         - measurement: 0.3 nm white noise shared, plus {own} nm of each run's own, a set-up \
         piston and tilt of the after map, about 0.2 % dropout pixels and one small dropout \
         disc.\n\n",
        seed = RECIPE_SEED,
        n = rs::RECIPE_N,
        d = rs::RECIPE_PIXEL_MM,
        ex = rs::RECIPE_TEXTURE_EXPONENT,
        trms = rs::RECIPE_TEXTURE_RMS_NM,
        sig = rs::recipe_tif().sigma_mm,
        dia = rs::recipe_tif().diameter_mm,
        peak = rs::recipe_tif().peak_rate_nm_per_s,
        dwell = rs::RECIPE_SPOT_DWELL_S,
        p = rs::RECIPE_PITCH_MM,
        v0 = rs::RECIPE_FEED_MM_PER_S.0,
        v1 = rs::RECIPE_FEED_MM_PER_S.1,
        rpm = rs::RECIPE_SPINDLE_RPM,
        fnn = rs::RECIPE_FN_N,
        nf = rs::RECIPE_NOISE_FORCE_N,
        z = rs::RECIPE_ZETA,
        own = rs::RECIPE_OWN_NOISE_NM,
    ));
    s.push_str("Built-in effects the report should find (the calibration is not told):\n\n");
    s.push_str("| run | effect | truth |\n|---|---|---|\n");
    for spec in rs::recipe_runs(RECIPE_SEED) {
        for e in &spec.effects {
            s.push_str(&format!("| {} | {} |\n", spec.name, rs::effect_words(e)));
        }
    }
    s.push_str(
        "\nNothing else differs between the runs, so the difference in ripple between the \
         bonnets is the vibration's.\n",
    );
    s
}

fn generate_samples(dir: &Path, seed: u64, repeats: usize) -> Result<(), CliError> {
    if repeats == 0 {
        return Err(CliError::usage("--repeats must be at least 1"));
    }
    stage!(
        "bonnetlab demo: generating the two-bonnet sample (seed {seed}) into {}",
        dir.display()
    );
    // Every file is staged and published together: a failed or concurrent generation never
    // leaves a mix of two sample sets.
    let werr = |e: crate::report::write::WriteError| CliError {
        code: 2,
        message: e.to_string(),
    };
    let mut set = crate::report::write::Set::begin(dir).map_err(werr)?;
    let maps = generate(seed, repeats);
    for m in &maps {
        let name = m.relative_path();
        set.surface(&name, &m.surface, bonnetlab_io::MapFormat::MetroProDat)
            .map_err(werr)?;
    }
    for spec in recipe_samples::recipe_runs(RECIPE_SEED) {
        stage!(
            "bonnetlab demo: generating the {} recipe run (exact deposition under the vibration \
             model, seed {})",
            spec.name,
            spec.seed
        );
        let run = recipe_samples::generate_run(&spec).map_err(|e| CliError {
            code: 1,
            message: format!("demo: {}: {e}", spec.name),
        })?;
        let files = recipe_samples::run_files(&spec, &run).map_err(|e| CliError {
            code: 2,
            message: format!("{}: {e}", dir.join(spec.name).display()),
        })?;
        for (name, bytes) in files {
            set.bytes(&format!("{}/{name}", spec.name), &bytes)
                .map_err(werr)?;
        }
    }
    set.bytes("README.md", readme(seed, repeats).as_bytes())
        .map_err(werr)?;
    set.commit().map_err(werr)?;
    for m in &maps {
        stage!("  wrote {}", dir.join(m.relative_path()).display());
    }
    for spec in recipe_samples::recipe_runs(RECIPE_SEED) {
        stage!(
            "  wrote {}",
            dir.join(spec.name).join("recipe.toml").display()
        );
    }
    Ok(())
}

pub fn run(args: &Args) -> Result<(), CliError> {
    if let Some(dir) = &args.generate_samples {
        generate_samples(dir, args.seed, args.repeats)?;
    }
    let default_out = PathBuf::from("reports/demo");
    let out = match (&args.out, &args.generate_samples) {
        (Some(o), _) => o,
        (None, None) => &default_out,
        (None, Some(dir)) => {
            println!(
                "demo: wrote the sample maps (seed {}, {} repeats) to {}",
                args.seed,
                args.repeats,
                dir.display()
            );
            return Ok(());
        }
    };
    let generated = out.join("samples");
    let samples = match &args.generate_samples {
        Some(dir) => dir,
        None if args.samples.is_dir() => &args.samples,
        None => {
            stage!(
                "bonnetlab demo: no {} folder here; generating the samples into {}",
                args.samples.display(),
                generated.display()
            );
            generate_samples(&generated, args.seed, args.repeats)?;
            &generated
        }
    };
    let runs = sample_runs(samples)?;
    let n: usize = runs.iter().map(|r| r.before.len() + r.after.len()).sum();
    stage!(
        "bonnetlab demo: comparing {} runs ({n} maps) from {} at a {} mm grating spacing",
        runs.len(),
        samples.display(),
        SAMPLE_PITCH_MM
    );
    let settings = Settings {
        pitch_mm: Some(SAMPLE_PITCH_MM),
        ..Settings::default()
    };
    let c = compare_with_progress(&runs, &settings, false)?;
    stage!(
        "bonnetlab demo: predicting the MSF per bonnet (vibration coupling, {} mm raster)",
        SAMPLE_PITCH_MM
    );
    let predicted = predicted_msf()?;
    for p in &predicted {
        let shares: Vec<String> = p
            .mechanisms
            .iter()
            .map(|m| format!("{} {} %", m.name, fixed(100.0 * m.share, 1)))
            .collect();
        stage!(
            "  {}: predicted Y ripple sigma1 {} nm, MSF band RMS {:.4} nm ({})",
            p.bonnet,
            p.ripple_sigma1_nm
                .map(|v| fixed(v, 4))
                .unwrap_or_else(|| "n/a".into()),
            p.removal_msf_band_rms_nm,
            shares.join(", ")
        );
    }
    stage!("bonnetlab demo: rendering the report (maps, PSD overlays, tables)");
    let written = write_report_with(out, &c, Some(&predicted)).map_err(|e| CliError {
        code: 2,
        message: e.to_string(),
    })?;
    for r in &c.runs {
        let imp = r
            .improvement_cr_rms
            .map(|v| format!(", improvement CR(RMS) {} %", fixed(100.0 * v, 2)))
            .unwrap_or_default();
        stage!(
            "  {}: RMS {:.3} -> {:.3} nm, CR(RMS) {:.2} %, CR(PV) {:.2} %{imp}",
            r.name,
            r.rms_before_nm,
            r.rms_after_nm,
            100.0 * r.cr_rms,
            100.0 * r.cr_pv
        );
    }
    for p in &written {
        stage!("  wrote {}", p.display());
    }
    let b = bonnet_comparison(samples, &out.join("bonnets"))?;
    let crs: Vec<String> = c
        .runs
        .iter()
        .map(|r| format!("{} CR(RMS) {} %", r.name, fixed(100.0 * r.cr_rms, 1)))
        .collect();
    println!(
        "demo: wrote {} ({} runs, {n} maps from {}; {}) and {} ({b})",
        out.join("report.html").display(),
        c.runs.len(),
        samples.display(),
        crs.join(", "),
        out.join("bonnets").join("report.html").display(),
    );
    Ok(())
}

/// The `compare` command the demo's bonnet comparison is (docs/cli.md, samples/README.md).
pub fn bonnet_compare_args(samples: &Path, out: &Path) -> super::compare::Args {
    let run = |name: &str| {
        format!(
            "{name}={}",
            samples.join(name).join("recipe.toml").display()
        )
    };
    super::compare::Args {
        runs: vec![run("original"), run("suppression")],
        pitch_mm: None,
        remove: "piston,tilt".into(),
        window: "hann".into(),
        pixel_mm: None,
        pixel_mm_y: None,
        out: out.to_path_buf(),
    }
}

/// Runs `compare --run original=SAMPLES/original/recipe.toml --run
/// suppression=SAMPLES/suppression/recipe.toml --out OUT` (what that command does, without its
/// summary line) and returns a short summary of the difference for the demo's line.
fn bonnet_comparison(samples: &Path, out: &Path) -> Result<String, CliError> {
    for b in ["original", "suppression"] {
        let r = samples.join(b).join("recipe.toml");
        if !r.is_file() {
            return Err(CliError::input(
                &r,
                "sample recipe missing; create the samples with \
                 `bonnetlab demo --generate-samples DIR`",
            ));
        }
    }
    let args = bonnet_compare_args(samples, out);
    stage!(
        "bonnetlab demo: comparing the bonnets' recipe runs ({} and {}): calibration, vibration \
         forcing, attribution",
        args.runs[0],
        args.runs[1]
    );
    let (runs, settings) = super::compare::parse(&args)?;
    let recipes = super::compare::recipe_runs(&args)?;
    let c = compare_with_progress(&runs, &settings, false)?;
    let opts = crate::pipeline::bonnets::Options {
        remove: settings.remove.clone(),
        ..Default::default()
    };
    let b = crate::pipeline::bonnets::compare_runs(&recipes, &opts).map_err(|e| CliError {
        code: e.exit_code,
        message: e.message,
    })?;
    let written = crate::report::compare_report::write_report_full(out, &c, None, Some(&b))
        .map_err(|e| CliError {
            code: 2,
            message: e.to_string(),
        })?;
    for p in &written {
        stage!("  wrote {}", p.display());
    }
    Ok(match b.difference.first() {
        Some(d) => {
            let top = d
                .causes
                .first()
                .map(|c| {
                    format!(
                        ", {} {} % of it",
                        c.cause,
                        fixed(100.0 * c.share_of_sigma1_difference, 0)
                    )
                })
                .unwrap_or_default();
            format!(
                "sigma1 difference {} nm{top}",
                fixed(d.sigma1_difference_nm, 3)
            )
        }
        None => "no difference computed".into(),
    })
}
