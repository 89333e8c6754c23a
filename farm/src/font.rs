//! The one compiled-in font: plots (learner, orchestrator) and maps draw the same text on
//! machines without system fonts.

/// DejaVu Sans (Bitstream Vera licence, `farm/assets/DejaVuSans-LICENSE.txt`).
pub const FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
