//! False-colour pictures of height maps for reports.
//!
//! Conventions:
//! - perceptual colour map (viridis, low = dark violet, high = yellow); invalid pixels grey;
//! - axes in mm when the pixel size is known, in pixels otherwise (the axis label says which);
//! - Y increases upward: row 0 is drawn at the bottom, so the picture shows the map in the
//!   (x, y) = (x0 + j dx, y0 + i dy) frame of `shared/spec/interfaces.md`;
//! - the colour range is the valid heights' min..max unless given (give the same range to
//!   maps that must be compared by eye); the colour bar is labelled in the given unit;
//! - the map is resampled by nearest neighbour into the plot area, keeping the physical
//!   aspect ratio, so output size does not grow with the map.

use plotters::coord::Shift;
use plotters::prelude::*;

use bonnetlab_surface::Surface;

use super::font;
use super::plot::{encode_png_rgb, fmt_tick, PlotError};

/// Grey used for invalid pixels.
pub const INVALID_GREY: [u8; 3] = [150, 150, 150];

/// How to draw a map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapOptions {
    pub title: String,
    /// Unit of the colour bar, e.g. `nm`.
    pub unit: String,
    /// Colour range (low, high) in the map's unit; `None` = min..max of the valid heights.
    pub range: Option<(f64, f64)>,
    /// Picture size in pixels.
    pub width: u32,
    pub height: u32,
}

impl MapOptions {
    pub fn new(title: impl Into<String>, unit: impl Into<String>) -> Self {
        MapOptions {
            title: title.into(),
            unit: unit.into(),
            range: None,
            width: 560,
            height: 480,
        }
    }

    pub fn range(mut self, lo: f64, hi: f64) -> Self {
        self.range = Some((lo, hi));
        self
    }
}

/// A false-colour PNG of the map with a colour bar, axes and title.
pub fn false_colour_png(s: &Surface, title: &str, unit: &str) -> Result<Vec<u8>, PlotError> {
    false_colour_png_with(s, &MapOptions::new(title, unit))
}

/// Min and max of the valid heights, or `None` when no pixel is valid.
pub fn valid_range(s: &Surface) -> Option<(f64, f64)> {
    let (lo, hi) = s
        .valid_heights()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// A false-colour PNG of the map drawn as `opts` says.
pub fn false_colour_png_with(s: &Surface, opts: &MapOptions) -> Result<Vec<u8>, PlotError> {
    let err = |what: String| PlotError {
        title: opts.title.clone(),
        what,
    };
    if !font::ensure_registered() {
        return Err(err("the embedded font was rejected".into()));
    }
    let (w, h) = (opts.width.max(200), opts.height.max(160));
    let (lo, hi) = colour_range(opts.range.or_else(|| valid_range(s)));
    let (rows, cols) = s.dim();
    let known = s.dx_mm.is_some() && s.dy_mm.is_some();
    let (x0, y0) = if known { s.origin_mm } else { (0.0, 0.0) };
    let (dx, dy) = if known {
        (s.dx_mm.unwrap_or(1.0), s.dy_mm.unwrap_or(1.0))
    } else {
        (1.0, 1.0)
    };
    // Pixel-edge extents, so the first and last pixels are drawn whole.
    let xr = (x0 - 0.5 * dx, x0 + (cols as f64 - 0.5) * dx);
    let yr = (y0 - 0.5 * dy, y0 + (rows as f64 - 0.5) * dy);
    let unit_xy = if known { "mm" } else { "pixels" };
    let layout = Layout::fit(w, h, (xr.1 - xr.0, yr.1 - yr.0));
    let (w, h) = (layout.width, layout.height);

    let mut buf = vec![0u8; w as usize * h as usize * 3];
    let (map_px, bar_px) = {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let root = root
            .titled(&opts.title, ("sans-serif", 17))
            .map_err(|e| err(e.to_string()))?;
        let (left, right) = root.split_horizontally(w - Layout::BAR_W);
        let map_px = draw_map_axes(&left, xr, yr, unit_xy, rows, cols).map_err(err)?;
        let bar_px = draw_bar_axes(&right, lo, hi, &opts.unit).map_err(err)?;
        root.present().map_err(|e| err(e.to_string()))?;
        (map_px, bar_px)
    };
    paint_map(&mut buf, w, map_px, s, (lo, hi));
    paint_bar(&mut buf, w, bar_px);
    encode_png_rgb(&buf, w, h).map_err(err)
}

/// Picture layout: the map keeps its physical aspect ratio inside the requested size and the
/// picture shrinks to fit it, so no large blank band is left beside a long, thin map.
struct Layout {
    width: u32,
    height: u32,
}

impl Layout {
    const TITLE_H: u32 = 30;
    const LABEL_X: u32 = 44;
    const LABEL_Y: u32 = 64;
    const PAD: u32 = 8;
    const BAR_W: u32 = 120;

    fn fit(max_w: u32, max_h: u32, (ew, eh): (f64, f64)) -> Layout {
        let avail_w = max_w
            .saturating_sub(Self::BAR_W + Self::LABEL_Y + 2 * Self::PAD)
            .max(40) as f64;
        let avail_h = max_h
            .saturating_sub(Self::TITLE_H + Self::LABEL_X + 2 * Self::PAD)
            .max(40) as f64;
        let (ew, eh) = (ew.max(1e-12), eh.max(1e-12));
        let scale = (avail_w / ew).min(avail_h / eh);
        // At least 120 px along each side so axis labels fit even for a 1 x N map.
        let map_w = ((ew * scale).round() as u32).max(120);
        let map_h = ((eh * scale).round() as u32).max(120);
        Layout {
            width: map_w + Self::BAR_W + Self::LABEL_Y + 2 * Self::PAD,
            height: map_h + Self::TITLE_H + Self::LABEL_X + 2 * Self::PAD,
        }
    }
}

/// Pixel rectangle (x0, y0, x1, y1), inclusive-exclusive, of a drawn plotting area.
type PixelRect = (i32, i32, i32, i32);

fn colour_range(r: Option<(f64, f64)>) -> (f64, f64) {
    match r {
        Some((a, b)) if a.is_finite() && b.is_finite() && b > a => (a, b),
        Some((a, _)) if a.is_finite() => (a - 1.0, a + 1.0),
        _ => (0.0, 1.0),
    }
}

/// Draws the map's axes (the area is sized by `Layout`); returns the plotting area in pixels.
fn draw_map_axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    xr: (f64, f64),
    yr: (f64, f64),
    unit_xy: &str,
    rows: usize,
    cols: usize,
) -> Result<PixelRect, String> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(Layout::PAD)
        .margin_left(Layout::PAD)
        .margin_right(Layout::PAD)
        .margin_bottom(Layout::PAD)
        .x_label_area_size(Layout::LABEL_X)
        .y_label_area_size(Layout::LABEL_Y)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(format!("x ({unit_xy}), {cols} columns"))
        .y_desc(format!("y ({unit_xy}), {rows} rows"))
        .x_label_formatter(&|v| fmt_tick(*v))
        .y_label_formatter(&|v| fmt_tick(*v))
        .x_labels(6)
        .y_labels(6)
        .label_style(("sans-serif", 12))
        .axis_desc_style(("sans-serif", 13))
        .draw()
        .map_err(|e| e.to_string())?;
    let (xp, yp) = chart.plotting_area().get_pixel_range();
    Ok((xp.start, yp.start, xp.end, yp.end))
}

