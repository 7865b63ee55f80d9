//! One-dimensional PSDs along X (rows) and Y (columns), ONE-SIDED, in nm^2 mm.
//!
//! For a line of N samples spaced d mm, window w (U = mean(w^2)), detrended samples z:
//! S[k] = d |sum_n w[n] z[n] e^{-2 pi i k n / N}|^2 / (N U) (two-sided density), then
//! P1[k] = 2 S[k] for 0 < k < N/2 and S[k] at k = 0 and k = N/2, f_k = k / (N d).
//! Lines are averaged with measured-count weights; dropouts are handled per segment, and every
//! segment of at least `min_segment_px` samples is used from its own first unbiased bin up
//! (rule and reasons in `lines`). Global form removal (`PsdOptions::remove`) runs once before
//! any line is cut. The lowest `biased_bins` bins are biased by the detrending (and, on
//! apertures without a full-length line, by the smear of the longest segment's window) and
//! should not be read.

use bonnetlab_surface::{HeightStats, Surface, Term};
use serde::Serialize;

use crate::dense::{sum_cols, sum_rows, MapView, StatsAcc};
use crate::error::SpectrumError;
use crate::form::{prepare, Prepared};
use crate::lines::{map_lines, Axis, Detrend, LineRules, LineSums};
use crate::window::Window;

/// Options shared by every PSD in this crate.
#[derive(Debug, Clone, PartialEq)]
pub struct PsdOptions {
    /// Data window (periodic Hann by default).
    pub window: Window,
    /// Form terms removed jointly from the whole map first (default piston, tilt).
    pub remove: Vec<Term>,
    /// Per-segment detrend after the global removal (default: mean).
    pub detrend: Detrend,
    /// Longest interior dropout (pixels) filled by linear interpolation (default 5).
    pub max_gap_px: usize,
    /// Shortest segment analysed, in pixels (default 8: a Hann segment of 8 samples is
    /// trusted only at bins >= 3N/8, near Nyquist; anything shorter resolves nothing).
    pub min_segment_px: usize,
    /// Shortest segment analysed, as a fraction of the line length (default 0: every segment
    /// is used, each at the frequencies its own length resolves; see `lines`). Before issue
    /// #19 this was 0.5, which on round apertures dropped every line outside the central
    /// 87 % of the diameter.
    pub min_segment_fraction: f64,
}

impl Default for PsdOptions {
    fn default() -> Self {
        PsdOptions {
            window: Window::Hann,
            remove: vec![Term::Piston, Term::Tilt],
            detrend: Detrend::Mean,
            max_gap_px: 5,
            min_segment_px: 8,
            min_segment_fraction: 0.0,
        }
    }
}

impl PsdOptions {
    /// The shortest segment analysed for lines of length n.
    pub fn min_segment_len(&self, n: usize) -> usize {
        let frac = (self.min_segment_fraction.clamp(0.0, 1.0) * n as f64).ceil() as usize;
        self.min_segment_px.max(frac).min(n).max(2)
    }

    fn rules(&self, n: usize) -> Result<LineRules, SpectrumError> {
        self.window.validate()?;
        if n < 4 {
            return Err(SpectrumError::TooSmall(format!(
                "lines of {n} samples (at least 4 needed)"
            )));
        }
        Ok(LineRules {
            window: self.window,
            detrend: self.detrend,
            max_gap_px: self.max_gap_px,
            min_len: self.min_segment_len(n),
            biased_bins: self.window.main_lobe_half_width_bins() + 1,
        })
    }
}

/// A one-sided 1-D PSD along one axis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Psd1d {
    pub axis: Axis,
    /// f_k = k / (N d), k = 0..=N/2, cycles/mm.
    pub freq_per_mm: Vec<f64>,
    /// ONE-SIDED density, nm^2 mm.
    pub psd_nm2_mm: Vec<f64>,
    /// Bin width 1 / (N d), mm^-1.
    pub df_per_mm: f64,
    /// Sample spacing d along the lines, mm.
    pub spacing_mm: f64,
    pub window: Window,
    /// ENBW of the window at the full line length, bins.
    pub enbw_bins: f64,
    /// Lines that contributed at least one segment.
    pub n_lines: usize,
    /// Segments averaged.
    pub n_segments: usize,
    /// Bins 0..biased_bins are biased by detrending (DC and the window's main lobe).
    pub biased_bins: usize,
    /// Form terms removed globally before the PSD.
    pub removed: Vec<Term>,
}

