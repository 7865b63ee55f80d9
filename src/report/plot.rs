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

use plotters::coord::combinators::LogCoord;
use plotters::coord::ranged1d::{
    AsRangedCoord, DefaultFormatting, KeyPointHint, Ranged, ValueFormatter,
};
use plotters::coord::types::RangedCoordf64;
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
        let layout = self.layout(root, xr);
        let (x0, x1) = (layout.plot_left, layout.plot_right);
        let (y0, y1) = (layout.plot_top, layout.plot_bottom);
        let measure = |t: &str| text_width(root, t, TICK_FONT);
        let xt = ticks(xr, self.x_scale, (x1 - x0) as f64, true, &measure);
        let yt = ticks(yr, self.y_scale, (y1 - y0) as f64, false, &measure);
        let (xs, ys) = (self.x_scale, self.y_scale);
        let lin = |r: (f64, f64), t: &(Vec<f64>, Vec<f64>)| Ticked {
            inner: RangedCoordf64::from(r.0..r.1),
            bold: t.0.clone(),
            light: t.1.clone(),
        };
        let log = |r: (f64, f64), t: &(Vec<f64>, Vec<f64>)| Ticked {
            inner: LogCoord::<f64>::from((r.0..r.1).log_scale()),
            bold: t.0.clone(),
            light: t.1.clone(),
        };
        let x_lin = || lin(xr, &xt);
        let x_log = || log(xr, &xt);
        let y_lin = || lin(yr, &yt);
        let y_log = || log(yr, &yt);
        match (xs, ys) {
            (Scale::Linear, Scale::Linear) => {
                self.draw_in(root, &layout, &pts, x_lin(), y_lin(), yr)
            }
            (Scale::Log, Scale::Linear) => self.draw_in(root, &layout, &pts, x_log(), y_lin(), yr),
            (Scale::Linear, Scale::Log) => self.draw_in(root, &layout, &pts, x_lin(), y_log(), yr),
            (Scale::Log, Scale::Log) => self.draw_in(root, &layout, &pts, x_log(), y_log(), yr),
        }
    }

    /// Where everything goes, in pixels. The title sits above the plot area, the marker labels
    /// in rows of their own between the title and the plot area (a label moves down a row
    /// rather than overlap another), and the legend in a column right of the plot area: no
    /// curve, marker line or tick label can be drawn under the legend or a label.
    fn layout<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, xr: (f64, f64)) -> Layout {
        let (w, h) = (self.width as i32, self.height as i32);
        let title = fit_text(root, &self.title, TITLE_FONT, w - 2 * MARGIN);
        let title_h = TITLE_FONT as i32 + 6;
        let max_legend_text = (w / 3).max(60);
        let legend: Vec<(usize, String)> = self
            .series
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.label.is_empty())
            .map(|(i, s)| (i, fit_text(root, &s.label, LEGEND_FONT, max_legend_text)))
            .collect();
        let legend_text_w = legend
            .iter()
            .map(|(_, l)| text_width(root, l, LEGEND_FONT))
            .max()
            .unwrap_or(0);
        let legend_w = if legend.is_empty() {
            0
        } else {
            LEGEND_SAMPLE + legend_text_w + 3 * LEGEND_PAD + MARGIN
        };
        let plot_left = MARGIN + Y_LABEL_AREA;
        let plot_right = w - legend_w - MARGIN;
        // Marker labels, greedily placed in the first row where they overlap nothing.
        let mut rows_end: Vec<i32> = Vec::new();
        let mut markers = Vec::new();
        for m in &self.markers {
            if !(ok_on(m.x, self.x_scale) && m.x >= xr.0 && m.x <= xr.1) {
                continue;
            }
            let t = match self.x_scale {
                Scale::Linear => (m.x - xr.0) / (xr.1 - xr.0),
                Scale::Log => (m.x / xr.0).ln() / (xr.1 / xr.0).ln(),
            };
            let px = plot_left + (t * (plot_right - plot_left) as f64).round() as i32;
            let tw = text_width(root, &m.label, MARKER_FONT);
            let mut left = px + 3;
            if left + tw > w - MARGIN / 2 {
                left = px - 3 - tw;
            }
            let row = match rows_end.iter().position(|&e| left > e + 6) {
                Some(r) => r,
                None => {
                    rows_end.push(i32::MIN / 2);
                    rows_end.len() - 1
                }
            };
            rows_end[row] = left + tw;
            markers.push((m.x, m.label.clone(), left, row));
        }
        let plot_top = MARGIN / 2 + title_h + rows_end.len() as i32 * MARKER_ROW + MARGIN / 2;
        let plot_bottom = h - MARGIN - X_LABEL_AREA;
        Layout {
            title,
            title_top: MARGIN / 2,
            legend,
            legend_w,
            plot_left,
            plot_right,
            plot_top,
            plot_bottom,
            markers,
            marker_top: MARGIN / 2 + title_h,
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn draw_in<DB, XS, YS>(
        &self,
        root: &DrawingArea<DB, Shift>,
        layout: &Layout,
        pts: &[Vec<(f64, f64)>],
        x_spec: XS,
        y_spec: YS,
        yr: (f64, f64),
    ) -> Result<(), PlotError>
    where
        DB: DrawingBackend,
        XS: AsRangedCoord<Value = f64>,
        YS: AsRangedCoord<Value = f64>,
        XS::CoordDescType: ValueFormatter<f64>,
        YS::CoordDescType: ValueFormatter<f64>,
    {
        let (w, _) = (self.width as i32, self.height as i32);
        let black = RGBColor(0, 0, 0);
        let tw = text_width(root, &layout.title, TITLE_FONT);
        root.draw(&Text::new(
            layout.title.clone(),
            ((w - tw) / 2, layout.title_top),
            ("sans-serif", TITLE_FONT)
                .into_font()
                .color(&black)
                .pos(Pos::new(HPos::Left, VPos::Top)),
        ))
        .map_err(|e| self.err(e))?;

        let area = root.margin(layout.plot_top - MARGIN, 0, 0, layout.legend_w as u32);
        let mut chart = ChartBuilder::on(&area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL_AREA)
            .y_label_area_size(Y_LABEL_AREA)
            .build_cartesian_2d(x_spec, y_spec)
            .map_err(|e| self.err(e))?;
        chart
            .configure_mesh()
            .x_desc(self.x_label.as_str())
            .y_desc(self.y_label.as_str())
            .x_label_formatter(&|v| fmt_tick(*v))
            .y_label_formatter(&|v| fmt_tick(*v))
            .label_style(("sans-serif", TICK_FONT))
            .axis_desc_style(("sans-serif", 14))
            .light_line_style(RGBColor(0, 0, 0).mix(0.05))
            .bold_line_style(RGBColor(0, 0, 0).mix(0.15))
            .draw()
            .map_err(|e| self.err(e))?;

        let grey = RGBColor(110, 110, 110);
        for (x, label, left, row) in &layout.markers {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(*x, yr.0), (*x, yr.1)],
                    6,
                    4,
                    grey.stroke_width(1),
                ))
                .map_err(|e| self.err(e))?;
            root.draw(&Text::new(
                label.clone(),
                (*left, layout.marker_top + *row as i32 * MARKER_ROW),
                ("sans-serif", MARKER_FONT)
                    .into_font()
                    .color(&grey)
                    .pos(Pos::new(HPos::Left, VPos::Top)),
            ))
            .map_err(|e| self.err(e))?;
        }

        let colour_of = |i: usize, s: &Series| {
            let (r, g, b) = s.colour.unwrap_or(PALETTE[i % PALETTE.len()]);
            RGBColor(r, g, b)
        };
        for (i, (s, p)) in self.series.iter().zip(pts).enumerate() {
            let style = colour_of(i, s).stroke_width(2);
            match s.style {
                LineStyle::Solid => chart.draw_series(LineSeries::new(p.iter().copied(), style)),
                LineStyle::Dashed => {
                    chart.draw_series(DashedLineSeries::new(p.iter().copied(), 8, 5, style))
                }
            }
            .map_err(|e| self.err(e))?;
        }

        if !layout.legend.is_empty() {
            let bx0 = w - layout.legend_w + LEGEND_PAD;
            let bx1 = w - MARGIN;
            let by0 = layout.plot_top;
            let by1 = by0 + LEGEND_PAD + layout.legend.len() as i32 * LEGEND_ROW;
            root.draw(&Rectangle::new(
                [(bx0, by0), (bx1, by1)],
                RGBColor(160, 160, 160).stroke_width(1),
            ))
            .map_err(|e| self.err(e))?;
            for (k, (i, label)) in layout.legend.iter().enumerate() {
                let s = &self.series[*i];
                let c = colour_of(*i, s);
                let y = by0 + LEGEND_PAD + k as i32 * LEGEND_ROW + LEGEND_ROW / 2 - 1;
                let sx0 = bx0 + LEGEND_PAD;
                let segments: Vec<(i32, i32)> = match s.style {
                    LineStyle::Solid => vec![(sx0, sx0 + LEGEND_SAMPLE)],
                    LineStyle::Dashed => (0..)
                        .map(|j| sx0 + j * 10)
                        .take_while(|&a| a < sx0 + LEGEND_SAMPLE)
                        .map(|a| (a, (a + 6).min(sx0 + LEGEND_SAMPLE)))
                        .collect(),
                };
                for (a, b) in segments {
                    root.draw(&PathElement::new(vec![(a, y), (b, y)], c.stroke_width(2)))
                        .map_err(|e| self.err(e))?;
                }
                root.draw(&Text::new(
                    label.clone(),
                    (sx0 + LEGEND_SAMPLE + LEGEND_PAD, y),
                    ("sans-serif", LEGEND_FONT)
                        .into_font()
                        .color(&black)
                        .pos(Pos::new(HPos::Left, VPos::Center)),
                ))
                .map_err(|e| self.err(e))?;
            }
        }
        Ok(())
    }
}

