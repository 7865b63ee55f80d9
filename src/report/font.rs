//! The one font every plot uses: DejaVu Sans, embedded in the binary and registered with
//! plotters' `ab_glyph` text renderer once per process.
//!
//! plotters is built without system-font support (no fontconfig / freetype), so without this
//! registration every text draw fails with `FontUnavailable` (see `shared/spec/crates.md`).
//! The font is registered under the generic family names plotters asks for, so any style a
//! plot requests resolves to it.

use std::sync::OnceLock;

use plotters::style::FontStyle;

/// DejaVu Sans (licence in `assets/fonts/DejaVuSans.LICENSE`).
static DEJAVU_SANS: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

static REGISTERED: OnceLock<bool> = OnceLock::new();

/// Registers the embedded font; returns `false` when the font bytes were rejected (which
/// would be a build defect, reported as a plot error rather than a panic).
pub fn ensure_registered() -> bool {
    *REGISTERED.get_or_init(|| {
        ["sans-serif", "serif", "monospace", "DejaVu Sans"]
            .iter()
            .all(|family| {
                plotters::style::register_font(family, FontStyle::Normal, DEJAVU_SANS).is_ok()
            })
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn embedded_font_registers() {
        assert!(super::ensure_registered());
        assert!(
            super::ensure_registered(),
            "second call must be a cheap no-op that still succeeds"
        );
    }
}
