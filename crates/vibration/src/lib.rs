//! Robot vibration: the modal table, the principal-stiffness two-degree-of-freedom forced
//! response, the suppression bonnet's added damping and series compliance, tool-tip time series,
//! and the coupling into removal.
//!
//! Units: stiffness N/mm, force N, mass kg, displacement mm, frequency Hz, angles in degrees at
//! the API. Frames and every default are documented in [`params`].

pub mod coupling;
pub mod error;
pub mod infer;
pub mod modal;
pub mod params;
pub mod response;
pub mod timeseries;

pub use error::VibrationError;
pub use params::{Bonnet, VibrationParams};
pub use response::{forced_response, frf, spindle_band_frf, FrfPoint, Response};
pub use timeseries::{tool_tip_displacement, TimeSeries};
