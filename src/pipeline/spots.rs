//! `spots`: fixed-point (spot) polishing sweeps. Every spot map a manifest lists is read and
//! measured, and the bonnet model fitted per bonnet (`bonnetlab_spots`); the bundled sample
//! sweep is generated from fixed seeds.

use std::fmt::Write as _;
use std::path::Path;

use bonnetlab_spots::manifest::parse_manifest;
use bonnetlab_spots::sweep::{measure_entries, SpotRecord};
use bonnetlab_spots::{
    analyse_sweep, generate_spot, BonnetModel, Factors, FitStart, SpotAnalysis, SpotSpec,
    SweepReport,
};
use bonnetlab_surface::format::fixed;
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;

use super::{Error, Progress};

/// A measured and fitted sweep.
pub struct Sweep {
    pub report: SweepReport,
    /// The analysis of each spot, in manifest order.
    pub analyses: Vec<SpotAnalysis>,
}

/// Parses the manifest text (`manifest` names it), reads and measures every spot map it lists
/// and fits the bonnet model per bonnet from `start`. Progress counts the maps read.
pub fn sweep(
    manifest: &Path,
    text: &str,
    start: &FitStart,
    progress: &dyn Progress,
) -> Result<Sweep, Error> {
    let m = parse_manifest(manifest, text).map_err(|e| Error::input(manifest, e))?;
    progress.message("reading spot maps");
    let mut maps = Vec::with_capacity(m.spots.len());
    for e in &m.spots {
        let s = bonnetlab_io::read_surface(&e.path).map_err(|err| Error {
            code: err.exit_code(),
            message: format!("{err} (listed at {} line {})", manifest.display(), e.line),
        })?;
        // A map without its pixel size is bad input (exit 2), as in every other command.
        if s.dx_mm.is_none() || s.dy_mm.is_none() {
            return Err(Error::input(
                &e.path,
                format!(
                    "the pixel size is unknown (the file does not give one): a spot map must carry its \
                     pixel size (listed at {} line {})",
                    manifest.display(),
                    e.line
                ),
            ));
        }
        maps.push(s);
        progress.inc();
    }
    progress.message("measuring spots and fitting the bonnet TIF models");
    let measured = measure_entries(&m, &maps).map_err(|(k, err)| {
        let e = &m.spots[k];
        Error::processing(
            &e.path,
            format!("{err} (listed at {} line {})", manifest.display(), e.line),
        )
    })?;
    let (records, analyses): (Vec<SpotRecord>, Vec<SpotAnalysis>) = measured.into_iter().unzip();
    let report = analyse_sweep(records, start);
    Ok(Sweep { report, analyses })
}

/// The number of spots a manifest lists (for a progress bar's length).
pub fn manifest_len(manifest: &Path, text: &str) -> Result<usize, Error> {
    parse_manifest(manifest, text)
        .map(|m| m.spots.len())
        .map_err(|e| Error::input(manifest, e))
}

/// The bundled sample sweep: the spot maps (file name, map) and the text of its
/// `manifest.toml`. `dir` names the sample in errors.
///
/// The sample: two bonnets, offset swept 0.2 .. 1.0 mm at the paper's Table 5 settings
/// otherwise, 2-minute spots, 97 x 97 maps at 0.25 mm, 1.5 nm noise, seeded tilt and centre
/// offsets. The suppression bonnet is given a lower Preston coefficient and a softer contact
/// (an assumption for the sample, not a measured fact).
pub fn sample_sweep(dir: &Path) -> Result<(Vec<(String, Surface)>, String), Error> {
    let mut maps = Vec::new();
    let bonnets = [
        ("original", BonnetModel::new(20.0, 0.020, 2.0)),
        ("suppression", BonnetModel::new(20.0, 0.015, 1.2)),
    ];
    let mut rng = Rng::new(2024);
    let mut manifest = String::from(
        "# Synthetic fixed-point sweep written by `bonnetlab spots --make-sample` (seeded):\n\
         # two bonnets, offset swept, the paper's Table 5 settings otherwise. Generating models:\n\
         # original R 20 mm, k 0.020 nm/(MPa mm), E 2.0 MPa; suppression R 20 mm, k 0.015, E 1.2;\n\
         # parabolic pressure; 1.5 nm white noise, random tilt and centre offset.\n\
         [defaults]\n\
         dwell_s = 120.0\nprecession_deg = 20.0\nspindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n",
    );
    let mut seed = 100;
    for (name, model) in bonnets {
        for h in [0.2, 0.4, 0.6, 0.8, 1.0] {
            let spec = SpotSpec {
                model,
                factors: Factors {
                    offset_mm: h,
                    ..Factors::PAPER_BASELINE
                },
                dwell_s: 120.0,
                rows: 97,
                cols: 97,
                dx_mm: 0.25,
                dy_mm: 0.25,
                centre_offset_mm: (rng.uniform() - 0.5, rng.uniform() - 0.5),
                piston_nm: 100.0 * (rng.uniform() - 0.5),
                tilt_nm_per_mm: (4.0 * (rng.uniform() - 0.5), 4.0 * (rng.uniform() - 0.5)),
                noise_rms_nm: 1.5,
                seed,
            };
            seed += 1;
            let s = generate_spot(&spec).map_err(|e| Error::processing(dir, e))?;
            let file = format!("{name}_offset_{h_s}.dat", h_s = fixed(h, 1));
            let _ = write!(
                manifest,
                "\n[[spot]]\nfile = \"{file}\"\nbonnet = \"{name}\"\noffset_mm = {h}\n"
            );
            maps.push((file, s));
        }
    }
    Ok((maps, manifest))
}