const MARGIN: i32 = 12;
const X_LABEL_AREA: i32 = 44;
const Y_LABEL_AREA: i32 = 72;
const TITLE_FONT: f64 = 18.0;
const TICK_FONT: f64 = 13.0;
const LEGEND_FONT: f64 = 13.0;
const MARKER_FONT: f64 = 12.0;
const MARKER_ROW: i32 = 15;
const LEGEND_ROW: i32 = 18;
const LEGEND_PAD: i32 = 6;
const LEGEND_SAMPLE: i32 = 26;

/// An axis whose labelled ticks and light grid lines are given (see [`ticks`]).
struct Ticked<R: Ranged<ValueType = f64>> {
    inner: R,
    bold: Vec<f64>,
    light: Vec<f64>,
}

impl<R: Ranged<ValueType = f64>> Ranged for Ticked<R> {
    type ValueType = f64;
    type FormatOption = DefaultFormatting;

    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<H: KeyPointHint>(&self, hint: H) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.light.clone()
        } else {
            self.bold.clone()
        }
    }

    fn axis_pixel_range(&self, limit: (i32, i32)) -> std::ops::Range<i32> {
        self.inner.axis_pixel_range(limit)
    }
}

/// Pixel positions computed once and used by the drawing.
struct Layout {
    title: String,
    title_top: i32,
    /// (series index, label as shown).
    legend: Vec<(usize, String)>,
    legend_w: i32,
    plot_left: i32,
    plot_right: i32,
    plot_top: i32,
    plot_bottom: i32,
    /// (x, label, left pixel of the label, row).
    markers: Vec<(f64, String, i32, usize)>,
    marker_top: i32,
}

