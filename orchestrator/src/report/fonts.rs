//! The one font of every picture the orchestrator draws.

use std::sync::OnceLock;

use plotters::style::FontStyle;

/// Family name the charts and maps ask for.
pub const FAMILY: &str = "sans-serif";

/// Registers the compiled-in DejaVu Sans once; returns the family name to draw with.
pub fn ensure() -> &'static str {
    static REGISTERED: OnceLock<()> = OnceLock::new();
    REGISTERED.get_or_init(|| {
        let ok = plotters::style::register_font(FAMILY, FontStyle::Normal, farm::font::FONT_TTF).is_ok();
        assert!(ok, "the bundled DejaVu Sans must parse");
    });
    FAMILY
}
