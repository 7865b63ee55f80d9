//! The surface model shared by every part of bonnetlab.
//!
//! Conventions (see `shared/spec/metrology.md`):
//! - heights in nm, lateral lengths in mm, spatial frequency in cycles/mm;
//! - array axis 0 = rows = Y (raster feed direction), axis 1 = columns = X (scan direction);
//! - pixel (i, j) has its centre at (x0 + j dx, y0 + i dy) mm;
//! - invalid pixels are carried by an explicit mask; their stored height is 0.0, never NaN.

pub mod error;
pub mod form;
pub mod rng;
pub mod stats;
pub mod surface;

pub use error::SurfaceError;
pub use form::{remove_terms, FormFit, Term};
pub use stats::{height_stats, HeightStats};
pub use surface::{Provenance, Surface};