fn text_width<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, t: &str, size: f64) -> i32 {
    root.estimate_text_size(t, &TextStyle::from(("sans-serif", size).into_font()))
        .map(|(w, _)| w as i32)
        // Without font metrics: DejaVu Sans averages about 0.62 em per character.
        .unwrap_or((t.chars().count() as f64 * 0.62 * size) as i32)
}

/// `t` shortened to fit `max_w` pixels: leading folders of a path are replaced by `…/` first
/// (the file name is kept), then the middle of the text is cut.
fn fit_text<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    t: &str,
    size: f64,
    max_w: i32,
) -> String {
    let fits = |s: &str| text_width(root, s, size) <= max_w;
    if fits(t) {
        return t.to_string();
    }
    let mut words: Vec<String> = t.split(' ').map(str::to_string).collect();
    // A word as (punctuation before a path, such as an opening bracket, which stays; the path
    // without a leading `…/`).
    let split = |w: &str| -> (String, String) {
        let lead: String = w
            .chars()
            .take_while(|c| !c.is_alphanumeric() && !matches!(c, '/' | '.' | '…' | '~' | '_'))
            .collect();
        let rest = w[lead.len()..].trim_start_matches("…/").to_string();
        (lead, rest)
    };
    let droppable = |w: &str| {
        split(w)
            .1
            .find('/')
            .is_some_and(|i| i + 1 < split(w).1.len())
    };
    // Drop the leading folder of the longest word that still has one, until the text fits.
    while let Some(k) = (0..words.len())
        .filter(|&k| droppable(&words[k]))
        .max_by_key(|&k| words[k].chars().count())
    {
        let (lead, w) = split(&words[k]);
        let rest = &w[w.find('/').unwrap_or(0) + 1..];
        words[k] = format!("{lead}…/{rest}");
        let joined = words.join(" ");
        if fits(&joined) {
            return joined;
        }
    }
    let s: Vec<char> = words.join(" ").chars().collect();
    // Keep the head and the tail (where a file name usually is), cut the middle.
    for cut in 1..s.len() {
        let keep = s.len() - cut;
        let head = keep / 3;
        let tail = keep - head;
        let cand: String = s[..head]
            .iter()
            .chain(std::iter::once(&'…'))
            .chain(&s[s.len() - tail..])
            .collect();
        if fits(&cand) {
            return cand;
        }
    }
    "…".into()
}

