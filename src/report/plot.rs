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

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use thiserror::Error;

use super::font;

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

    fn err(&self, e: impl std::fmt::Display) -> PlotError {
        PlotError {
            title: self.title.clone(),
            what: e.to_string(),
        }
    }

    /// Points of a series that can be shown on the plot's axes.
    fn drawable(&self, s: &Series) -> Vec<(f64, f64)> {
        s.x.iter()
            .zip(&s.y)
            .map(|(&x, &y)| (x, y))
            .filter(|&(x, y)| ok_on(x, self.x_scale) && ok_on(y, self.y_scale))
            .collect()
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), PlotError> {
        root.fill(&WHITE).map_err(|e| self.err(e))?;
        let pts: Vec<Vec<(f64, f64)>> = self.series.iter().map(|s| self.drawable(s)).collect();
        let xr = axis_range(pts.iter().flatten().map(|p| p.0), self.x_scale);
        let yr = axis_range(pts.iter().flatten().map(|p| p.1), self.y_scale);
        match (self.x_scale, self.y_scale) {
            (Scale::Linear, Scale::Linear) => {
                self.draw_in(root, &pts, xr.0..xr.1, yr.0..yr.1, xr, yr)
            }
            (Scale::Log, Scale::Linear) => {
                self.draw_in(root, &pts, (xr.0..xr.1).log_scale(), yr.0..yr.1, xr, yr)
            }
            (Scale::Linear, Scale::Log) => {
                self.draw_in(root, &pts, xr.0..xr.1, (yr.0..yr.1).log_scale(), xr, yr)
            }
            (Scale::Log, Scale::Log) => self.draw_in(
                root,
                &pts,
                (xr.0..xr.1).log_scale(),
                (yr.0..yr.1).log_scale(),
                xr,
                yr,
            ),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn draw_in<DB, XS, YS>(
        &self,
        root: &DrawingArea<DB, Shift>,
        pts: &[Vec<(f64, f64)>],
        x_spec: XS,
        y_spec: YS,
        xr: (f64, f64),
        yr: (f64, f64),
    ) -> Result<(), PlotError>
    where
        DB: DrawingBackend,
        XS: AsRangedCoord<Value = f64>,
        YS: AsRangedCoord<Value = f64>,
        XS::CoordDescType: ValueFormatter<f64>,
        YS::CoordDescType: ValueFormatter<f64>,
    {
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(72)
            .build_cartesian_2d(x_spec, y_spec)
            .map_err(|e| self.err(e))?;
        chart
            .configure_mesh()
            .x_desc(self.x_label.as_str())
            .y_desc(self.y_label.as_str())
            .x_label_formatter(&|v| fmt_tick(*v))
            .y_label_formatter(&|v| fmt_tick(*v))
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
            .light_line_style(RGBColor(0, 0, 0).mix(0.05))
            .bold_line_style(RGBColor(0, 0, 0).mix(0.15))
            .draw()
            .map_err(|e| self.err(e))?;

        let grey = RGBColor(110, 110, 110);
        for m in &self.markers {
            if !(ok_on(m.x, self.x_scale) && m.x >= xr.0 && m.x <= xr.1) {
                continue;
            }
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(m.x, yr.0), (m.x, yr.1)],
                    6,
                    4,
                    grey.stroke_width(1),
                ))
                .map_err(|e| self.err(e))?;
            chart
                .draw_series(std::iter::once(Text::new(
                    m.label.clone(),
                    (m.x, yr.1),
                    ("sans-serif", 12)
                        .into_font()
                        .color(&grey)
                        .pos(Pos::new(HPos::Left, VPos::Top)),
                )))
                .map_err(|e| self.err(e))?;
        }

        let mut any_legend = false;
        for (i, (s, p)) in self.series.iter().zip(pts).enumerate() {
            let (r, g, b) = s.colour.unwrap_or(PALETTE[i % PALETTE.len()]);
            let colour = RGBColor(r, g, b);
            let style = colour.stroke_width(2);
            let anno = match s.style {
                LineStyle::Solid => chart.draw_series(LineSeries::new(p.iter().copied(), style)),
                LineStyle::Dashed => {
                    chart.draw_series(DashedLineSeries::new(p.iter().copied(), 8, 5, style))
                }
            }
            .map_err(|e| self.err(e))?;
            if !s.label.is_empty() {
                any_legend = true;
                anno.label(s.label.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(2))
                });
            }
        }
        if any_legend {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(160, 160, 160))
                .label_font(("sans-serif", 13))
                .draw()
                .map_err(|e| self.err(e))?;
        }
        Ok(())
    }
}

fn ok_on(v: f64, scale: Scale) -> bool {
    v.is_finite() && (scale == Scale::Linear || v > 0.0)
}

/// Axis range covering the values with a small margin; a sane default when there are none.
fn axis_range(values: impl Iterator<Item = f64>, scale: Scale) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    match scale {
        Scale::Linear => {
            if !(lo.is_finite() && hi.is_finite()) {
                return (0.0, 1.0);
            }
            let span = hi - lo;
            if span <= 0.0 {
                let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
                return (lo - d, hi + d);
            }
            (lo - 0.04 * span, hi + 0.04 * span)
        }
        Scale::Log => {
            if !(lo.is_finite() && hi.is_finite()) {
                return (0.1, 10.0);
            }
            let (l, h) = (lo.log10(), hi.log10());
            let pad = if h - l <= 0.0 { 0.5 } else { 0.04 * (h - l) };
            (10f64.powf(l - pad), 10f64.powf(h + pad))
        }
    }
}

/// Compact tick label: plain decimals in a readable range, scientific outside it.
pub fn fmt_tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { format!("{v}") };
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.1e}");
        return s.replace(".0e", "e");
    }
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// Encodes an 8-bit RGB buffer as PNG.
pub fn encode_png_rgb(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| format!("PNG encoding failed: {e}"))?;
    Ok(out)
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

    #[test]
    fn tick_labels_are_compact() {
        assert_eq!(fmt_tick(0.1), "0.1");
        assert_eq!(fmt_tick(100.0), "100");
        assert_eq!(fmt_tick(1e-5), "1e-5");
        assert_eq!(fmt_tick(2.5e6), "2.5e6");
        assert_eq!(fmt_tick(0.0), "0");
    }
}