/// Draws the colour bar's axis (value labels in `unit`); returns its plotting area in pixels.
fn draw_bar_axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    lo: f64,
    hi: f64,
    unit: &str,
) -> Result<PixelRect, String> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(Layout::PAD)
        .margin_bottom(Layout::PAD + Layout::LABEL_X)
        .margin_left(12)
        .margin_right(4)
        .right_y_label_area_size(78)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(|e| e.to_string())?
        .set_secondary_coord(0.0..1.0, lo..hi);
    chart
        .configure_secondary_axes()
        .y_labels(8)
        .y_desc(unit)
        .y_label_formatter(&|v| fmt_tick(*v))
        .label_style(("sans-serif", 12))
        .axis_desc_style(("sans-serif", 13))
        .draw()
        .map_err(|e| e.to_string())?;
    let (xp, yp) = chart.plotting_area().get_pixel_range();
    Ok((xp.start, yp.start, xp.end, yp.end))
}

fn put(buf: &mut [u8], w: u32, x: i32, y: i32, c: [u8; 3]) {
    if x < 0 || y < 0 || x as u32 >= w {
        return;
    }
    let k = (y as usize * w as usize + x as usize) * 3;
    if let Some(px) = buf.get_mut(k..k + 3) {
        px.copy_from_slice(&c);
    }
}

fn paint_map(
    buf: &mut [u8],
    w: u32,
    (px0, py0, px1, py1): PixelRect,
    s: &Surface,
    (lo, hi): (f64, f64),
) {
    let (rows, cols) = s.dim();
    let (pw, ph) = ((px1 - px0).max(1) as f64, (py1 - py0).max(1) as f64);
    if rows == 0 || cols == 0 {
        return;
    }
    for py in py0..py1 {
        // Row 0 at the bottom: the top pixel row shows the last map row.
        let fy = (py1 - 1 - py) as f64 + 0.5;
        let i = ((fy / ph * rows as f64) as usize).min(rows - 1);
        for px in px0..px1 {
            let fx = (px - px0) as f64 + 0.5;
            let j = ((fx / pw * cols as f64) as usize).min(cols - 1);
            let c = match s.get(i, j) {
                Some(v) => viridis((v - lo) / (hi - lo)),
                None => INVALID_GREY,
            };
            put(buf, w, px, py, c);
        }
    }
}

fn paint_bar(buf: &mut [u8], w: u32, (px0, py0, px1, py1): PixelRect) {
    // Stop short of the right edge: the value labels and tick marks start there.
    let px1 = (px1 - 6).max(px0 + 4);
    let ph = (py1 - py0).max(1) as f64;
    for py in py0..py1 {
        let t = ((py1 - 1 - py) as f64 + 0.5) / ph;
        let c = viridis(t);
        for px in px0..px1 {
            put(buf, w, px, py, c);
        }
    }
}