impl Psd1d {
    /// Frequency of the first unbiased bin, mm^-1.
    pub fn first_unbiased_freq_per_mm(&self) -> f64 {
        self.biased_bins as f64 * self.df_per_mm
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.psd_nm2_mm.len()
    }

    pub fn is_empty(&self) -> bool {
        self.psd_nm2_mm.is_empty()
    }
}

/// Sample spacing and line length along an axis.
fn geometry(s: &Surface, axis: Axis) -> Result<(f64, usize), SpectrumError> {
    let (dx, dy) = s.pixel_mm("a PSD")?;
    Ok(match axis {
        Axis::X => (dx, s.cols()),
        Axis::Y => (dy, s.rows()),
    })
}

/// Converts line sums to a one-sided density.
fn finish(
    sums: &LineSums,
    n: usize,
    d: f64,
    axis: Axis,
    opts: &PsdOptions,
    removed: Vec<Term>,
) -> Psd1d {
    let df = 1.0 / (n as f64 * d);
    let nbins = n / 2 + 1;
    let b = opts.window.main_lobe_half_width_bins() + 1;
    // Bins where no segment is trusted (below the longest segment's first unbiased bin) take
    // every segment and are reported as biased.
    let first_trusted = (b * n).div_ceil(sums.max_len.max(1)).max(b);
    let psd = (0..nbins)
        .map(|k| {
            let fold = if k == 0 || (n.is_multiple_of(2) && k == n / 2) {
                1.0
            } else {
                2.0
            };
            let (p, w) = if sums.bin_weight[k] > 0.0 {
                (sums.power[k], sums.bin_weight[k])
            } else {
                (sums.power_all[k], sums.weight)
            };
            if w > 0.0 {
                fold * d * p / w
            } else {
                0.0
            }
        })
        .collect();
    Psd1d {
        axis,
        freq_per_mm: (0..nbins).map(|k| k as f64 * df).collect(),
        psd_nm2_mm: psd,
        df_per_mm: df,
        spacing_mm: d,
        window: opts.window,
        enbw_bins: opts.window.enbw_bins(n),
        n_lines: sums.n_lines,
        n_segments: sums.n_segments,
        biased_bins: first_trusted.min(nbins),
        removed,
    }
}

/// PSD along `axis` of a surface whose form has already been removed (no removal here).
pub fn line_psd(s: &Surface, axis: Axis, opts: &PsdOptions) -> Result<Psd1d, SpectrumError> {
    geometry(s, axis)?;
    let p = prepare(s, &[])?;
    Ok(along(&p, axis, opts, false)?.0)
}

/// The line sums of a prepared map along `axis` (with the residual's height moments when
/// `stats` and `axis` is X).
fn line_sums(
    p: &Prepared,
    axis: Axis,
    rules: LineRules,
    stats: bool,
) -> (LineSums, Option<StatsAcc>) {
    // Standard layout is what every reader produces; anything else is copied once here.
    let hc = p.surface.heights_nm().as_standard_layout();
    let vc = p.surface.valid().as_standard_layout();
    let (rows, cols) = p.surface.dim();
    let (Some(heights), Some(valid)) = (hc.as_slice(), vc.as_slice()) else {
        unreachable!("a standard-layout array is contiguous");
    };
    let map = MapView {
        heights,
        valid,
        rows,
        cols,
        model: p.model.as_ref(),
        mask: &p.mask,
        sums: &p.sums,
    };
    match axis {
        Axis::X => sum_rows(&map, rules, stats.then_some(p.mean_nm)),
        Axis::Y => (sum_cols(&map, rules), None),
    }
}

fn along(
    p: &Prepared,
    axis: Axis,
    opts: &PsdOptions,
    stats: bool,
) -> Result<(Psd1d, Option<StatsAcc>), SpectrumError> {
    let (d, n) = geometry(&p.surface, axis)?;
    let rules = opts.rules(n)?;
    let (sums, st) = line_sums(p, axis, rules, stats);
    if sums.n_segments == 0 {
        return Err(SpectrumError::NoUsableLine {
            axis: axis.name(),
            min_len: rules.min_len,
        });
    }
    Ok((finish(&sums, n, d, axis, opts, p.removed.clone()), st))
}

fn prepared_along(s: &Surface, axis: Axis, opts: &PsdOptions) -> Result<Psd1d, SpectrumError> {
    geometry(s, axis)?;
    let p = prepare(s, &opts.remove)?;
    Ok(along(&p, axis, opts, false)?.0)
}

