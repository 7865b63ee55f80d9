//! `bonnetlab demo`: the bundled two-bonnet example.
//!
//! - `bonnetlab demo --generate-samples samples/` writes the sample maps (MetroPro `.dat`,
//!   two repeat measurements before and after for each bonnet; `crate::report::samples`), the
//!   recipe run of each bonnet (`recipe.toml`, `path.csv`, `spot.dat`, `before.dat`,
//!   `after.dat`; `crate::pipeline::recipe_samples`) and their README, from seeds;
//! - `bonnetlab demo --out reports/demo` runs `compare` on the repeat maps (default `samples/`,
//!   pitch 3 mm, piston + tilt removed) and writes the report, showing its progress; the report
//!   also carries the vibration coupling's predicted MSF per bonnet on a run matching the sample
//!   (`crate::pipeline::msf_prediction::predicted_msf`: the paper's bonnet and process parameters, 3 mm raster, sample grid);
//!   then it runs `compare --run original=samples/original/recipe.toml --run
//!   suppression=samples/suppression/recipe.toml --out reports/demo/bonnets` (the bonnet
//!   comparison: measured vs predicted ripple, calibrated effects, inferred vibration forcing,
//!   attribution of the difference).

use std::path::{Path, PathBuf};

use super::compare::compare_with_progress;
use super::CliError;
use crate::pipeline::bonnets;
use crate::pipeline::demo::{generate_samples as generate, sample_recipes, sample_runs};
use crate::pipeline::msf_prediction::predicted_msf;
use crate::pipeline::samples::{SAMPLE_PITCH_MM, SAMPLE_SEED};
use crate::pipeline::Progress;
use crate::report::compare_report::write_report_with;
use crate::report::comparison::Settings;
use crate::report::format::fixed;

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
    #[arg(long, allow_negative_numbers = true, default_value_t = 2, value_parser = super::num::repeats)]
    pub repeats: usize,
}

/// The demo's stages on a terminal's stderr ([`stage!`]).
struct Stages;

impl Progress for Stages {
    fn message(&self, msg: &str) {
        stage!("bonnetlab demo: {msg}");
    }
    fn inc(&self) {}
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
    let mut set = crate::report::write::Set::begin(dir, "demo-samples").map_err(werr)?;
    let samples = generate(dir, seed, repeats, &Stages)?;
    for m in &samples.maps {
        let name = m.relative_path();
        set.surface(&name, &m.surface, bonnetlab_io::MapFormat::MetroProDat)
            .map_err(werr)?;
    }
    for (run, files) in &samples.runs {
        for (name, bytes) in files {
            set.bytes(&format!("{run}/{name}"), bytes).map_err(werr)?;
        }
    }
    set.bytes(
        "README.md",
        crate::report::demo::readme(seed, repeats).as_bytes(),
    )
    .map_err(werr)?;
    set.commit().map_err(werr)?;
    for m in &samples.maps {
        stage!("  wrote {}", dir.join(m.relative_path()).display());
    }
    for (run, _) in &samples.runs {
        stage!("  wrote {}", dir.join(run).join("recipe.toml").display());
    }
    Ok(())
}

/// Checks, before any work, that `dir` can be an output directory: absent (its nearest
/// existing ancestor a directory) or a directory. The demo writes several sets one after
/// another (samples, the maps' report, the bonnets' report); a destination that cannot take
/// them is refused before the first is published.
fn usable_dir(dir: &Path) -> Result<(), CliError> {
    let not_dir = |p: &Path| {
        CliError::input(
            dir,
            format!("cannot write: {} is not a directory", p.display()),
        )
    };
    for a in dir.ancestors() {
        if a.as_os_str().is_empty() {
            break;
        }
        if let Ok(m) = std::fs::metadata(a) {
            return if m.is_dir() { Ok(()) } else { Err(not_dir(a)) };
        }
    }
    Ok(())
}

pub fn run(args: &Args) -> Result<(), CliError> {
    if let Some(o) = &args.out {
        usable_dir(o)?;
        usable_dir(&o.join("bonnets"))?;
    } else if args.generate_samples.is_none() {
        usable_dir(Path::new("reports/demo"))?;
        usable_dir(Path::new("reports/demo/bonnets"))?;
    }
    if let Some(dir) = &args.generate_samples {
        usable_dir(dir)?;
        generate_samples(dir, args.seed, args.repeats)?;
    }
    let default_out = PathBuf::from("reports/demo");
    let out = match (&args.out, &args.generate_samples) {
        (Some(o), _) => o,
        (None, None) => &default_out,
        (None, Some(dir)) => {
            return super::println_stdout(&format!(
                "demo: wrote the sample maps (seed {}, {} repeats) to {}",
                args.seed,
                args.repeats,
                dir.display()
            ));
        }
    };
    let generated = out.join("samples");
    let samples = match &args.generate_samples {
        Some(dir) => dir,
        None if args.samples.is_dir() => &args.samples,
        None if args.samples.exists() => {
            return Err(CliError::input(
                &args.samples,
                "--samples: not a directory (the folder of sample runs, samples/original and \
                 samples/suppression)",
            ));
        }
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
    super::println_stdout(&format!(
        "demo: wrote {} ({} runs, {n} maps from {}; {}) and {} ({b})",
        out.join("report.html").display(),
        c.runs.len(),
        samples.display(),
        crs.join(", "),
        out.join("bonnets").join("report.html").display(),
    ))
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
    sample_recipes(samples)?;
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
    let opts = bonnets::Options {
        remove: settings.remove.clone(),
        ..Default::default()
    };
    let b = bonnets::compare_runs(&recipes, &opts).map_err(|e| CliError {
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
