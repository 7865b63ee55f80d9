//! Numbers for people: a value printed to the precision it carries, not the digits of its
//! binary representation (a MetroPro pixel size stored as f32 0.4 prints as `0.4`, not
//! `0.39999998989515007`, and 1e300 as `1e300`, not 301 digits). JSON keeps full precision; only
//! human-facing text (terminal, HTML, error messages) goes through here. The one formatter of
//! the workspace: `bonnetlab::report::format` re-exports it and the spectrum crate's reasons use it.

/// `v` with at most `sig` significant digits, trailing zeros dropped; scientific notation
/// outside [1e-4, 1e7). Non-finite values print as `NaN`, `inf`, `-inf`.
pub fn sig(v: f64, sig: usize) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".into();
    }
    let sig = sig.clamp(1, 17);
    let a = v.abs();
    if !(1e-4..1e7).contains(&a) {
        let s = format!("{:.*e}", sig - 1, v);
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = trim(m);
        return format!("{m}e{e}");
    }
    let mag = a.log10().floor() as i32;
    let decimals = (sig as i32 - 1 - mag).max(0) as usize;
    if mag + 1 > sig as i32 {
        let q = 10f64.powi(mag + 1 - sig as i32);
        return format!("{:.0}", (v / q).round() * q);
    }
    let s = format!("{v:.decimals$}");
    // Rounding can carry into a new digit (9.99996 -> 10.0000): one digit fewer then.
    let s = if s
        .trim_start_matches('-')
        .trim_start_matches('0')
        .starts_with('.')
    {
        s
    } else {
        let digits = s.chars().filter(char::is_ascii_digit).count();
        if digits > sig && decimals > 0 {
            format!("{v:.*}", decimals - 1)
        } else {
            s
        }
    };
    trim(&s)
}

/// `v` with `decimals` digits after the point, as `{v:.decimals$}` prints it, for table cells
/// and summaries of ordinary magnitudes; from 1e7 up, [`sig`] with four significant digits
/// (`1e300`, never 301 digits). Non-finite values print as `NaN`, `inf`, `-inf`.
pub fn fixed(v: f64, decimals: usize) -> String {
    if v.is_finite() && v.abs() < 1e7 {
        format!("{v:.decimals$}")
    } else {
        sig(v, 4)
    }
}

/// A length that came from a single-precision field (a pixel size): 7 significant digits.
pub fn f32_value(v: f64) -> String {
    sig(v, 7)
}

fn trim(s: &str) -> String {
    if s.contains('.') {
        let t = s.trim_end_matches('0').trim_end_matches('.');
        if t == "-0" {
            "0".into()
        } else {
            t.to_string()
        }
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_precision_artefacts_are_gone() {
        assert_eq!(f32_value(f64::from(0.4f32)), "0.4");
        assert_eq!(f32_value(f64::from(1.25f32)), "1.25");
        assert_eq!(f32_value(f64::from(0.000_245_677_f32)), "0.000245677");
        assert_eq!(sig(1.250_000_031_577_656_7, 7), "1.25");
    }

    #[test]
    fn significant_digits_and_edges() {
        assert_eq!(sig(143.426_01, 6), "143.426");
        assert_eq!(sig(-0.0, 4), "0");
        assert_eq!(sig(9.999_96, 5), "10");
        assert_eq!(sig(123_456.7, 3), "123000");
        assert_eq!(sig(2.5e-6, 3), "2.5e-6");
        assert_eq!(sig(f64::NAN, 3), "NaN");
        assert_eq!(sig(1000.0, 4), "1000");
        assert_eq!(sig(1e300, 4), "1e300");
        assert_eq!(sig(-1e-300, 4), "-1e-300");
    }

    #[test]
    fn fixed_decimals_never_print_hundreds_of_digits() {
        assert_eq!(fixed(0.123456, 3), "0.123");
        assert_eq!(fixed(1e300, 3), "1e300");
        assert_eq!(fixed(-2.5e12, 1), "-2.5e12");
        assert!(fixed(1e-300, 3).len() <= 6);
    }
}
