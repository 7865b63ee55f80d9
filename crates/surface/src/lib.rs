//! The surface model shared by every part of bonnetlab.
//!
//! Conventions (see `shared/spec/metrology.md`):
//! - heights in nm, lateral lengths in mm, spatial frequency in cycles/mm;
//! - array axis 0 = rows = Y (raster feed direction), axis 1 = columns = X (scan direction);
//! - pixel (i, j) has its centre at (x0 + j dx, y0 + i dy) mm;
//! - invalid pixels are carried by an explicit mask; their stored height is 0.0, never NaN.

pub mod basis;
pub mod convergence;
pub mod error;
pub mod fill;
pub mod form;
pub mod format;
pub mod grid;
pub mod lm;
pub mod lsq;
pub mod pvr;
pub mod rng;
pub mod stats;
pub mod surface;

pub use convergence::{
    compare_runs, convergence, convergence_ratio, improvement, repeat_cr, Convergence, RepeatCr,
    RunComparison, Spread,
};
pub use error::SurfaceError;
pub use form::{evaluate_fit, fit_terms, remove_terms, FormFit, Term};
pub use grid::Grid;
pub use pvr::{pvr, Pvr, PVR_SET};
pub use stats::{height_stats, HeightStats};
pub use surface::{Provenance, Surface};
