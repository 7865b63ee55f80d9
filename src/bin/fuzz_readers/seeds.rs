//! The fuzzer's seed corpus: small generated maps, the real Zygo samples (when present) and
//! valid recipes, manifests and dwell cases that the structured readers mutate.

use std::path::{Path, PathBuf};

use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use ndarray::Array2;

use crate::Reader;

fn seed_surface(rows: usize, cols: usize, holes: bool, px: Option<f64>) -> Surface {
    let mut rng = Rng::new((rows * 1000 + cols) as u64);
    let z = Array2::from_shape_fn((rows, cols), |_| {
        if holes && rng.uniform() < 0.1 {
            f64::NAN
        } else {
            100.0 * rng.normal()
        }
    });
    Surface::new(z, px, px).expect("seed surface")
}

/// The real Zygo samples: `$BONNETLAB_REAL_DIR`, else shared/data/real beside the repository.
fn real_dir() -> PathBuf {
    std::env::var_os("BONNETLAB_REAL_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real"))
}

fn real_files(ext: &str) -> Vec<Vec<u8>> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(real_dir())
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    names.sort();
    names
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .filter_map(|p| std::fs::read(p).ok())
        .collect()
}

/// A small Zygo ASCII export (the real PCO2 header with a 6 x 4 phase window, no intensity).
fn small_asc() -> Vec<u8> {
    let mut s = String::from(
        "Zygo ASCII Data File - Format 2\n1 8 1 1 \"Tue May 10 07:36:59 2005     \"\n0 0 0 0 0 0\n\
         0 0 6 4\n\"part\"\n\"\"\n\"\"\n0 0.5 6.328e-007 0 1 0 0.000636653 1513096733\n\
         320 240 4 0 65341 0 \"Sm Aperture\"\n0 0 1 2180 3 1 0.1 51.0067 17 50\n\
         1 0 20 1 96.8896 0 0 0 0\n0 \"                           \"\n1 0\n\"None   \"\n#\n#\n",
    );
    for k in 0..24 {
        s += &if k == 7 {
            "2147483640".to_string()
        } else {
            format!("{}", k * 37 - 400)
        };
        s += if k % 10 == 9 { "\n" } else { " " };
    }
    s += "\n#\n";
    s.into_bytes()
}

/// A small Zygo XYZ export (spec section 4: the ASCII header, then `X Y Z` lines in camera
/// pixels and micrometres, `No Data` for a missing point).
fn small_xyz() -> Vec<u8> {
    let mut s = String::from(
        "Zygo XYZ Data File - Format 1\n1 8 1 1 \"Tue May 10 07:36:59 2005     \"\n0 0 0 0 0 0\n\
         2 3 4 3\n\"part\"\n\"\"\n\"\"\n0 0.5 6.328e-007 0 1 0 0.000636653 1513096733\n\
         320 240 4 0 65341 0 \"Sm Aperture\"\n0 0 1 2180 3 1 0.1 51.0067 17 50\n\
         1 0 20 1 96.8896 0 0 0 0\n0 \"                           \"\n1 0\n\"None   \"\n#\n",
    );
    for row in 0..3 {
        for col in 0..4 {
            if (row, col) == (1, 2) {
                s += &format!("{} {} No Data\n", col + 2, row + 3);
            } else {
                s += &format!(
                    "{} {} {:.6}\n",
                    col + 2,
                    row + 3,
                    0.01 * (row * 4 + col) as f64 - 0.05
                );
            }
        }
    }
    s += "#\n";
    s.into_bytes()
}

const RECIPE: &str = "[measurement]\nbefore = \"before.dat\"\nafter = \"after.dat\"\n\n\
[tif]\nspot = \"spot.dat\"\ndwell_s = 30.0\n\n[path]\nlog = \"path.csv\"\npitch_mm = 3.0\n\n\
[process]\nbonnet = \"original\"\nspindle_rpm = 1000.0\noffset_mm = 0.6\nprecession_deg = 20.0\n\
inner_pressure_mpa = 0.25\n\n[vibration]\nstiffness_n_per_m = 1.0e6\n";

const RECIPE_MODEL: &str = "[measurement]\nbefore = \"b.csv\"\nafter = \"a.csv\"\n[tif]\n\
model = { kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0, diameter_mm = 10.0 }\n\
[path]\nlog = \"p.csv\"\n";

const RECIPE_BONNET: &str = "[measurement]\nbefore = \"b.csv\"\n[tif]\n\
model = { kind = \"bonnet\", radius_mm = 20.0, offset_mm = 0.3, peak_rate_nm_per_s = 20.0 }\n\
[path]\nlog = \"p.csv\"\npitch_mm = 1.0\n[process]\nspindle_rpm = 1200.0\n\
inner_pressure_mpa = 0.2\n[vibration]\nstiffness_n_per_m = 2.0e6\n";

