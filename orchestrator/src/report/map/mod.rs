//! Top-down maps of a room (like the trajectory figures 4.2 and 4.3 of the dissertation): floor,
//! walls and every object's footprint, with the reachable grid, the robot's path, the person,
//! the robot, the target instance, stops and intervention gestures drawn on top.
//!
//! The map looks down on the x–z plane with +x to the right and +z up the image, so a robot at
//! yaw 0 points up the page and yaw 90 points right. Everything is drawn at twice the output
//! resolution and averaged down, which smooths the edges of shapes that plotters' bitmap
//! backend draws without anti-aliasing. The font is compiled in, so machines without system
//! fonts draw the same picture.

mod footprint;
mod style;

use std::path::Path;

use image::RgbImage;
use nalgebra::Point3;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use worker::geometry::{Part, heading};
use worker::scene::Scene;

use footprint::footprint;
use style::{
    BACKGROUND, INK, INTERVENTION, Legend, OTHER, PATH, PERSON, REACHABLE, ROBOT, STOP, TARGET, WALL, display, font,
    lighten, octagon, scale, triangle,
};

/// Supersampling factor: drawn at this multiple of the output size, then averaged.
const SS: i32 = 2;
/// Space around the room (metres).
const MARGIN_M: f32 = 0.35;
/// Height of the title band and width of the legend panel (output pixels).
const TITLE_PX: i32 = 34;
const LEGEND_PX: i32 = 190;
/// Below and above these, a map would be illegible or absurdly large.
const MIN_PPM: f32 = 10.0;
const MAX_PPM: f32 = 400.0;

/// What plotters' drawing calls return; drawing into a memory buffer does not fail in practice.
type Drawn = Result<(), Box<dyn std::error::Error>>;

#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("{path}: cannot encode the map as PNG: {message}")]
    Encode { path: String, message: String },
    #[error("{path}: cannot write the map: {source}")]
    Write { path: String, source: std::io::Error },
}

/// A top-down picture of one scene that trajectories and markers are drawn onto.
pub struct TopDownMap {
    /// RGB pixels at `SS` times the output size.
    pixels: Vec<u8>,
    /// Supersampled canvas size.
    size: (u32, u32),
    /// Supersampled pixels per metre.
    ppm: f32,
    /// World x at the left edge and z at the top edge of the plot area.
    x_min: f32,
    z_max: f32,
    /// Centre and footprint radius (metres) of each scene object.
    objects: Vec<([f32; 2], f32)>,
    legend: Vec<Legend>,
    title: Option<String>,
}

impl TopDownMap {
    /// Draws the room: floor, walls, the footprint of every object (filled with its colour,
    /// outlined) and the category name of every target object. `pixels_per_metre` is clamped
    /// to 10..400.
    pub fn new(scene: &Scene, pixels_per_metre: f32) -> TopDownMap {
        let ppm_out = if pixels_per_metre.is_finite() { pixels_per_metre.clamp(MIN_PPM, MAX_PPM) } else { 80.0 };
        let (hx, hz) = scene.room.half();
        // extra walls may stick out of the room rectangle
        let (mut x0, mut x1, mut z0, mut z1) = (-hx, hx, -hz, hz);
        for w in &scene.walls {
            for p in [w.from, w.to] {
                x0 = x0.min(p[0]);
                x1 = x1.max(p[0]);
                z0 = z0.min(p[1]);
                z1 = z1.max(p[1]);
            }
        }
        let (x_min, x_max, z_min, z_max) = (x0 - MARGIN_M, x1 + MARGIN_M, z0 - MARGIN_M, z1 + MARGIN_M);
        let plot_w = ((x_max - x_min) * ppm_out).ceil() as i32;
        let plot_h = ((z_max - z_min) * ppm_out).ceil() as i32;
        let out_w = plot_w + LEGEND_PX;
        let out_h = (plot_h + TITLE_PX).max(TITLE_PX + 8 * 24);
        let size = ((out_w * SS) as u32, (out_h * SS) as u32);
        let mut map = TopDownMap {
            pixels: vec![0; size.0 as usize * size.1 as usize * 3],
            size,
            ppm: ppm_out * SS as f32,
            x_min,
            z_max,
            objects: Vec::new(),
            legend: Vec::new(),
            title: None,
        };
        map.draw_room(scene);
        map
    }

