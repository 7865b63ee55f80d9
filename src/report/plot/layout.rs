//! Where everything goes, in pixels: the title, the marker labels (in rows of their own) and
//! the legend (a column right of the plot area), and the measuring and fitting of text.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::axes::ok_on;
use super::{LinePlot, Scale};

pub(crate) const MARGIN: i32 = 12;
pub(crate) const X_LABEL_AREA: i32 = 44;
pub(crate) const Y_LABEL_AREA: i32 = 72;
pub(crate) const TITLE_FONT: f64 = 18.0;
pub(crate) const TICK_FONT: f64 = 13.0;
pub(crate) const LEGEND_FONT: f64 = 13.0;
pub(crate) const MARKER_FONT: f64 = 12.0;
pub(crate) const MARKER_ROW: i32 = 15;
pub(crate) const LEGEND_ROW: i32 = 18;
pub(crate) const LEGEND_PAD: i32 = 6;
pub(crate) const LEGEND_SAMPLE: i32 = 26;

/// Pixel positions computed once and used by the drawing.
pub(crate) struct Layout {
    pub(crate) title: String,
    pub(crate) title_top: i32,
    /// (series index, label as shown).
    pub(crate) legend: Vec<(usize, String)>,
    pub(crate) legend_w: i32,
    pub(crate) plot_left: i32,
    pub(crate) plot_right: i32,
    pub(crate) plot_top: i32,
    pub(crate) plot_bottom: i32,
    /// (x, label, left pixel of the label, row).
    pub(crate) markers: Vec<(f64, String, i32, usize)>,
    pub(crate) marker_top: i32,
}

impl LinePlot {
    /// Where everything goes, in pixels. The title sits above the plot area, the marker labels
    /// in rows of their own between the title and the plot area (a label moves down a row
    /// rather than overlap another), and the legend in a column right of the plot area: no
    /// curve, marker line or tick label can be drawn under the legend or a label.
    pub(crate) fn layout<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        xr: (f64, f64),
    ) -> Layout {
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
}

pub(crate) fn text_width<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    t: &str,
    size: f64,
) -> i32 {
    root.estimate_text_size(t, &TextStyle::from(("sans-serif", size).into_font()))
        .map(|(w, _)| w as i32)
        // Without font metrics: DejaVu Sans averages about 0.62 em per character.
        .unwrap_or((t.chars().count() as f64 * 0.62 * size) as i32)
}

/// `t` shortened to fit `max_w` pixels: leading folders of a path are replaced by `…/` first
/// (the file name is kept), then the middle of the text is cut.
pub(crate) fn fit_text<DB: DrawingBackend>(
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

#[cfg(test)]
mod tests {
    use super::super::test_support::with_root;
    use super::super::Series;
    use super::*;

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
