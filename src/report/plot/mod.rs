//! Line plots for reports: several series with a legend, linear or logarithmic axes, vertical
//! markers (for example the grating frequency 1/pitch and its harmonics), axis labels that
//! carry their units. Rendered with plotters to SVG text or to PNG bytes.
//!
//! Conventions:
//! - on a logarithmic axis, points with a non-positive coordinate are left out (the DC bin of
//!   a PSD, a zero PSD value), as are non-finite points on any axis; the plot never fails
//!   because of them;
//! - markers outside the data's x range are not drawn (a harmonic above Nyquist);
//! - colours come from a fixed palette in series order, so output bytes are deterministic.

//!
//! Modules: [`axes`] (ranges, ticks and their labels), [`layout`] (where the title, marker
//! labels and the legend go, text measuring and fitting), [`draw`] (the curves, markers and
//! legend drawn into a plotters area), [`png`] (encoding).

use plotters::prelude::*;
use thiserror::Error;

use super::font;

pub mod axes;
pub mod draw;
pub mod layout;
pub mod png;

pub use axes::fmt_tick;
pub use png::encode_png_rgb;

/// A plot that could not be drawn (a backend or font failure; never the data's fault).
#[derive(Debug, Error, Clone, PartialEq)]
#[error("plot '{title}': {what}")]
pub struct PlotError {
    pub title: String,
    pub what: String,
}

/// Axis scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    Linear,
    Log,
}

/// Line style of a series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineStyle {
    Solid,
    Dashed,
}

/// One curve: x and y of equal length (extra values of the longer one are ignored).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub label: String,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    /// RGB colour; `None` takes the palette colour for the series' position.
    pub colour: Option<(u8, u8, u8)>,
    pub style: LineStyle,
}

impl Series {
    pub fn new(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Self {
        Series {
            label: label.into(),
            x,
            y,
            colour: None,
            style: LineStyle::Solid,
        }
    }

    pub fn colour(mut self, rgb: (u8, u8, u8)) -> Self {
        self.colour = Some(rgb);
        self
    }

    pub fn dashed(mut self) -> Self {
        self.style = LineStyle::Dashed;
        self
    }
}

/// A vertical line at `x` with a short label at its top.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    pub x: f64,
    pub label: String,
}

/// A line plot description; render it with [`LinePlot::to_svg`] or [`LinePlot::to_png`].
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    pub title: String,
    /// Axis label including its unit, e.g. `frequency (1/mm)`.
    pub x_label: String,
    pub y_label: String,
    pub x_scale: Scale,
    pub y_scale: Scale,
    pub series: Vec<Series>,
    pub markers: Vec<Marker>,
    /// Size in pixels.
    pub width: u32,
    pub height: u32,
}

/// Colour-blind-safe palette (Okabe & Ito), in the order series take it.
pub const PALETTE: [(u8, u8, u8); 8] = [
    (0, 114, 178),
    (213, 94, 0),
    (0, 158, 115),
    (204, 121, 167),
    (230, 159, 0),
    (86, 180, 233),
    (0, 0, 0),
    (240, 228, 66),
];

