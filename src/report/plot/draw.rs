//! Drawing a line plot into a plotters area: title, mesh with the given ticks, marker lines
//! and labels, the curves (solid or dashed) and the legend with each curve's line style.

use plotters::coord::combinators::LogCoord;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::axes::{axis_range, fmt_tick, ok_on, ticks, Ticked};
use super::layout::{
    text_width, Layout, LEGEND_FONT, LEGEND_PAD, LEGEND_ROW, LEGEND_SAMPLE, MARGIN, MARKER_FONT,
    MARKER_ROW, TICK_FONT, TITLE_FONT, X_LABEL_AREA, Y_LABEL_AREA,
};
use super::{LinePlot, LineStyle, PlotError, Scale, Series, PALETTE};

impl LinePlot {
    /// Points of a series that can be shown on the plot's axes.
    fn drawable(&self, s: &Series) -> Vec<(f64, f64)> {
        s.x.iter()
            .zip(&s.y)
            .map(|(&x, &y)| (x, y))
            .filter(|&(x, y)| ok_on(x, self.x_scale) && ok_on(y, self.y_scale))
            .collect()
    }

    pub(crate) fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), PlotError> {
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
