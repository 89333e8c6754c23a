//! How a map looks: its colours, the font, the glyphs of stops and interventions, and what the
//! legend can explain.

use plotters::style::RGBColor;

// The palette: the room's own colours come from the scene (`display`), these from the map.
pub(super) const BACKGROUND: RGBColor = RGBColor(246, 246, 244);
pub(super) const WALL: RGBColor = RGBColor(70, 70, 74);
pub(super) const INK: RGBColor = RGBColor(30, 30, 34);
pub(super) const REACHABLE: RGBColor = RGBColor(150, 156, 170);
pub(super) const PATH: RGBColor = RGBColor(122, 38, 160);
pub(super) const PERSON: RGBColor = RGBColor(30, 150, 70);
pub(super) const ROBOT: RGBColor = RGBColor(25, 95, 215);
pub(super) const TARGET: RGBColor = RGBColor(220, 30, 40);
pub(super) const OTHER: RGBColor = RGBColor(235, 120, 20);
pub(super) const STOP: RGBColor = RGBColor(200, 20, 30);
pub(super) const INTERVENTION: RGBColor = RGBColor(245, 170, 0);

/// What the legend explains; each kind appears once, in the order first drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Legend {
    Reachable,
    Path,
    Person,
    Robot,
    Target,
    OtherInstance,
    Stop,
    Intervention,
}

impl Legend {
    pub(super) fn label(self) -> &'static str {
        match self {
            Legend::Reachable => "reachable position",
            Legend::Path => "robot path",
            Legend::Person => "person",
            Legend::Robot => "robot",
            Legend::Target => "target instance",
            Legend::OtherInstance => "same category",
            Legend::Stop => "stop",
            Legend::Intervention => "intervention gesture",
        }
    }
}

pub(super) fn font() -> &'static str {
    crate::report::fonts::ensure()
}

/// Linear RGB 0..1 → a display colour (the renderer's gamma 2.2).
pub(super) fn display(c: [f32; 3]) -> RGBColor {
    let f = |v: f32| (v.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0 + 0.5) as u8;
    RGBColor(f(c[0]), f(c[1]), f(c[2]))
}

pub(super) fn scale(c: RGBColor, k: f32) -> RGBColor {
    let f = |v: u8| (v as f32 * k).clamp(0.0, 255.0) as u8;
    RGBColor(f(c.0), f(c.1), f(c.2))
}

pub(super) fn lighten(c: RGBColor, k: f32) -> RGBColor {
    let f = |v: u8| (v as f32 + (255.0 - v as f32) * k) as u8;
    RGBColor(f(c.0), f(c.1), f(c.2))
}

/// A stop's glyph: an octagon of radius `r` around `c` (pixels).
pub(super) fn octagon(c: (i32, i32), r: i32) -> Vec<(i32, i32)> {
    (0..8)
        .map(|k| {
            let a = std::f32::consts::TAU * (k as f32 + 0.5) / 8.0;
            (c.0 + (r as f32 * a.cos()).round() as i32, c.1 + (r as f32 * a.sin()).round() as i32)
        })
        .collect()
}

/// An intervention's glyph: a triangle pointing up, of radius `r` around `c` (pixels).
pub(super) fn triangle(c: (i32, i32), r: i32) -> Vec<(i32, i32)> {
    let h = (r as f32 * 0.87).round() as i32;
    vec![(c.0, c.1 - r), (c.0 + h, c.1 + r / 2), (c.0 - h, c.1 + r / 2)]
}