impl LinePlot {
    /// A linear-axes plot of 800 x 480 pixels with no series yet.
    pub fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
    ) -> Self {
        LinePlot {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_scale: Scale::Linear,
            y_scale: Scale::Linear,
            series: Vec::new(),
            markers: Vec::new(),
            width: 800,
            height: 480,
        }
    }

    pub fn log_log(mut self) -> Self {
        self.x_scale = Scale::Log;
        self.y_scale = Scale::Log;
        self
    }

    pub fn scales(mut self, x: Scale, y: Scale) -> Self {
        self.x_scale = x;
        self.y_scale = y;
        self
    }

    pub fn size(mut self, width: u32, height: u32) -> Self {
        self.width = width.max(64);
        self.height = height.max(64);
        self
    }

    pub fn series(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }

    pub fn marker(mut self, x: f64, label: impl Into<String>) -> Self {
        self.markers.push(Marker {
            x,
            label: label.into(),
        });
        self
    }

    /// Markers at k / pitch for k = 1..=harmonics, labelled `f0`, `2f0`, ...
    pub fn grating_markers(mut self, pitch_mm: f64, harmonics: usize) -> Self {
        if pitch_mm.is_finite() && pitch_mm > 0.0 {
            for k in 1..=harmonics {
                let label = if k == 1 {
                    format!("f0 = 1/{} mm", fmt_tick(pitch_mm))
                } else {
                    format!("{k}f0")
                };
                self.markers.push(Marker {
                    x: k as f64 / pitch_mm,
                    label,
                });
            }
        }
        self
    }

    /// Renders to an SVG document.
    pub fn to_svg(&self) -> Result<String, PlotError> {
        self.check_font()?;
        let mut out = String::new();
        {
            let root =
                SVGBackend::with_string(&mut out, (self.width, self.height)).into_drawing_area();
            self.draw(&root)?;
            root.present().map_err(|e| self.err(e))?;
        }
        Ok(out)
    }

    /// Renders to PNG bytes (8-bit RGB).
    pub fn to_png(&self) -> Result<Vec<u8>, PlotError> {
        self.check_font()?;
        let (w, h) = (self.width, self.height);
        let mut buf = vec![0u8; w as usize * h as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            self.draw(&root)?;
            root.present().map_err(|e| self.err(e))?;
        }
        encode_png_rgb(&buf, w, h).map_err(|what| PlotError {
            title: self.title.clone(),
            what,
        })
    }

    fn check_font(&self) -> Result<(), PlotError> {
        if font::ensure_registered() {
            Ok(())
        } else {
            Err(PlotError {
                title: self.title.clone(),
                what: "the embedded font was rejected".into(),
            })
        }
    }

    pub(crate) fn err(&self, e: impl std::fmt::Display) -> PlotError {
        PlotError {
            title: self.title.clone(),
            what: e.to_string(),
        }
    }
}

#[cfg(test)]
pub(crate) mod test_support {
    use plotters::coord::Shift;
    use plotters::prelude::*;

    use super::font;

    /// A bitmap drawing area of 800 x 480 with the embedded font registered.
    pub fn with_root<T>(f: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> T) -> T {
        assert!(font::ensure_registered());
        let mut buf = vec![0u8; 800 * 480 * 3];
        let root = BitMapBackend::with_buffer(&mut buf, (800, 480)).into_drawing_area();
        f(&root)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_plot() -> LinePlot {
        let f: Vec<f64> = (0..200).map(|k| k as f64 * 0.02).collect();
        let p1: Vec<f64> = f.iter().map(|&x| 1.0 / (0.01 + x * x)).collect();
        let p2: Vec<f64> = f.iter().map(|&x| 0.5 / (0.01 + x * x)).collect();
        LinePlot::new(
            "PSD along Y",
            "frequency (1/mm)",
            "PSD (nm^2 mm, one-sided)",
        )
        .log_log()
        .series(Series::new("before", f.clone(), p1))
        .series(Series::new("after", f, p2).dashed())
        .grating_markers(3.0, 3)
    }

    #[test]
    fn svg_has_text_series_and_markers() {
        let svg = sample_plot().to_svg().unwrap();
        assert!(
            svg.starts_with("<svg") || svg.contains("<svg"),
            "not an SVG"
        );
        assert!(svg.contains("PSD along Y"));
        assert!(svg.contains("frequency (1/mm)"));
        assert!(svg.contains("before") && svg.contains("after"));
        assert!(svg.contains("f0 = 1/3 mm") && svg.contains("2f0") && svg.contains("3f0"));
        assert!(svg.contains("<polyline"), "no line drawn");
    }

    #[test]
    fn png_is_valid_deterministic_and_not_blank() {
        let a = sample_plot().to_png().unwrap();
        let b = sample_plot().to_png().unwrap();
        assert_eq!(a, b, "output bytes must be deterministic");
        let img = image::load_from_memory(&a).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (800, 480));
        // Count pixels in the first series' colour: the curve must actually be drawn.
        let (r, g, b) = PALETTE[0];
        let n = img.pixels().filter(|p| p.0 == [r, g, b]).count();
        assert!(n > 200, "only {n} pixels of the series colour");
        let dark = img.pixels().filter(|p| p.0.iter().all(|&c| c < 80)).count();
        assert!(dark > 500, "text and axes missing ({dark} dark pixels)");
    }

    #[test]
    fn non_positive_and_nan_points_do_not_break_log_plots() {
        let p = LinePlot::new("t", "x", "y").log_log().series(Series::new(
            "s",
            vec![0.0, 1.0, f64::NAN, 2.0],
            vec![1.0, -1.0, 3.0, 4.0],
        ));
        assert!(p.to_svg().is_ok());
        let empty = LinePlot::new("empty", "x", "y")
            .log_log()
            .series(Series::new("s", vec![], vec![]));
        assert!(empty.to_png().is_ok());
    }

