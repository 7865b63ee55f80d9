//! The commanded raster path of a synthetic run: lines along X stepped by the pitch along Y,
//! bidirectional, with over-travel, logged at a fixed rate. The feed along each line realises a
//! dwell-per-area map derived from the surface (slow where there is more to remove):
//! `dwell_per_area = 1 / (feed * pitch)`.

use crate::path::PathLog;

pub struct RasterPlan {
    pub x_min_mm: f64,
    pub x_max_mm: f64,
    pub y_min_mm: f64,
    pub y_max_mm: f64,
    pub pitch_mm: f64,
    pub sample_hz: f64,
}

/// Generates the commanded log; `feed_at(x, y)` gives the feed (mm/s, > 0) at a point.
pub fn raster(plan: &RasterPlan, feed_at: impl Fn(f64, f64) -> f64) -> PathLog {
    let dt = 1.0 / plan.sample_hz;
    let (mut t, mut xs, mut ys) = (vec![0.0], vec![plan.x_min_mm], vec![plan.y_min_mm]);
    let mut y = plan.y_min_mm;
    let mut forward = true;
    let mut now = 0.0;
    loop {
        // One line: integrate x' = +-feed(x, y) with midpoint steps of dt.
        let (x_end, sgn) = if forward {
            (plan.x_max_mm, 1.0)
        } else {
            (plan.x_min_mm, -1.0)
        };
        let mut x = *xs.last().unwrap_or(&plan.x_min_mm);
        loop {
            let v1 = feed_at(x, y).max(1e-3);
            let xm = x + sgn * 0.5 * dt * v1;
            let step = dt * feed_at(xm, y).max(1e-3);
            let remaining = (x_end - x) * sgn;
            if step >= remaining {
                let frac = remaining / step;
                now += frac * dt;
                x = x_end;
                t.push(now);
                xs.push(x);
                ys.push(y);
                break;
            }
            x += sgn * step;
            now += dt;
            t.push(now);
            xs.push(x);
            ys.push(y);
        }
        if y + plan.pitch_mm > plan.y_max_mm + 1e-9 {
            break;
        }
        // Step over to the next line at the feed of the line end.
        let v = feed_at(x, y).max(1e-3);
        let n = ((plan.pitch_mm / v) / dt).ceil().max(1.0) as usize;
        for k in 1..=n {
            now += plan.pitch_mm / v / n as f64;
            t.push(now);
            xs.push(x);
            ys.push(y + plan.pitch_mm * k as f64 / n as f64);
        }
        y += plan.pitch_mm;
        forward = !forward;
    }
    PathLog {
        t_s: t,
        x_mm: xs,
        y_mm: ys,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_feed_line_takes_length_over_feed() {
        let plan = RasterPlan {
            x_min_mm: 0.0,
            x_max_mm: 10.0,
            y_min_mm: 0.0,
            y_max_mm: 2.0,
            pitch_mm: 1.0,
            sample_hz: 10.0,
        };
        let p = raster(&plan, |_, _| 2.0);
        // 3 lines of 10 mm + 2 step-overs of 1 mm at 2 mm/s
        assert!(
            (p.duration_s() - (30.0 + 2.0) / 2.0).abs() < 1e-9,
            "{}",
            p.duration_s()
        );
        assert!((p.y_mm.last().unwrap() - 2.0).abs() < 1e-12);
        assert!((p.x_mm.last().unwrap() - 10.0).abs() < 1e-12);
    }
}