/// One-sided PSD along X (each row a line), nm^2 mm.
pub fn psd_x(s: &Surface, opts: &PsdOptions) -> Result<Psd1d, SpectrumError> {
    prepared_along(s, Axis::X, opts)
}

/// One-sided PSD along Y (each column a line, the raster feed direction), nm^2 mm.
pub fn psd_y(s: &Surface, opts: &PsdOptions) -> Result<Psd1d, SpectrumError> {
    prepared_along(s, Axis::Y, opts)
}

/// Both PSDs with a single form fit.
pub fn psd_xy(s: &Surface, opts: &PsdOptions) -> Result<(Psd1d, Psd1d), SpectrumError> {
    s.pixel_mm("a PSD")?;
    let p = prepare(s, &opts.remove)?;
    let x = along(&p, Axis::X, opts, false)?.0;
    let y = along(&p, Axis::Y, opts, false)?.0;
    Ok((x, y))
}

/// Height parameters of the map after `opts.remove` (the same numbers as
/// `bonnetlab_surface::height_stats` of the residual) together with both PSDs: the metrology
/// of one map with one form fit and no residual map. The statistics are gathered while the X
/// lines are read, so they cost no pass of their own.
pub fn stats_psd_xy(
    s: &Surface,
    opts: &PsdOptions,
) -> Result<(HeightStats, Psd1d, Psd1d), SpectrumError> {
    s.pixel_mm("a PSD")?;
    let p = prepare(s, &opts.remove)?;
    let (x, st) = along(&p, Axis::X, opts, true)?;
    let stats = st
        .and_then(|a| a.finish(p.mean_nm))
        .ok_or(bonnetlab_surface::SurfaceError::NoValidPixel)?;
    let y = along(&p, Axis::Y, opts, false)?.0;
    Ok((stats, x, y))
}