const SPOT_MANIFEST: &str = "[defaults]\ndwell_s = 120.0\nprecession_deg = 20.0\n\
spindle_rpm = 500.0\ninner_pressure_mpa = 0.25\nring_inner_mm = 8.0\nring_outer_mm = 11.0\n\n\
[[spot]]\nfile = \"a.dat\"\nbonnet = \"original\"\noffset_mm = 0.2\n\n\
[[spot]]\nfile = \"b.dat\"\nbonnet = \"suppression\"\noffset_mm = 0.4\ndwell_s = 60.0\n";

const SPOT_MANIFEST_CSV: &str = "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,\
inner_pressure_mpa\na.dat,original,120,20,0.2,500,0.25\nb.dat,suppression,120,20,0.4,500,0.25\n";

const DWELL_CASE: &str = "surface = \"case.dat\"\npixel_mm = 0.361515\n\n[tif]\n\
kind = \"gaussian\"\nsigma_mm = 1.0\ndiameter_mm = 10.0\npeak_rate_nm_per_s = 10.0\n\n\
[clear_aperture]\nrows = [19, 62]\ncols = [31, 558]\nx_mm = [11.206965, 201.363855]\n\
y_mm = [6.868785, 22.052415]\n";

/// Seeds per reader: (bytes, weight). Large real files get a small weight: they are slow.
pub(crate) fn seeds(r: Reader) -> Vec<(Vec<u8>, u32)> {
    let small = [
        seed_surface(5, 7, true, Some(0.1)),
        seed_surface(16, 9, false, None),
        seed_surface(1, 1, false, Some(2.5)),
    ];
    let dat: Vec<Vec<u8>> = small
        .iter()
        .filter_map(|s| bonnetlab_io::metropro_dat_write::encode(s).ok())
        .collect();
    let csv: Vec<Vec<u8>> = small
        .iter()
        .map(|s| {
            let mut v = Vec::new();
            bonnetlab_io::csv_grid::write(s, &mut v).expect("in-memory write");
            v
        })
        .collect();
    let exr: Vec<Vec<u8>> = small
        .iter()
        .filter_map(|s| bonnetlab_io::exr_map::encode(s).ok())
        .collect();
    let path_csv = {
        let n = 40;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.2).collect();
        let x: Vec<f64> = (0..n).map(|k| (k % 10) as f64 * 1.5).collect();
        let y: Vec<f64> = (0..n).map(|k| (k / 10) as f64 * 3.0).collect();
        let p = bonnetlab_process::PathLog::new(t, x, y).expect("path");
        bonnetlab_process::path::log::path_to_csv(&p).into_bytes()
    };
    let weighted = |v: Vec<Vec<u8>>, w: u32| v.into_iter().map(move |b| (b, w));
    let big = |v: Vec<Vec<u8>>| {
        v.into_iter().map(|b| {
            let w = if b.len() > 1_000_000 { 1 } else { 4 };
            (b, w)
        })
    };
    let out: Vec<(Vec<u8>, u32)> = match r {
        Reader::Dat => weighted(dat.clone(), 100)
            .chain(big(real_files("dat")))
            .collect(),
        Reader::Asc => std::iter::once((small_asc(), 200))
            .chain(big(real_files("asc")))
            .collect(),
        Reader::Xyz => vec![(small_xyz(), 100)],
        Reader::Datx => big(real_files("datx")).collect(),
        Reader::Csv => weighted(csv.clone(), 100).collect(),
        Reader::Exr => weighted(exr.clone(), 100).collect(),
        Reader::Detect => weighted(dat, 50)
            .chain(weighted(csv, 50))
            .chain(weighted(exr, 50))
            .chain(std::iter::once((small_asc(), 50)))
            .chain(std::iter::once((small_xyz(), 50)))
            .chain(big(real_files("datx")))
            .chain(big(real_files("dat")))
            .collect(),
        Reader::Path => vec![
            (path_csv, 100),
            (
                b"x_mm,t_s,y_mm,extra\n1,0,2,a\n2,0.5,2,b\n3,1.0,2.5,c\n".to_vec(),
                50,
            ),
        ],
        Reader::Recipe => vec![
            (RECIPE.as_bytes().to_vec(), 100),
            (RECIPE_MODEL.as_bytes().to_vec(), 50),
        ],
        // Model TIFs weigh more here: their checks go further (plan.rs).
        Reader::RecipeX => vec![
            (RECIPE.as_bytes().to_vec(), 50),
            (RECIPE_MODEL.as_bytes().to_vec(), 50),
            (RECIPE_BONNET.as_bytes().to_vec(), 50),
        ],
        // Generated per input (mutate::extreme_path_log); the seed is unused.
        Reader::PathX => vec![(Vec::new(), 1)],
        Reader::ManifestX => vec![
            (SPOT_MANIFEST.as_bytes().to_vec(), 100),
            (SPOT_MANIFEST_CSV.as_bytes().to_vec(), 50),
        ],
        Reader::DwellX => vec![(DWELL_CASE.as_bytes().to_vec(), 100)],
    };
    out
}
