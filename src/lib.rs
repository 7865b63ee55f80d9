//! bonnetlab: metrology, polishing simulation, vibration coupling and closed-loop calibration
//! for robot bonnet polishing of SiC optics.
//!
//! Data flows one way: `io` builds a `Surface`; analyses (`surface`, `spectrum`, `process`,
//! `vibration`, `calibrate`) take surfaces and return plain serialisable result structs;
//! `report` renders those structs for people (HTML, plots) and pipelines (JSON, CSV).

pub use bonnetlab_calibrate as calibrate;
pub use bonnetlab_io as io;
pub use bonnetlab_process as process;
pub use bonnetlab_spectrum as spectrum;
pub use bonnetlab_spots as spots;
pub use bonnetlab_surface as surface;
pub use bonnetlab_vibration as vibration;

pub mod cli;
pub mod pipeline;
pub mod report;