/// Viridis sampled at t = 0, 1/8, ..., 1 (matplotlib's table); linear in between.
const VIRIDIS: [[u8; 3]; 9] = [
    [0x44, 0x01, 0x54],
    [0x47, 0x2c, 0x7a],
    [0x3b, 0x51, 0x8b],
    [0x2c, 0x71, 0x8e],
    [0x21, 0x90, 0x8d],
    [0x27, 0xad, 0x81],
    [0x5c, 0xc8, 0x63],
    [0xaa, 0xdc, 0x32],
    [0xfd, 0xe7, 0x25],
];

/// Viridis colour of `t` in [0, 1] (clamped; NaN gives the low end).
pub fn viridis(t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let pos = t * (VIRIDIS.len() - 1) as f64;
    let k = (pos.floor() as usize).min(VIRIDIS.len() - 2);
    let f = pos - k as f64;
    let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
    let mix = |u: u8, v: u8| (u as f64 + f * (v as f64 - u as f64)).round() as u8;
    [mix(a[0], b[0]), mix(a[1], b[1]), mix(a[2], b[2])]
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn viridis_ends_and_clamping() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(1.0), VIRIDIS[8]);
        assert_eq!(viridis(0.5), VIRIDIS[4]);
        assert_eq!(viridis(-3.0), VIRIDIS[0]);
        assert_eq!(viridis(7.0), VIRIDIS[8]);
        assert_eq!(viridis(f64::NAN), VIRIDIS[0]);
        // Monotone in lightness proxy (sum of channels) along the map: perceptual ordering.
        let l: Vec<u32> = (0..=20)
            .map(|k| viridis(k as f64 / 20.0).iter().map(|&c| c as u32).sum())
            .collect();
        assert!(l.windows(2).all(|p| p[1] + 2 >= p[0]), "{l:?}");
    }

    /// A ramp in x with an invalid disc: the picture must show the low and high colours, grey,
    /// the colour bar, and the low end on the left (x increasing to the right).
    #[test]
    fn ramp_map_is_drawn_with_colours_bar_and_grey() {
        let (rows, cols) = (60, 90);
        let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let (di, dj) = (i as f64 - 30.0, j as f64 - 45.0);
            if di * di + dj * dj < 100.0 {
                f64::NAN
            } else {
                j as f64
            }
        });
        let s = Surface::new(z, Some(0.5), Some(0.5)).unwrap();
        let png = false_colour_png(&s, "ramp", "nm").unwrap();
        assert_eq!(
            png,
            false_colour_png(&s, "ramp", "nm").unwrap(),
            "deterministic bytes"
        );
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count(INVALID_GREY) > 100, "invalid disc not grey");
        assert!(count(VIRIDIS[0]) > 100, "low end missing");
        assert!(count(VIRIDIS[8]) > 100, "high end missing");
        // Left of the map is low (dark), right is high (yellow): find the first/last yellow column.
        let (mut first_low, mut first_high) = (u32::MAX, u32::MAX);
        for (x, _, p) in img.enumerate_pixels() {
            if p.0 == VIRIDIS[0] {
                first_low = first_low.min(x);
            }
            if p.0 == VIRIDIS[8] {
                first_high = first_high.min(x);
            }
        }
        assert!(
            first_low < first_high,
            "x axis reversed: low at {first_low}, high at {first_high}"
        );
    }

    #[test]
    fn unknown_pixel_size_and_empty_maps_still_render() {
        let z = Array2::from_shape_fn((10, 30), |(i, j)| (i * j) as f64);
        let s = Surface::new(z, None, None).unwrap();
        assert!(false_colour_png(&s, "pixels", "nm").is_ok());
        let e = Surface::new(Array2::from_elem((4, 4), f64::NAN), None, None).unwrap();
        let png = false_colour_png(&e, "empty", "nm").unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert!(img.pixels().filter(|p| p.0 == INVALID_GREY).count() > 1000);
    }

    #[test]
    fn row_zero_is_at_the_bottom() {
        // Heights increase with the row index: the top of the picture must be the high end.
        let z = Array2::from_shape_fn((50, 50), |(i, _)| i as f64);
        let s = Surface::new(z, Some(1.0), Some(1.0)).unwrap();
        let img = image::load_from_memory(&false_colour_png(&s, "rows", "nm").unwrap())
            .unwrap()
            .to_rgb8();
        let (mut top_high, mut top_low) = (u32::MAX, u32::MAX);
        for (x, y, p) in img.enumerate_pixels() {
            // Skip the colour bar on the right.
            if x > img.width() - 120 {
                continue;
            }
            if p.0 == VIRIDIS[8] {
                top_high = top_high.min(y);
            }
            if p.0 == VIRIDIS[0] {
                top_low = top_low.min(y);
            }
        }
        assert!(top_high < top_low, "high rows must be drawn above low rows");
    }
}