/// Labelled ticks (and light grid lines) for an axis `len_px` long. Linear axes step by 1, 2
/// or 5 x 10^k; logarithmic axes label 1 x 10^k, or 1, 2, 5 x 10^k, or every integer
/// multiple, whichever is the densest whose labels do not touch (the x axis measures its
/// labels; the y axis needs 18 px per label), and fall back to linear steps inside a
/// range narrower than that.
fn ticks(
    r: (f64, f64),
    scale: Scale,
    len_px: f64,
    horizontal: bool,
    measure: &dyn Fn(&str) -> i32,
) -> (Vec<f64>, Vec<f64>) {
    let len_px = len_px.max(1.0);
    let px = |v: f64| match scale {
        Scale::Linear => (v - r.0) / (r.1 - r.0) * len_px,
        Scale::Log => (v / r.0).ln() / (r.1 / r.0).ln() * len_px,
    };
    let spaced = |t: &[f64]| {
        t.windows(2).all(|w| {
            let gap = (px(w[1]) - px(w[0])).abs();
            let need = if horizontal {
                0.5 * (measure(&fmt_tick(w[0])) + measure(&fmt_tick(w[1]))) as f64 + 10.0
            } else {
                18.0
            };
            gap >= need
        })
    };
    let linear = || {
        for n in (2..=12usize).rev() {
            let t = nice_linear(r, n);
            if t.len() >= 2 && spaced(&t) {
                return t;
            }
        }
        nice_linear(r, 2)
    };
    match scale {
        Scale::Linear => (linear(), Vec::new()),
        Scale::Log => {
            let (d0, d1) = (r.0.log10().floor() as i32, r.1.log10().ceil() as i32);
            let in_range = |m: &[f64], every: i32| -> Vec<f64> {
                let mut t = Vec::new();
                for d in d0..=d1 {
                    if (d - d0) % every != 0 {
                        continue;
                    }
                    for &k in m {
                        let v = k * 10f64.powi(d);
                        if v >= r.0 * (1.0 - 1e-9) && v <= r.1 * (1.0 + 1e-9) {
                            t.push(v);
                        }
                    }
                }
                t
            };
            let all: Vec<f64> = (1..10).map(f64::from).collect();
            let light = in_range(&all, 1);
            for m in [&all[..], &[1.0, 2.0, 5.0][..], &[1.0][..]] {
                let t = in_range(m, 1);
                if t.len() >= 2 && spaced(&t) {
                    return (t, light);
                }
                if t.len() < 2 {
                    // Less than a step of this kind in range: plain decimal steps.
                    return (linear(), light);
                }
            }
            for every in 2..=((d1 - d0).max(2)) {
                let t = in_range(&[1.0], every);
                if t.len() < 2 || spaced(&t) {
                    return (t, light);
                }
            }
            (in_range(&[1.0], d1 - d0), light)
        }
    }
}

