//! Closing the loop with measured data: registration, residual, diagnosis, an effect library
//! with hold-out selection, and a generator of synthetic measured runs.

pub mod coarse;
pub mod error;

pub mod grid;
pub mod path;
pub mod tif;

pub use error::CalibrateError;
pub mod band;
pub mod effects;
pub mod fill_error;
pub mod lsq;
pub mod model;
pub mod noise;
pub mod pipeline;
pub mod refine;
pub mod resample;
pub mod run;
pub mod selection;
pub mod synth;
pub mod uncertainty;
pub mod unexplained;
