//! `demo`: the bundled two-bonnet example. The sample (the repeat maps of
//! [`super::samples`] and the recipe runs of [`super::recipe_samples`]) is generated here from
//! seeds; the runs to compare are found on disk here; the comparison itself is `compare`'s
//! pipeline and the predicted MSF is [`super::msf_prediction`].

use std::path::{Path, PathBuf};

use super::compare::RunSpec;
use super::recipe_samples::{self, RECIPE_SEED};
use super::samples::{generate, paper_bonnets, SampleMap};
use super::{Error, Progress};

/// One recipe run's files: (file name, bytes).
pub type RunFiles = Vec<(String, Vec<u8>)>;

/// The generated sample: the repeat maps and, per recipe run, its name and files.
pub struct Samples {
    pub maps: Vec<SampleMap>,
    pub runs: Vec<(&'static str, RunFiles)>,
}

/// Generates the sample maps (`seed`, `repeats` measurements per map) and the recipe runs
/// (their own fixed seed, [`RECIPE_SEED`]); `dir` names the sample in errors. Progress gets a
/// message as each recipe run starts (each is an exact deposition, the slow part).
pub fn generate_samples(
    dir: &Path,
    seed: u64,
    repeats: usize,
    progress: &dyn Progress,
) -> Result<Samples, Error> {
    let maps = generate(seed, repeats);
    let mut runs = Vec::new();
    for spec in recipe_samples::recipe_runs(RECIPE_SEED) {
        progress.message(&format!(
            "generating the {} recipe run (exact deposition under the vibration model, seed {})",
            spec.name, spec.seed
        ));
        let run = recipe_samples::generate_run(&spec).map_err(|e| Error {
            code: 1,
            message: format!("demo: {}: {e}", spec.name),
        })?;
        let files = recipe_samples::run_files(&spec, &run).map_err(|e| Error {
            code: 2,
            message: format!("{}: {e}", dir.join(spec.name).display()),
        })?;
        runs.push((spec.name, files));
    }
    Ok(Samples { maps, runs })
}

/// Repeats found on disk for one bonnet and state (`before_1.dat`, `before_2.dat`, ...).
fn repeats_on_disk(dir: &Path, bonnet: &str, state: &str) -> Vec<PathBuf> {
    (1..100)
        .map(|k| dir.join(bonnet).join(format!("{state}_{k}.dat")))
        .take_while(|p| p.is_file())
        .collect()
}

/// The runs of the bundled sample in `dir`: one per bonnet, original first (the reference).
pub fn sample_runs(dir: &Path) -> Result<Vec<RunSpec>, Error> {
    let mut runs = Vec::new();
    for b in paper_bonnets() {
        let before = repeats_on_disk(dir, b.name, "before");
        let after = repeats_on_disk(dir, b.name, "after");
        if before.is_empty() || after.is_empty() {
            return Err(Error::input(
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

/// The recipe files of the sample's runs (original, suppression), checked to exist.
pub fn sample_recipes(dir: &Path) -> Result<[PathBuf; 2], Error> {
    let files = ["original", "suppression"].map(|b| dir.join(b).join("recipe.toml"));
    for r in &files {
        if !r.is_file() {
            return Err(Error::input(
                r,
                "sample recipe missing; create the samples with \
                 `bonnetlab demo --generate-samples DIR`",
            ));
        }
    }
    Ok(files)
}
