//! Power spectral densities of surface maps (1-D along X and Y, 2-D, radial), band-limited RMS
//! and the ripple check at the raster's grating spacing. Conventions: `shared/spec/metrology.md`.
//!
//! Band RMS values for reports come from `areal` (brick-wall bands of the map's orthonormal 2-D
//! transform, each axis's border mirrored or periodic, holes filled, band powers by a projection
//! over the valid pixels that is never negative and adds up to Sq^2 exactly); `band` integrates
//! a PSD and is labelled as a PSD quantity.
//!
//! Every PSD says its sidedness: `Psd1d` is ONE-SIDED (nm^2 mm), `Psd2d` is TWO-SIDED
//! (nm^2 mm^2), the radial forms are labelled (`integrated_nm2_mm`, `average_nm2_mm2`).
//! Frequencies are in cycles/mm; angular frequencies only appear in `convert`.
//!
//! Pipeline: global form removal (`PsdOptions::remove`: piston / tilt / power by a joint
//! normal-equation fit in `form`, subtracted on the fly; other terms through
//! `bonnetlab_surface::remove_terms`) -> per-line segments with short gaps interpolated ->
//! per-segment detrend, window, zero-padded real FFT -> valid-count weighted average. Lines
//! without invalid pixels take a fused fast path (`dense`); the map is read once by `scan`,
//! once per direction, and never copied. `stats_psd_xy` adds the height statistics of the
//! residual in the X pass (the full metrology of a map). FFT plans are shared and buffers
//! reused per rayon job; results do not depend on the thread count.

pub mod areal;
pub mod band;
#[macro_use]
mod simd;
pub mod convert;
mod dense;
pub mod error;
pub mod form;
pub mod limit;
mod lines;
pub mod psd1d;
pub mod psd2d;
pub mod ripple;
mod scan;
pub mod window;

pub use areal::{band_split, ArealBands, BAND_EDGES_DEFAULT_PER_MM};
pub use band::{band, band_power, band_rms, fmt_short, fmt_sig, BandRms, MSF_DEFAULT_PER_MM};
pub use convert::{to_gwyddion_w1, to_surfacetopography_c1d, ConvertedPsd};
pub use error::SpectrumError;
pub use form::remove_form;
pub use limit::{check_limit, LimitCheck, LimitLine};
pub use lines::{Axis, Detrend};
pub use psd1d::{
    band_rms_profile, line_psd, psd_x, psd_xy, psd_y, stats_psd_xy, Psd1d, PsdOptions,
};
pub use psd2d::{psd_2d, Psd2d, RadialPsd};
pub use ripple::{
    ripple, ripple_from_psds, Harmonic, Ripple, RippleOptions, PROMINENCE_THRESHOLD_DB,
};
pub use window::Window;
