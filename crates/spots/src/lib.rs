//! Fixed-point (spot) polishing sweeps: per-spot TIF metrics, per-bonnet trends across a swept
//! factor, and the bonnet TIF model fitted to the spots.
//!
//! Data flow: a manifest lists spot maps and their settings (`manifest`); each map gives
//! `metrics::SpotMetrics` (`background`, `centre`, `profile` do the steps); per bonnet the
//! `model::BonnetModel` is fitted to the spots (`fit`); `trend` tabulates metric against factor
//! per bonnet with the model's prediction and the optimisation degree between bonnets.
//! `generate` makes seeded synthetic spots from the model for tests and samples.

pub mod background;
pub mod centre;
pub mod error;
pub mod export;
pub mod fit;
pub mod generate;
pub mod manifest;
pub mod metrics;
pub mod model;
pub mod profile;
pub mod sweep;
pub mod trend;

pub use background::MapKind;
pub use error::SpotsError;
pub use fit::{fit_model, FitStart, ModelFit, Observation};
pub use generate::{generate_spot, SpotSpec};
pub use manifest::{parse_manifest, read_manifest, Manifest, SpotEntry};
pub use metrics::{measure_spot, SpotAnalysis, SpotMetrics, SpotOptions};
pub use model::{BonnetModel, Factor, Factors, ModelMetrics};
pub use sweep::{analyse_sweep, measure_entries, BonnetFit, SpotRecord, SweepReport};
pub use trend::{Optimisation, Trend, TrendMetric};