/// About `n` ticks at 1, 2 or 5 x 10^k steps inside `r`.
fn nice_linear(r: (f64, f64), n: usize) -> Vec<f64> {
    let span = r.1 - r.0;
    if !(span > 0.0 && span.is_finite()) {
        return vec![r.0];
    }
    let raw = span / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (r.0 / step).ceil() as i64;
    let last = (r.1 / step).floor() as i64;
    (first..=last).map(|i| i as f64 * step).collect()
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

    /// Curves through every corner of the plot area (where the old in-plot legend sat), a
    /// dashed series and close markers: from the image, the legend box holds no curve pixel
    /// and every series colour outside it lies left of it; the dashed series' legend sample
    /// is drawn dashed.
    #[test]
    fn legend_hides_nothing_and_shows_the_line_style() {
        let x: Vec<f64> = (0..=100).map(|k| k as f64 / 100.0).collect();
        let up: Vec<f64> = x.to_vec();
        let down: Vec<f64> = x.iter().map(|v| 1.0 - v).collect();
        let flat_top: Vec<f64> = x.iter().map(|_| 1.0).collect();
        let plot = LinePlot::new("corners", "x (mm)", "y (nm)")
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
            assert_eq!(outside_right, 0, "series {k} drawn beside the legend");
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

    fn with_root<T>(f: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> T) -> T {
        assert!(font::ensure_registered());
        let mut buf = vec![0u8; 800 * 480 * 3];
        let root = BitMapBackend::with_buffer(&mut buf, (800, 480)).into_drawing_area();
        f(&root)
    }

    #[test]
    fn close_marker_labels_take_separate_rows() {
        let plot = LinePlot::new("t", "f (Hz)", "x (mm)")
            .series(Series::new("s", vec![0.0, 30.0], vec![0.0, 1.0]))
            .marker(16.67, "spindle 1000 rpm")
            .marker(20.0, "mode 4")
            .marker(21.67, "mode 5")
            .marker(5.0, "mode 1");
        let boxes = with_root(|root| {
            let l = plot.layout(root, (0.0, 30.0));
            l.markers
                .iter()
                .map(|(_, label, left, row)| {
                    (*left, *left + text_width(root, label, MARKER_FONT), *row)
                })
                .collect::<Vec<_>>()
        });
        assert_eq!(boxes.len(), 4);
        for (i, a) in boxes.iter().enumerate() {
            for b in &boxes[i + 1..] {
                let overlap = a.2 == b.2 && a.0 < b.1 && b.0 < a.1;
                assert!(!overlap, "labels {a:?} and {b:?} overlap");
            }
        }
        assert!(
            boxes.iter().any(|b| b.2 > 0),
            "no label moved to a second row"
        );
    }

    #[test]
    fn log_axis_ticks_are_labelled_and_do_not_touch() {
        with_root(|root| {
            let measure = |t: &str| text_width(root, t, TICK_FONT);
            // Less than two decades, mostly below 0.1 (old: no label below 0.1, or
            // "0.080.090.1" where every integer multiple was labelled).
            for (r, len) in [
                ((0.03, 0.5), 600.0),
                ((0.02, 1.3), 640.0),
                ((1e-3, 8.0), 500.0),
            ] {
                let (t, _) = ticks(r, Scale::Log, len, true, &measure);
                assert!(t.len() >= 3, "{r:?}: only {t:?}");
                assert!(
                    t.iter().any(|&v| v < 0.1),
                    "{r:?}: no tick below 0.1: {t:?}"
                );
                let px = |v: f64| (v / r.0).ln() / (r.1 / r.0).ln() * len;
                for w in t.windows(2) {
                    let need = 0.5 * (measure(&fmt_tick(w[0])) + measure(&fmt_tick(w[1]))) as f64;
                    assert!(px(w[1]) - px(w[0]) > need, "{r:?}: {w:?} labels touch");
                }
            }
            // A range inside one decade still gets labels.
            let (t, _) = ticks((0.3, 0.9), Scale::Log, 600.0, true, &measure);
            assert!(t.len() >= 3, "{t:?}");
        });
    }

    #[test]
    fn long_titles_keep_the_file_name() {
        let title = "1-D PSD (/very/long/folder/name/that/keeps/going/and/going/further/still/before_1_with_a_long_name.dat, window hann)";
        let fitted = with_root(|root| {
            let t = fit_text(root, title, TITLE_FONT, 800 - 2 * MARGIN);
            assert!(text_width(root, &t, TITLE_FONT) <= 800 - 2 * MARGIN);
            t
        });
        assert!(fitted.starts_with("1-D PSD (…/"), "{fitted}");
        // A file name too long even without its folders is cut in the middle, never a panic.
        let long = format!("PSD of /a/{}.dat", "x".repeat(200));
        let cut = with_root(|root| fit_text(root, &long, TITLE_FONT, 400));
        assert!(cut.ends_with(".dat") && cut.contains('…'), "{cut}");
        assert!(
            fitted.ends_with("before_1_with_a_long_name.dat, window hann)"),
            "{fitted}"
        );
    }
}