/// Band RMS in [f1, f2] mm^-1 of every line along `axis` (rows for X, columns for Y), from
/// each line's own PSD; `None` for a line without a usable segment. Locates ripple on the part.
pub fn band_rms_profile(
    s: &Surface,
    axis: Axis,
    f1_per_mm: f64,
    f2_per_mm: f64,
    opts: &PsdOptions,
) -> Result<Vec<Option<f64>>, SpectrumError> {
    crate::band::check_band(f1_per_mm, f2_per_mm)?;
    let (d, n) = geometry(s, axis)?;
    let p = prepare(s, &opts.remove)?;
    let rules = opts.rules(n)?;
    Ok(map_lines(
        p.surface.heights_nm().view(),
        p.surface.valid().view(),
        axis,
        rules,
        p.model.as_ref(),
        |sums| {
            if sums.n_segments == 0 {
                return None;
            }
            let psd = finish(sums, n, d, axis, opts, Vec::new());
            Some(crate::band::band_rms(&psd, f1_per_mm, f2_per_mm))
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;
    use ndarray::Array2;

    /// Brute-force DFT periodogram of one line, two-sided density, for comparison.
    fn dft_density(z: &[f64], w: &[f64], d: f64) -> Vec<f64> {
        let n = z.len();
        let u: f64 = w.iter().map(|v| v * v).sum::<f64>() / n as f64;
        (0..n)
            .map(|k| {
                let (mut re, mut im) = (0.0, 0.0);
                for (j, (&zj, &wj)) in z.iter().zip(w).enumerate() {
                    let ph = -2.0 * std::f64::consts::PI * (k * j) as f64 / n as f64;
                    re += wj * zj * ph.cos();
                    im += wj * zj * ph.sin();
                }
                d * (re * re + im * im) / (n as f64 * u)
            })
            .collect()
    }

    #[test]
    fn matches_brute_force_dft_on_random_rows() {
        let (rows, cols, d) = (5, 37, 0.2);
        let mut r = Rng::new(3);
        let h = Array2::from_shape_fn((rows, cols), |_| r.normal());
        let s = Surface::new(h.clone(), Some(d), Some(0.3)).unwrap();
        let opts = PsdOptions {
            remove: vec![],
            ..PsdOptions::default()
        };
        let p = psd_x(&s, &opts).unwrap();
        let w = Window::Hann.coefficients(cols);
        let mut expect = vec![0.0; cols / 2 + 1];
        for i in 0..rows {
            let row: Vec<f64> = h.row(i).to_vec();
            let mean = row.iter().sum::<f64>() / cols as f64;
            let z: Vec<f64> = row.iter().map(|v| v - mean).collect();
            let s2 = dft_density(&z, &w, d);
            for k in 0..expect.len() {
                // N odd: every k > 0 has a mirror bin.
                expect[k] += if k == 0 { s2[k] } else { 2.0 * s2[k] } / rows as f64;
            }
        }
        for (a, b) in p.psd_nm2_mm.iter().zip(&expect) {
            assert!((a - b).abs() <= 1e-10 * b.abs().max(1e-6), "{a} vs {b}");
        }
        assert_eq!(p.n_lines, rows);
        assert!((p.df_per_mm - 1.0 / (cols as f64 * d)).abs() < 1e-15);
    }

    #[test]
    fn dropout_rows_use_every_segment_at_its_own_resolution() {
        // A row split in two by a long gap: at each bin, the measured-count weighted mean of the
        // pieces trusted there (a piece of m samples from bin ceil(3 N / m) up, and every piece
        // below bin 3), the pieces analysed by hand.
        let mut r = Rng::new(11);
        let n = 64;
        let z: Vec<f64> = (0..n).map(|_| r.normal()).collect();
        let mut valid = vec![true; n];
        for v in valid.iter_mut().take(30).skip(20) {
            *v = false;
        }
        // One interpolated sample inside the second piece: it counts in the segment but not in
        // its weight.
        valid[40] = false;
        let h = Array2::from_shape_vec((1, n), z.clone()).unwrap();
        let m = Array2::from_shape_vec((1, n), valid).unwrap();
        let s = Surface::with_mask(h, m, Some(0.1), Some(0.1)).unwrap();
        let opts = PsdOptions {
            remove: vec![],
            ..PsdOptions::default()
        };
        let p = psd_x(&s, &opts).unwrap();
        assert_eq!(p.n_segments, 2);
        let mut zf = z.clone();
        zf[40] = 0.5 * (z[39] + z[41]);
        let mut num = vec![0.0; n / 2 + 1];
        let mut den = vec![0.0; n / 2 + 1];
        for (a, b, measured) in [(0usize, 20usize, 20.0), (30, 64, 33.0)] {
            let m = b - a;
            let first = (3 * n).div_ceil(m);
            let seg = &zf[a..b];
            let mean = seg.iter().sum::<f64>() / m as f64;
            let w = Window::Hann.coefficients(m);
            let e: f64 = w.iter().map(|v| v * v).sum();
            let mut padded = vec![0.0; n];
            for k in 0..m {
                padded[k] = (seg[k] - mean) * w[k];
            }
            let ones = vec![1.0; n];
            // dft_density normalises by N U = sum(ones^2) = n; rescale to the segment energy.
            let s2 = dft_density(&padded, &ones, 0.1);
            for k in 0..num.len() {
                if k < 3 || k >= first {
                    let fold = if k == 0 || k == n / 2 { 1.0 } else { 2.0 };
                    num[k] += fold * s2[k] * n as f64 / e * measured;
                    den[k] += measured;
                }
            }
        }
        // The longer piece (34) is trusted from bin 6: bins 3..5 take both pieces (biased).
        assert_eq!(p.biased_bins, 6);
        for k in 0..num.len() {
            let expect = if den[k] > 0.0 {
                num[k] / den[k]
            } else {
                // both pieces, every bin
                let mut t = 0.0;
                for (a, b, measured) in [(0usize, 20usize, 20.0), (30, 64, 33.0)] {
                    let m = b - a;
                    let seg = &zf[a..b];
                    let mean = seg.iter().sum::<f64>() / m as f64;
                    let w = Window::Hann.coefficients(m);
                    let e: f64 = w.iter().map(|v| v * v).sum();
                    let mut padded = vec![0.0; n];
                    for j in 0..m {
                        padded[j] = (seg[j] - mean) * w[j];
                    }
                    let s2 = dft_density(&padded, &vec![1.0; n], 0.1);
                    t += 2.0 * s2[k] * n as f64 / e * measured / 53.0;
                }
                t
            };
            let got = p.psd_nm2_mm[k];
            assert!(
                (got - expect).abs() <= 1e-10 * expect.abs().max(1e-9),
                "bin {k}: {got} vs {expect}"
            );
        }
    }

    #[test]
    fn errors_on_unknown_pixel_size_and_empty_map() {
        let s = Surface::new(Array2::zeros((8, 8)), None, None).unwrap();
        assert!(psd_x(&s, &PsdOptions::default()).is_err());
        let s = Surface::new(Array2::from_elem((8, 8), f64::NAN), Some(1.0), Some(1.0)).unwrap();
        assert!(psd_x(&s, &PsdOptions::default()).is_err());
    }
}