    /// Supersampled pixel of a world point (x, z).
    fn px(&self, x: f32, z: f32) -> (i32, i32) {
        (((x - self.x_min) * self.ppm).round() as i32, ((self.z_max - z) * self.ppm).round() as i32 + TITLE_PX * SS)
    }

    /// A length in metres as supersampled pixels.
    fn len(&self, metres: f32) -> i32 {
        (metres * self.ppm).round().max(1.0) as i32
    }

    fn with_area<F>(&mut self, f: F)
    where
        F: FnOnce(&DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Drawn,
    {
        let size = self.size;
        let area = BitMapBackend::with_buffer(&mut self.pixels, size).into_drawing_area();
        // drawing into an in-memory buffer with in-range coordinates does not fail
        f(&area).expect("drawing into the map buffer");
    }

    fn draw_room(&mut self, scene: &Scene) {
        font();
        let r = &scene.room;
        let (hx, hz) = r.half();
        let t = 0.1;
        let floor = lighten(display(r.floor.color), 0.45);
        let corners = |x0: f32, z0: f32, x1: f32, z1: f32, m: &TopDownMap| [m.px(x0, z1), m.px(x1, z0)];
        let floor_rect = corners(-hx, -hz, hx, hz, self);
        let walls = [
            corners(-hx - t, -hz - t, hx + t, -hz, self),
            corners(-hx - t, hz, hx + t, hz + t, self),
            corners(-hx - t, -hz, -hx, hz, self),
            corners(hx, -hz, hx + t, hz, self),
        ];
        let extra: Vec<Vec<(i32, i32)>> = scene
            .walls
            .iter()
            .map(|w| {
                let (a, b) = (nalgebra::Vector2::from(w.from), nalgebra::Vector2::from(w.to));
                let d = (b - a).normalize();
                let n = nalgebra::Vector2::new(-d.y, d.x) * (w.thickness / 2.0);
                [a + n, b + n, b - n, a - n].iter().map(|p| self.px(p.x, p.y)).collect()
            })
            .collect();
        let grid = self.metre_grid(hx, hz);
        let polys = self.footprints(scene);
        self.objects = scene
            .objects
            .iter()
            .map(|o| {
                let (w, d) = (o.size[0], o.size[2]);
                ([o.position[0], o.position[2]], 0.5 * (w * w + d * d).sqrt())
            })
            .collect();

        let line = SS as u32;
        self.with_area(|area| {
            area.fill(&BACKGROUND)?;
            area.draw(&Rectangle::new(floor_rect, floor.filled()))?;
            for g in &grid {
                area.draw(&PathElement::new(g.to_vec(), scale(floor, 0.92).stroke_width(line)))?;
            }
            for (poly, color) in &polys {
                area.draw(&Polygon::new(poly.clone(), color.filled()))?;
                let mut closed = poly.clone();
                closed.push(poly[0]);
                area.draw(&PathElement::new(closed, scale(*color, 0.55).stroke_width(line)))?;
            }
            for w in &walls {
                area.draw(&Rectangle::new(*w, WALL.filled()))?;
            }
            for poly in &extra {
                area.draw(&Polygon::new(poly.clone(), WALL.filled()))?;
            }
            Ok(())
        });
        self.draw_labels(scene);
        self.draw_scale_bar(hx, hz);
    }

    /// A line every metre, for scale.
    fn metre_grid(&self, hx: f32, hz: f32) -> Vec<[(i32, i32); 2]> {
        let mut grid = Vec::new();
        let mut x = (-hx).ceil();
        while x <= hx {
            grid.push([self.px(x, -hz), self.px(x, hz)]);
            x += 1.0;
        }
        let mut z = (-hz).ceil();
        while z <= hz {
            grid.push([self.px(-hx, z), self.px(hx, z)]);
            z += 1.0;
        }
        grid
    }

    /// Every part's footprint with its object's colour, lowest tops first so that what is on
    /// top stays visible.
    fn footprints(&self, scene: &Scene) -> Vec<(Vec<(i32, i32)>, RGBColor)> {
        let mut parts: Vec<(f32, usize, Part)> = Vec::new();
        for (i, o) in scene.objects.iter().enumerate() {
            for p in o.parts(i) {
                parts.push((p.aabb().1.y, i, p));
            }
        }
        parts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        parts
            .iter()
            .map(|(_, i, p)| {
                let poly = footprint(p).iter().map(|&(x, z)| self.px(x, z)).collect();
                (poly, display(scene.objects[*i].color))
            })
            .collect()
    }

    /// Category names of the target objects, nudged apart where they would overlap.
    fn draw_labels(&mut self, scene: &Scene) {
        let size = 11 * SS;
        let mut placed: Vec<(i32, i32, i32, i32)> = Vec::new();
        let mut labels = Vec::new();
        {
            let area = BitMapBackend::with_buffer(&mut self.pixels, self.size).into_drawing_area();
            let style = TextStyle::from((font(), size as f64).into_font());
            for o in scene.objects.iter().filter(|o| o.category.is_target()) {
                let name = o.category.name();
                let (tw, th) = area.estimate_text_size(name, &style).unwrap_or((name.len() as u32 * 6, 12));
                let (tw, th) = (tw as i32 + 4 * SS, th as i32 + 2 * SS);
                let (cx, cy) = (
                    ((o.position[0] - self.x_min) * self.ppm) as i32,
                    ((self.z_max - o.position[2]) * self.ppm) as i32 + TITLE_PX * SS,
                );
                // the first free spot near the object, else the one that overlaps least
                let (dx, dy) = (tw / 2 + 3 * SS, th + 2 * SS);
                let candidates = [
                    (0, 0),
                    (0, -dy),
                    (0, dy),
                    (dx, 0),
                    (-dx, 0),
                    (dx, -dy),
                    (-dx, -dy),
                    (dx, dy),
                    (-dx, dy),
                    (0, -2 * dy),
                    (0, 2 * dy),
                    (2 * dx, 0),
                    (-2 * dx, 0),
                ];
                let rect = |dx: i32, dy: i32| (cx + dx - tw / 2, cy + dy - th / 2, cx + dx + tw / 2, cy + dy + th / 2);
                let overlap = |r: (i32, i32, i32, i32)| -> i64 {
                    placed
                        .iter()
                        .map(|p| {
                            let w = (r.2.min(p.2) - r.0.max(p.0)).max(0) as i64;
                            let h = (r.3.min(p.3) - r.1.max(p.1)).max(0) as i64;
                            w * h
                        })
                        .sum()
                };
                let mut best = rect(0, 0);
                let mut best_cost = i64::MAX;
                for &(x, y) in &candidates {
                    let r = rect(x, y);
                    // keep a pixel of air between labels
                    let cost = overlap((r.0 - SS, r.1 - SS, r.2 + SS, r.3 + SS));
                    if cost < best_cost {
                        best = r;
                        best_cost = cost;
                    }
                    if cost == 0 {
                        break;
                    }
                }
                let r = best;
                placed.push(r);
                labels.push((r, name));
            }
        }
        self.with_area(|area| {
            let style = TextStyle::from((font(), size as f64).into_font())
                .color(&INK)
                .pos(Pos::new(HPos::Center, VPos::Center));
            for (r, name) in &labels {
                area.draw(&Rectangle::new([(r.0, r.1), (r.2, r.3)], WHITE.mix(0.78).filled()))?;
                area.draw(&Text::new(*name, ((r.0 + r.2) / 2, (r.1 + r.3) / 2), style.clone()))?;
            }
            Ok(())
        });
    }

    fn draw_scale_bar(&mut self, hx: f32, hz: f32) {
        let (x0, y) = self.px(-hx, -hz - MARGIN_M * 0.55);
        let x1 = x0 + self.len(1.0);
        let tick = 3 * SS;
        self.with_area(|area| {
            let s = INK.stroke_width(SS as u32);
            area.draw(&PathElement::new(vec![(x0, y), (x1, y)], s))?;
            area.draw(&PathElement::new(vec![(x0, y - tick), (x0, y + tick)], s))?;
            area.draw(&PathElement::new(vec![(x1, y - tick), (x1, y + tick)], s))?;
            let style = TextStyle::from((font(), (10 * SS) as f64).into_font())
                .color(&INK)
                .pos(Pos::new(HPos::Left, VPos::Center));
            area.draw(&Text::new("1 m", (x1 + 4 * SS, y), style))?;
            Ok(())
        });
    }

    fn note(&mut self, what: Legend) {
        if !self.legend.contains(&what) {
            self.legend.push(what);
        }
    }

    /// Small dots at the reachable grid positions (x, z).
    pub fn reachable(&mut self, points: &[[f32; 2]]) -> &mut Self {
        let dots: Vec<(i32, i32)> = points.iter().map(|p| self.px(p[0], p[1])).collect();
        self.with_area(|area| {
            for &d in &dots {
                area.draw(&Circle::new(d, 2 * SS, REACHABLE.filled()))?;
            }
            Ok(())
        });
        self.note(Legend::Reachable);
        self
    }

    /// The robot's path through positions (x, z), with a dot at each step.
    pub fn path(&mut self, points: &[[f32; 2]]) -> &mut Self {
        let pts: Vec<(i32, i32)> = points.iter().map(|p| self.px(p[0], p[1])).collect();
        self.with_area(|area| {
            if pts.len() >= 2 {
                area.draw(&PathElement::new(pts.clone(), PATH.mix(0.85).stroke_width(3 * SS as u32)))?;
            }
            for &p in &pts {
                area.draw(&Circle::new(p, 2 * SS, PATH.filled()))?;
            }
            Ok(())
        });
        self.note(Legend::Path);
        self
    }

    /// A disc with an arrow along the heading of `yaw_deg`.
    fn agent(&mut self, pos: [f32; 2], yaw_deg: f32, radius_m: f32, color: RGBColor) {
        let c = self.px(pos[0], pos[1]);
        let r = self.len(radius_m);
        let h = heading(yaw_deg);
        let tip_m = radius_m + 0.2;
        let tip = self.px(pos[0] + h.x * tip_m, pos[1] + h.y * tip_m);
        // arrow head: two points behind the tip, either side of the heading
        let side = |s: f32| {
            let back = tip_m - 0.14;
            self.px(pos[0] + h.x * back + h.y * s * 0.09, pos[1] + h.y * back - h.x * s * 0.09)
        };
        let (l, rt) = (side(1.0), side(-1.0));
        let rim = self.px(pos[0] + h.x * radius_m, pos[1] + h.y * radius_m);
        self.with_area(|area| {
            area.draw(&Circle::new(c, r, color.mix(0.9).filled()))?;
            area.draw(&Circle::new(c, r, WHITE.stroke_width(SS as u32)))?;
            // a white shaft from the centre, the coloured head beyond the disc
            area.draw(&PathElement::new(vec![c, rim], WHITE.stroke_width(2 * SS as u32)))?;
            area.draw(&Polygon::new(vec![tip, l, rt], scale(color, 0.8).filled()))?;
            Ok(())
        });
    }

    /// The person: a disc and an arrow where they face.
    pub fn person(&mut self, pos: [f32; 2], yaw_deg: f32) -> &mut Self {
        self.agent(pos, yaw_deg, 0.2, PERSON);
        self.note(Legend::Person);
        self
    }

    /// The robot: a disc of its radius (0.3 m, §3.2.2) and an arrow along its heading.
    pub fn robot(&mut self, pos: [f32; 2], yaw_deg: f32) -> &mut Self {
        self.agent(pos, yaw_deg, 0.3, ROBOT);
        self.note(Legend::Robot);
        self
    }

    fn ring_radius(&self, object: usize) -> Option<((i32, i32), i32)> {
        let (c, r) = *self.objects.get(object)?;
        Some((self.px(c[0], c[1]), self.len(r.max(0.15) + 0.12)))
    }

    /// A bold ring around the target instance (an index into `Scene::objects`).
    pub fn target(&mut self, object: usize) -> &mut Self {
        if let Some((c, r)) = self.ring_radius(object) {
            self.with_area(|area| {
                area.draw(&Circle::new(c, r, WHITE.stroke_width(6 * SS as u32)))?;
                area.draw(&Circle::new(c, r, TARGET.stroke_width(3 * SS as u32)))?;
                Ok(())
            });
            self.note(Legend::Target);
        }
        self
    }

    /// Dashed rings around other instances of the target's category.
    pub fn other_instances(&mut self, objects: &[usize]) -> &mut Self {
        let rings: Vec<((i32, i32), i32)> = objects.iter().filter_map(|&o| self.ring_radius(o)).collect();
        if rings.is_empty() {
            return self;
        }
        self.with_area(|area| {
            for &(c, r) in &rings {
                let n = 48;
                let pts: Vec<(i32, i32)> = (0..=n)
                    .map(|k| {
                        let a = std::f32::consts::TAU * k as f32 / n as f32;
                        (c.0 + (r as f32 * a.cos()).round() as i32, c.1 + (r as f32 * a.sin()).round() as i32)
                    })
                    .collect();
                area.draw(&DashedPathElement::new(pts, 5 * SS, 4 * SS, OTHER.stroke_width(2 * SS as u32)))?;
            }
            Ok(())
        });
        self.note(Legend::OtherInstance);
        self
    }

    /// Octagons where the robot issued Stop.
    pub fn stops(&mut self, points: &[[f32; 2]]) -> &mut Self {
        let centers: Vec<(i32, i32)> = points.iter().map(|p| self.px(p[0], p[1])).collect();
        self.with_area(|area| {
            for &c in &centers {
                let oct = octagon(c, 7 * SS);
                area.draw(&Polygon::new(oct.clone(), STOP.filled()))?;
                let mut closed = oct.clone();
                closed.push(oct[0]);
                area.draw(&PathElement::new(closed, WHITE.stroke_width(SS as u32)))?;
            }
            Ok(())
        });
        self.note(Legend::Stop);
        self
    }

    /// Triangles at the robot's positions on steps where an intervention gesture was shown.
    pub fn interventions(&mut self, points: &[[f32; 2]]) -> &mut Self {
        let centers: Vec<(i32, i32)> = points.iter().map(|p| self.px(p[0], p[1])).collect();
        self.with_area(|area| {
            for &c in &centers {
                let tri = triangle(c, 7 * SS);
                area.draw(&Polygon::new(tri.clone(), INTERVENTION.filled()))?;
                let mut closed = tri.clone();
                closed.push(tri[0]);
                area.draw(&PathElement::new(closed, scale(INTERVENTION, 0.6).stroke_width(SS as u32)))?;
            }
            Ok(())
        });
        self.note(Legend::Intervention);
        self
    }

    /// The line of text above the map.
    pub fn title(&mut self, text: &str) -> &mut Self {
        self.title = Some(text.to_string());
        self
    }

    /// The finished picture: the map with its title and legend, at the output resolution.
    pub fn to_rgb_image(&self) -> RgbImage {
        let mut pixels = self.pixels.clone();
        {
            let area = BitMapBackend::with_buffer(&mut pixels, self.size).into_drawing_area();
            self.draw_decorations(&area).expect("drawing into the map buffer");
        }
        downsample(&pixels, self.size, SS as u32)
    }

    fn draw_decorations(&self, area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Drawn {
        let f = font();
        if let Some(t) = &self.title {
            let style =
                TextStyle::from((f, (15 * SS) as f64).into_font()).color(&INK).pos(Pos::new(HPos::Left, VPos::Center));
            area.draw(&Text::new(t.as_str(), (10 * SS, TITLE_PX * SS / 2), style))?;
        }
        let x = self.size.0 as i32 - LEGEND_PX * SS + 12 * SS;
        let mut y = TITLE_PX * SS + 16 * SS;
        let text =
            TextStyle::from((f, (11 * SS) as f64).into_font()).color(&INK).pos(Pos::new(HPos::Left, VPos::Center));
        let row = 22 * SS;
        for item in &self.legend {
            let c = (x + 9 * SS, y);
            match item {
                Legend::Reachable => area.draw(&Circle::new(c, 2 * SS, REACHABLE.filled()))?,
                Legend::Path => {
                    area.draw(&PathElement::new(vec![(x, y), (x + 18 * SS, y)], PATH.stroke_width(3 * SS as u32)))?
                }
                Legend::Person => area.draw(&Circle::new(c, 6 * SS, PERSON.filled()))?,
                Legend::Robot => area.draw(&Circle::new(c, 8 * SS, ROBOT.filled()))?,
                Legend::Target => area.draw(&Circle::new(c, 7 * SS, TARGET.stroke_width(3 * SS as u32)))?,
                Legend::OtherInstance => area.draw(&Circle::new(c, 7 * SS, OTHER.stroke_width(2 * SS as u32)))?,
                Legend::Stop => area.draw(&Polygon::new(octagon(c, 7 * SS), STOP.filled()))?,
                Legend::Intervention => area.draw(&Polygon::new(triangle(c, 7 * SS), INTERVENTION.filled()))?,
            }
            area.draw(&Text::new(item.label(), (x + 26 * SS, y), text.clone()))?;
            y += row;
        }
        Ok(())
    }

    /// Writes the finished picture as a PNG (atomically).
    pub fn save_png(&self, path: &Path) -> Result<(), MapError> {
        let img = self.to_rgb_image();
        let mut bytes = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
            .map_err(|e| MapError::Encode { path: path.display().to_string(), message: e.to_string() })?;
        farm::files::write_atomic(path, &bytes)
            .map_err(|source| MapError::Write { path: path.display().to_string(), source })
    }

    /// Output size in pixels (width, height).
    pub fn dimensions(&self) -> (u32, u32) {
        (self.size.0 / SS as u32, self.size.1 / SS as u32)
    }

    /// Where world points land in the output image, as an affine map of (x, z) in metres:
    /// column = a·x + b·z + c, row = d·x + e·z + f, returned as [a, b, c, d, e, f].
    pub fn transform(&self) -> [f32; 6] {
        let k = self.ppm / SS as f32;
        [k, 0.0, -self.x_min * k, 0.0, -k, self.z_max * k + TITLE_PX as f32]
    }

    /// Where a world point (x, z) lands in the output image (column, row).
    pub fn pixel_of(&self, x: f32, z: f32) -> (u32, u32) {
        let (px, py) = self.px(x, z);
        ((px / SS).max(0) as u32, (py / SS).max(0) as u32)
    }
}

/// Averages `k`×`k` blocks of an RGB buffer.
fn downsample(pixels: &[u8], (w, h): (u32, u32), k: u32) -> RgbImage {
    let (ow, oh) = (w / k, h / k);
    let mut out = RgbImage::new(ow, oh);
    let n = k * k;
    for y in 0..oh {
        for x in 0..ow {
            let mut acc = [0u32; 3];
            for dy in 0..k {
                let row = ((y * k + dy) * w + x * k) as usize * 3;
                for dx in 0..k as usize {
                    for c in 0..3 {
                        acc[c] += pixels[row + dx * 3 + c] as u32;
                    }
                }
            }
            out.put_pixel(
                x,
                y,
                image::Rgb([((acc[0] + n / 2) / n) as u8, ((acc[1] + n / 2) / n) as u8, ((acc[2] + n / 2) / n) as u8]),
            );
        }
    }
    out
}

/// The world position (x, z) of a 3D point, for callers holding `Point3`s.
pub fn xz(p: &Point3<f32>) -> [f32; 2] {
    [p.x, p.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use worker::render::benchmark_room;
    use worker::scene::Category;

    #[test]
    fn map_png_shows_the_room_and_its_objects() {
        let scene = benchmark_room();
        let mut map = TopDownMap::new(&scene, 80.0);
        let reachable: Vec<[f32; 2]> = (0..24)
            .flat_map(|i| (0..20).map(move |j| [-2.875 + 0.25 * i as f32, -2.375 + 0.25 * j as f32]))
            .filter(|p| p[0].abs() < 1.0 || p[1] > 0.0)
            .collect();
        let path = [[-0.5, 0.6], [-0.5, 0.35], [-0.25, 0.1], [0.0, -0.15], [0.25, -0.15], [0.5, -0.15]];
        let laptop = scene.instances(Category::Laptop).next().unwrap();
        let plates: Vec<usize> = scene.instances(Category::Plate).collect();
        map.title("FloorPlan test · Laptop · success")
            .reachable(&reachable)
            .path(&path)
            .person([-1.0, -0.3], 120.0)
            .robot([0.5, -0.15], 90.0)
            .target(laptop)
            .other_instances(&plates)
            .stops(&[[0.5, -0.15]])
            .interventions(&[[-0.5, 0.6], [-0.5, 0.35]]);
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("map.png");
        map.save_png(&file).unwrap();
        if let Ok(keep) = std::env::var("GESTHOR_MAP_DUMP") {
            std::fs::copy(&file, keep).unwrap();
        }

        let img = image::open(&file).unwrap().to_rgb8();
        // 6.7 m × 5.7 m of plot at 80 px/m, the title band and the legend panel
        assert_eq!(img.dimensions(), map.dimensions());
        assert_eq!(img.width(), (6.7f32 * 80.0).ceil() as u32 + LEGEND_PX as u32);
        assert_eq!(img.height(), (5.7f32 * 80.0).ceil() as u32 + TITLE_PX as u32);

        let close = |a: image::Rgb<u8>, b: RGBColor| {
            (a.0[0] as i32 - b.0 as i32).abs() <= 3
                && (a.0[1] as i32 - b.1 as i32).abs() <= 3
                && (a.0[2] as i32 - b.2 as i32).abs() <= 3
        };
        let count = |c: RGBColor| img.pixels().filter(|p| close(**p, c)).count();
        // the blue sofa, the red armchair and the walls are there in their colours
        let sofa = display(scene.objects[0].color);
        let armchair = display(scene.objects[2].color);
        assert!(count(sofa) > 1000, "sofa pixels: {}", count(sofa));
        assert!(count(armchair) > 500, "armchair pixels: {}", count(armchair));
        assert!(count(WALL) > 1000);
        // the sofa stands at the back wall (−z), which is at the bottom of the image
        let (_, sofa_row) = map.pixel_of(0.0, -2.05);
        let (_, table_row) = map.pixel_of(1.0, 1.1);
        assert!(sofa_row > table_row);
        assert!(close(*img.get_pixel(map.pixel_of(0.0, -1.95).0, sofa_row), sofa) || count(sofa) > 0);
        // the robot and the markers are drawn
        assert!(count(ROBOT) > 100 && count(PERSON) > 50 && count(STOP) > 20 && count(INTERVENTION) > 20);
    }

    #[test]
    fn odd_scales_are_clamped() {
        let scene = benchmark_room();
        let small = TopDownMap::new(&scene, 0.0);
        let nan = TopDownMap::new(&scene, f32::NAN);
        assert!(small.dimensions().0 >= (6.7 * MIN_PPM) as u32);
        assert!(nan.dimensions().0 > 0);
    }
}