    #[test]
    fn markers_outside_the_data_are_skipped() {
        let p = LinePlot::new("t", "x", "y")
            .series(Series::new("s", vec![0.0, 1.0], vec![0.0, 1.0]))
            .marker(0.5, "inside")
            .marker(5.0, "outside");
        let svg = p.to_svg().unwrap();
        assert!(svg.contains("inside"));
        assert!(!svg.contains("outside"));
    }

    /// Curves through every corner of the plot area (where the old in-plot legend sat), a
    /// dashed series and close markers, on every axis-scale combination the reports use
    /// (linear, log-log for PSDs, semi-log): from the image, the legend box holds no curve
    /// pixel and every series colour outside it lies left of it; the dashed series' legend
    /// sample is drawn dashed.
    #[test]
    fn legend_hides_nothing_and_shows_the_line_style() {
        for (xs, ys) in [
            (Scale::Linear, Scale::Linear),
            (Scale::Log, Scale::Log),
            (Scale::Log, Scale::Linear),
            (Scale::Linear, Scale::Log),
        ] {
            legend_check(xs, ys);
        }
    }

    fn legend_check(xs: Scale, ys: Scale) {
        // Positive everywhere so that the log axes keep every point.
        let x: Vec<f64> = (1..=100).map(|k| k as f64 / 100.0).collect();
        let up: Vec<f64> = x.to_vec();
        let down: Vec<f64> = x.iter().map(|v| 1.01 - v).collect();
        let flat_top: Vec<f64> = x.iter().map(|_| 1.0).collect();
        let plot = LinePlot::new("corners", "x (mm)", "y (nm)")
            .scales(xs, ys)
            .series(Series::new("rising", x.clone(), up))
            .series(Series::new("falling", x.clone(), down).dashed())
            .series(Series::new("top", x, flat_top))
            .marker(0.5, "spindle 1000 rpm")
            .marker(0.52, "mode 4");
        let img = image::load_from_memory(&plot.to_png().unwrap())
            .unwrap()
            .to_rgb8();
        let border = [160u8, 160, 160];
        // The box's edges: rows and columns with a run of 20+ border-coloured pixels.
        let (w, h) = img.dimensions();
        let run = |pix: &mut dyn Iterator<Item = bool>| {
            let (mut best, mut cur) = (0, 0);
            for on in pix {
                cur = if on { cur + 1 } else { 0 };
                best = best.max(cur);
            }
            best
        };
        let rows: Vec<u32> = (0..h)
            .filter(|&y| run(&mut (0..w).map(|x| img.get_pixel(x, y).0 == border)) >= 20)
            .collect();
        let cols: Vec<u32> = (0..w)
            .filter(|&x| run(&mut (0..h).map(|y| img.get_pixel(x, y).0 == border)) >= 20)
            .collect();
        assert!(!rows.is_empty() && !cols.is_empty(), "no legend box found");
        let (bx0, bx1) = (cols[0], *cols.last().unwrap());
        let (by0, by1) = (rows[0], *rows.last().unwrap());
        assert!(bx1 > bx0 && by1 > by0, "no legend box found");
        for (k, &(r, g, b)) in PALETTE.iter().enumerate().take(3) {
            let mut outside_right = 0;
            let mut in_box = Vec::new();
            for (x, y, p) in img.enumerate_pixels() {
                if p.0 != [r, g, b] {
                    continue;
                }
                let inside = x >= bx0 && x <= bx1 && y >= by0 && y <= by1;
                if inside {
                    in_box.push((x, y));
                } else if x >= bx0 {
                    outside_right += 1;
                }
            }
            assert_eq!(
                outside_right, 0,
                "{xs:?}/{ys:?}: series {k} drawn beside the legend"
            );
            // Inside the box only the legend sample: one row band, left of the labels.
            let rows: std::collections::BTreeSet<u32> = in_box.iter().map(|p| p.1).collect();
            assert!(
                !in_box.is_empty() && rows.len() <= 3,
                "series {k}: {} pixels on {} rows inside the legend box",
                in_box.len(),
                rows.len()
            );
            let row = *rows.iter().next().unwrap();
            let mut xs: Vec<u32> = in_box.iter().filter(|p| p.1 == row).map(|p| p.0).collect();
            xs.sort_unstable();
            let runs = 1 + xs.windows(2).filter(|w| w[1] > w[0] + 1).count();
            if k == 1 {
                assert!(runs >= 2, "dashed series has a solid legend sample");
            } else {
                assert_eq!(runs, 1, "solid series has a broken legend sample");
            }
        }
    }
}
