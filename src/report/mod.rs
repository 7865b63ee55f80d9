//! Rendering result structs for people (HTML with inline plots) and pipelines (JSON, CSV).
//! Nothing outside this module formats text for people.

pub mod bonnets;
pub mod compare_report;
pub mod comparison;
pub mod dwell_report;
pub mod font;
pub use bonnetlab_surface::format;
pub mod html;
pub mod maps;
pub mod msf_prediction;
pub mod plot;
pub mod recipe_samples;
pub mod run_spec;
pub mod samples;
pub mod write;
