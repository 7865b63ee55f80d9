//! The band the process can produce and the finer band (issue #15's band-aware residual).
//!
//! Removal is the TIF convolved with the dwell (and with every path or rate effect the model
//! knows), so its spectrum is the TIF's transfer times something: where the TIF's |MTF| is
//! negligible the process cannot make structure, whatever the path did. The *process band* is
//! radial frequency below `cutoff`: the highest |f| at which the TIF's |MTF| (its kernel
//! spectrum from the process crate's FFT, sampled at the map pitch, normalised by its value at
//! f = 0) is at least [`MTF_THRESHOLD`]. The *fine band* is from `cutoff` to the map's Nyquist
//! frequency: texture that does not resample identically (a sub-pixel registration of a
//! surface sampled at points), aliasing and noise live there, and no effect can explain it.
//!
//! Band RMS values come from the spectrum crate's areal split ([`band_split`]: brick-wall
//! bands of the 2-D DCT, holes filled, the bands' powers add up to the map's mean square
//! exactly); the band components from [`lowpass`], the same split as a map. Each band's share
//! of white noise of RMS sigma is `sigma * sqrt(a)`, `a` the band's share of the frequency
//! rectangle [-Nyquist_x, Nyquist_x] x [-Nyquist_y, Nyquist_y].

use ndarray::Array2;
use serde::Serialize;

use bonnetlab_process::fft::Convolver;
use bonnetlab_spectrum::areal::lowpass;
use bonnetlab_spectrum::band_split;
use bonnetlab_surface::Surface;

use crate::grid::MapGrid;
use crate::tif::TifMap;

/// |MTF| (relative to its value at f = 0) above which the TIF is taken to pass a frequency.
pub const MTF_THRESHOLD: f64 = 1e-2;

/// The process band of a run.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ProcessBand {
    /// Radial frequency (cycles/mm) below which the process can make structure.
    pub cutoff_per_mm: f64,
    /// The |MTF| threshold that defines it.
    pub mtf_threshold: f64,
    /// Nyquist frequencies of the map (cycles/mm), x and y.
    pub nyquist_per_mm: [f64; 2],
}

/// One band of a residual: its edges (cycles/mm, radial), RMS and the white-noise floor's
/// share of it.
#[derive(Debug, Clone, Serialize)]
pub struct BandResidual {
    /// "process" (what the TIF passes) or "fine" (above it).
    pub band: String,
    pub band_per_mm: [f64; 2],
    pub rms_nm: f64,
    /// The noise floor's part in this band (white noise), nm RMS.
    pub floor_nm: f64,
}

impl ProcessBand {
    /// The process band of `tif` on `grid` (the TIF sampled at the map pitch).
    pub fn of(tif: &TifMap, grid: &MapGrid) -> ProcessBand {
        let (dx, dy) = (grid.dx_mm, grid.dy_mm);
        let nyq = [0.5 / dx, 0.5 / dy];
        let k = &tif.tool().sampled().rate_nm_per_s;
        let (k0, k1) = k.dim();
        // Transform of at least 4 kernel widths (and 64 pixels): frequency steps fine enough
        // to place the cutoff within a few percent.
        let conv = Convolver::new((3 * k0).max(64), (3 * k1).max(64), k.view());
        let (n0, n1) = conv.fft_shape();
        let spec = conv.kernel_spectrum();
        let peak = spec.first().map(|c| c.norm()).unwrap_or(0.0);
        let mut cut: f64 = 0.0;
        // Transposed half spectrum: element k1 * n0 + k0 (k0 rows / y, k1 columns / x).
        for (idx, c) in spec.iter().enumerate() {
            let (c1, c0) = (idx / n0, idx % n0);
            let s0 = c0.min(n0 - c0) as f64;
            let f = (s0 / (n0 as f64 * dy)).hypot(c1 as f64 / (n1 as f64 * dx));
            if c.norm() >= MTF_THRESHOLD * peak {
                cut = cut.max(f);
            }
        }
        ProcessBand {
            cutoff_per_mm: cut.min(nyq[0].min(nyq[1])),
            mtf_threshold: MTF_THRESHOLD,
            nyquist_per_mm: nyq,
        }
    }

    /// Share of white-noise power below the cutoff: the disc's area in the frequency
    /// rectangle (the disc clipped to it, by a fine count).
    pub fn process_share(&self) -> f64 {
        let [nx, ny] = self.nyquist_per_mm;
        let f = self.cutoff_per_mm;
        let m = 400;
        let mut hit = 0usize;
        for i in 0..m {
            for j in 0..m {
                let (u, v) = (
                    (i as f64 + 0.5) / m as f64 * nx,
                    (j as f64 + 0.5) / m as f64 * ny,
                );
                if u.hypot(v) < f {
                    hit += 1;
                }
            }
        }
        hit as f64 / (m * m) as f64
    }

    /// The fine-band component of a masked map (the map minus its process-band low-pass).
    pub fn fine_part(&self, g: &MapGrid, r: &Array2<f64>, valid: &Array2<bool>) -> Array2<f64> {
        let low = lowpass(r, valid, g.dx_mm, g.dy_mm, self.cutoff_per_mm);
        r - &low
    }

    /// The residual's RMS per band (process, fine) with each band's share of the white-noise
    /// floor `noise_nm`. A band the map cannot resolve is left out.
    pub fn split(
        &self,
        g: &MapGrid,
        r: &Array2<f64>,
        valid: &Array2<bool>,
        noise_nm: f64,
    ) -> Vec<BandResidual> {
        let Ok(s) = Surface::with_mask(r.clone(), valid.clone(), Some(g.dx_mm), Some(g.dy_mm))
        else {
            return Vec::new();
        };
        let f = self.cutoff_per_mm;
        let Ok(b) = band_split(&s, &[], (f, f)) else {
            return Vec::new();
        };
        let share = self.process_share();
        let nyq = self.nyquist_per_mm[0].max(self.nyquist_per_mm[1]);
        let mut out = Vec::new();
        if let Some(v) = b.figure_rms_nm {
            out.push(BandResidual {
                band: "process".into(),
                band_per_mm: [0.0, f],
                rms_nm: v,
                floor_nm: noise_nm * share.sqrt(),
            });
        }
        if let Some(v) = b.fine_rms_nm {
            out.push(BandResidual {
                band: "fine".into(),
                band_per_mm: [f, nyq],
                rms_nm: v,
                floor_nm: noise_nm * (1.0 - share).max(0.0).sqrt(),
            });
        }
        out
    }
}
