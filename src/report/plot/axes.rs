//! Axis ranges, tick positions and tick labels.

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};

use super::Scale;
use crate::report::format;

/// An axis whose labelled ticks and light grid lines are given (see [`ticks`]).
pub(crate) struct Ticked<R: Ranged<ValueType = f64>> {
    pub(crate) inner: R,
    pub(crate) bold: Vec<f64>,
    pub(crate) light: Vec<f64>,
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

/// Labelled ticks (and light grid lines) for an axis `len_px` long. Linear axes step by 1, 2
/// or 5 x 10^k; logarithmic axes label 1 x 10^k, or 1, 2, 5 x 10^k, or every integer
/// multiple, whichever is the densest whose labels do not touch (the x axis measures its
/// labels; the y axis needs 18 px per label), and fall back to linear steps inside a
/// range narrower than that.
pub(crate) fn ticks(
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

pub(crate) fn ok_on(v: f64, scale: Scale) -> bool {
    v.is_finite() && (scale == Scale::Linear || v > 0.0)
}

/// Axis range covering the values with a small margin; a sane default when there are none.
pub(crate) fn axis_range(values: impl Iterator<Item = f64>, scale: Scale) -> (f64, f64) {
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

/// Compact tick label: the value to six significant digits in [1e-3, 1e5) (through
/// [`format::sig`], so `0.1 + 0.2` prints `0.3` and `0.00125` keeps its last digit), scientific
/// with up to three significant digits outside it (`1e-5`, `2.5e6`).
pub fn fmt_tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { format!("{v}") };
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.2e}");
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = m.trim_end_matches('0').trim_end_matches('.');
        return format!("{m}e{e}");
    }
    format::sig(v, 6)
}

#[cfg(test)]
mod tests {
    use super::super::layout::{text_width, TICK_FONT};
    use super::super::test_support::with_root;
    use super::*;

    #[test]
    fn tick_labels_are_compact() {
        assert_eq!(fmt_tick(0.1), "0.1");
        assert_eq!(fmt_tick(100.0), "100");
        assert_eq!(fmt_tick(1e-5), "1e-5");
        assert_eq!(fmt_tick(2.5e6), "2.5e6");
        assert_eq!(fmt_tick(0.0), "0");
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

    /// Tick labels carry their value: no two ticks of an axis share a label, and every label
    /// reads back as its tick (old: `{:.4}` printed 0.00101 and 0.00102 both as "0.001", and
    /// scientific labels kept one decimal, 1.25e-5 as "1.2e-5").
    #[test]
    fn tick_labels_are_distinct_and_exact() {
        assert_eq!(fmt_tick(0.1 + 0.2), "0.3");
        assert_eq!(fmt_tick(0.00125), "0.00125");
        assert_eq!(fmt_tick(1.25e-5), "1.25e-5");
        assert_eq!(fmt_tick(-2e6), "-2e6");
        with_root(|root| {
            let measure = |t: &str| text_width(root, t, TICK_FONT);
            let cases = [
                ((0.001, 0.0011), Scale::Linear),
                ((1000.0, 1000.5), Scale::Linear),
                ((0.1, 0.7), Scale::Linear),
                ((-3e-3, 2e-3), Scale::Linear),
                ((1e-6, 3e-6), Scale::Linear),
                ((2.0e4, 2.0006e4), Scale::Linear),
                ((1e-5, 1e-3), Scale::Log),
                ((0.02, 1.3), Scale::Log),
                ((3e3, 8e5), Scale::Log),
                ((1.2e-5, 3.3e-5), Scale::Log),
            ];
            for (r, scale) in cases {
                for horizontal in [true, false] {
                    let (t, _) = ticks(r, scale, 600.0, horizontal, &measure);
                    let labels: Vec<String> = t.iter().map(|&v| fmt_tick(v)).collect();
                    let mut unique = labels.clone();
                    unique.sort();
                    unique.dedup();
                    assert_eq!(unique.len(), labels.len(), "{r:?} {scale:?}: {labels:?}");
                    for (v, l) in t.iter().zip(&labels) {
                        let back: f64 = l.parse().unwrap();
                        let tol = 1e-6 * (r.1 - r.0).abs().max(v.abs() * 1e-3);
                        assert!((back - v).abs() <= tol, "{r:?}: tick {v} labelled {l}");
                    }
                }
            }
        });
    }
}
