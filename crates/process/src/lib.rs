//! The polishing process: tool influence functions, raster paths and their kinematics,
//! dwell-time solvers and removal simulation (fast FFT and exact time-domain deposition).
//!
//! Frame and units: the shared map frame (pixel (i, j) centre at (x0 + j dx, y0 + i dy) mm,
//! rows = Y = feed, columns = X = scan); heights and removal in nm (removal positive = material
//! removed); rates in nm/s; dwell in s (per pixel for maps, or s/mm^2 when said).

pub mod channels;
pub mod config;
pub mod dwell;
pub mod error;
pub mod fft;
pub mod grid;
pub mod interp;
pub mod memory;
pub mod modulated;
pub mod path;
pub mod perturb;
pub mod pixel;
pub mod recipe;
pub mod removal;
pub mod simulate;
pub mod tif;
pub mod usage;

pub use error::ProcessError;
pub use grid::Grid;
pub use path::{read_path_csv, PathLog, RasterSpec};
pub use recipe::Recipe;
pub use removal::{convolve_tif, deposit_exact, dwell_map, FastRemoval};
pub use tif::{RateField, Tif};
