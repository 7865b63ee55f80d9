//! The comparison's result types, computed by [`crate::pipeline::compare`], as the renderers
//! of `compare` and `demo` name them; and the number format of their prose.

pub use crate::pipeline::compare::*;

/// A number with 4 significant digits for prose (one definition, in the spectrum crate).
pub use bonnetlab_spectrum::fmt_sig;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn significant_digits() {
        assert_eq!(fmt_sig(0.0333333), "0.03333");
        assert_eq!(fmt_sig(143.426), "143.4");
        assert_eq!(fmt_sig(1.5), "1.500");
    }
}
