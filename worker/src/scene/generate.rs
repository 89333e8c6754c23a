//! Procedural rooms: 30 per scene type, deterministic from a seed.
//!
//! Each type has a recipe of what stands where: furniture against walls (counters, beds,
//! sofas), free-standing furniture in the middle (tables with chairs), surface items on hosts
//! (cups on counters, laptops on desks), wall items (windows, posters, towel holders) and
//! things hanging on holders. Sizes, colours, styles, positions and which optional pieces
//! appear vary per room; some categories appear several times. A layout is kept only if the
//! robot can move around it (one large connected free area), otherwise the next attempt is
//! drawn from the same seed stream.

use nalgebra::{Point2, Vector2};
use rand::Rng;
use rand::seq::IndexedRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{Category, Object, Room, Scene, SceneId, SceneType, Surface};
use crate::geometry::{Material, heading};
use crate::nav::{GRID_STEP, NavGrid};
use crate::physics::{Physics, RobotBody};
use farm::seed;

mod furnish;

/// Stream key of scene generation (`seed::rng(seed, &[SCENE_KEY, floorplan, attempt])`).
const SCENE_KEY: u64 = 0x5C3E_0001;

/// Generates all 120 rooms in parallel; the result does not depend on the thread count.
pub fn generate_all(seed: u64) -> Vec<Scene> {
    let ids: Vec<SceneId> = SceneId::all().collect();
    ids.par_iter().map(|&id| generate(id, seed)).collect()
}

/// Generates one room.
pub fn generate(id: SceneId, seed: u64) -> Scene {
    for attempt in 0..64u64 {
        let mut rng = seed::rng(seed, &[SCENE_KEY, id.floorplan() as u64, attempt]);
        let scene = layout(id, seed, &mut rng);
        if navigable(&scene) {
            return scene;
        }
    }
    panic!("no navigable layout for {} in 64 attempts (seed {seed})", id.name());
}

/// The free floor must be mostly one connected area, large enough to walk around in.
fn navigable(scene: &Scene) -> bool {
    let physics = Physics::new(&scene.parts(), RobotBody::default());
    let grid = NavGrid::build(&physics, &scene.room, GRID_STEP);
    let (label, largest) = grid.components();
    let Some(l) = largest else { return false };
    let free = grid.free_cells().count();
    let main = label.iter().filter(|&&x| x == l).count();
    let area = scene.room.width * scene.room.depth;
    main as f32 >= 0.85 * free as f32 && main as f32 * GRID_STEP * GRID_STEP >= 0.25 * area
}

/// A wall of the rectangular room: 0 back (z = −d/2), 1 right (x = +w/2), 2 front, 3 left.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Wall(u8);

impl Wall {
    const ALL: [Wall; 4] = [Wall(0), Wall(1), Wall(2), Wall(3)];
    /// Yaw of something standing against this wall and facing into the room.
    fn yaw(self) -> f32 {
        [0.0, 270.0, 180.0, 90.0][self.0 as usize]
    }
    fn length(self, room: &Room) -> f32 {
        if self.0 % 2 == 0 { room.width } else { room.depth }
    }
    fn half_span(self, room: &Room) -> f32 {
        if self.0 % 2 == 0 { room.depth / 2.0 } else { room.width / 2.0 }
    }
    /// Floor point at `off` metres out from the wall and `u` along it (u grows to the right
    /// of someone standing at the wall facing into the room).
    fn point(self, room: &Room, u: f32, off: f32) -> Point2<f32> {
        let n = heading(self.yaw());
        let t = Vector2::new(n.y, -n.x);
        let c = -n * self.half_span(room);
        Point2::from(c + n * off + t * u)
    }
    fn adjacent(self) -> [Wall; 2] {
        [Wall((self.0 + 1) % 4), Wall((self.0 + 3) % 4)]
    }
    fn opposite(self) -> Wall {
        Wall((self.0 + 2) % 4)
    }
}

/// An axis-aligned footprint on the floor (yaws are multiples of 90° for floor furniture).
#[derive(Clone, Copy, Debug)]
struct Rect {
    min: Point2<f32>,
    max: Point2<f32>,
}

impl Rect {
    fn around(c: Point2<f32>, size_x: f32, size_z: f32) -> Rect {
        let h = Vector2::new(size_x / 2.0, size_z / 2.0);
        Rect { min: c - h, max: c + h }
    }
    fn overlaps(&self, o: &Rect, gap: f32) -> bool {
        self.min.x < o.max.x + gap
            && o.min.x < self.max.x + gap
            && self.min.y < o.max.y + gap
            && o.min.y < self.max.y + gap
    }
}

/// A wall item's span on its wall (along-wall interval and height range).
#[derive(Clone, Copy, Debug)]
struct WallSpan {
    wall: Wall,
    u0: f32,
    u1: f32,
    y0: f32,
    y1: f32,
}

struct Layout<'r> {
    rng: &'r mut ChaCha8Rng,
    room: Room,
    objects: Vec<Object>,
    /// Footprints of floor-standing objects (index into `objects`).
    floor: Vec<(Rect, usize)>,
    wall_spans: Vec<WallSpan>,
    /// Footprints of items already on each host.
    on_host: Vec<(usize, Rect)>,
}

impl Layout<'_> {
    fn size(&mut self, c: Category) -> [f32; 3] {
        let (lo, hi) = c.size_range();
        [0, 1, 2].map(|i| if hi[i] > lo[i] { self.rng.random_range(lo[i]..=hi[i]) } else { lo[i] })
    }

    fn color(&mut self, c: Category) -> [f32; 3] {
        let base = *c.palette().choose(self.rng).expect("palette");
        let k: f32 = self.rng.random_range(0.9..1.08);
        base.map(|v| (v * k).clamp(0.0, 1.0))
    }

    fn push(&mut self, category: Category, pos: [f32; 3], yaw: f32, size: [f32; 3], on: Option<usize>) -> usize {
        let color = self.color(category);
        let style = self.rng.random_range(0..3);
        self.objects.push(Object { category, position: pos, yaw, size, color, style, on });
        self.objects.len() - 1
    }

    fn footprint(yaw: f32, p: Point2<f32>, size: [f32; 3]) -> Rect {
        let quarter = ((yaw / 90.0).round() as i32).rem_euclid(2) == 1;
        if quarter { Rect::around(p, size[2], size[0]) } else { Rect::around(p, size[0], size[2]) }
    }

    fn floor_free(&self, r: &Rect, gap: f32) -> bool {
        let (hx, hz) = self.room.half();
        r.min.x >= -hx - 1e-3
            && r.max.x <= hx + 1e-3
            && r.min.y >= -hz - 1e-3
            && r.max.y <= hz + 1e-3
            && self.floor.iter().all(|(o, _)| !o.overlaps(r, gap))
    }

    fn wall_free(&self, s: &WallSpan) -> bool {
        self.wall_spans.iter().all(|o| o.wall != s.wall || o.u1 <= s.u0 || s.u1 <= o.u0 || o.y1 <= s.y0 || s.y1 <= o.y0)
    }

    /// Stands a piece of furniture against `wall` at along-wall position `u`; None if it does
    /// not fit there.
    fn against_wall_at(&mut self, c: Category, wall: Wall, u: f32, size: [f32; 3]) -> Option<usize> {
        let yaw = wall.yaw();
        let p = wall.point(&self.room, u, size[2] / 2.0 + 0.01);
        let r = Self::footprint(yaw, p, size);
        let span = WallSpan { wall, u0: u - size[0] / 2.0, u1: u + size[0] / 2.0, y0: 0.0, y1: size[1] };
        if !self.floor_free(&r, 0.02) || !self.wall_free(&span) {
            return None;
        }
        let i = self.push(c, [p.x, size[1] / 2.0, p.y], yaw, size, None);
        self.floor.push((r, i));
        self.wall_spans.push(span);
        Some(i)
    }

    /// Tries random positions along a wall (or along any wall when `wall` is None).
    fn against_wall(&mut self, c: Category, wall: Option<Wall>) -> Option<usize> {
        let size = self.size(c);
        for _ in 0..40 {
            let w = wall.unwrap_or_else(|| *Wall::ALL.choose(self.rng).unwrap());
            let half = (w.length(&self.room) - size[0]) / 2.0 - 0.02;
            if half <= 0.0 {
                continue;
            }
            let u = self.rng.random_range(-half..=half);
            if let Some(i) = self.against_wall_at(c, w, u, size) {
                return Some(i);
            }
        }
        None
    }

    /// Stands something on the floor at `p` facing `yaw`, keeping `gap` to other furniture.
    fn on_floor_at(&mut self, c: Category, p: Point2<f32>, yaw: f32, size: [f32; 3], gap: f32) -> Option<usize> {
        let r = Self::footprint(yaw, p, size);
        if !self.floor_free(&r, gap) {
            return None;
        }
        let i = self.push(c, [p.x, size[1] / 2.0, p.y], yaw, size, None);
        self.floor.push((r, i));
        Some(i)
    }

    /// A random free floor spot at least `wall_gap` from the walls.
    fn on_floor(&mut self, c: Category, wall_gap: f32, gap: f32) -> Option<usize> {
        let size = self.size(c);
        let (hx, hz) = self.room.half();
        for _ in 0..60 {
            let yaw = *[0.0f32, 90.0, 180.0, 270.0].choose(self.rng).unwrap();
            let r = Self::footprint(yaw, Point2::origin(), size);
            let (ex, ez) = (r.max.x + wall_gap, r.max.y + wall_gap);
            if ex >= hx || ez >= hz {
                return None;
            }
            let p = Point2::new(self.rng.random_range(-hx + ex..=hx - ex), self.rng.random_range(-hz + ez..=hz - ez));
            if let Some(i) = self.on_floor_at(c, p, yaw, size, gap) {
                return Some(i);
            }
        }
        None
    }

    /// Hangs a wall item on `wall` (any wall if None) with its centre at a height drawn from the
    /// category's range.
    fn on_wall(&mut self, c: Category, wall: Option<Wall>) -> Option<usize> {
        let mut size = self.size(c);
        let (ylo, yhi) = c.wall_height().expect("wall item has a height");
        for _ in 0..40 {
            let w = wall.unwrap_or_else(|| *Wall::ALL.choose(self.rng).unwrap());
            let y = self.rng.random_range(ylo..=yhi);
            if c == Category::Window || c == Category::Poster || c == Category::Mirror {
                size[1] = size[1].min(2.0 * (self.room.height - 0.15 - y)).min(2.0 * (y - 0.75));
            }
            let half = (w.length(&self.room) - size[0]) / 2.0 - 0.1;
            if half <= 0.0 {
                continue;
            }
            let u = self.rng.random_range(-half..=half);
            let span = WallSpan {
                wall: w,
                u0: u - size[0] / 2.0 - 0.05,
                u1: u + size[0] / 2.0 + 0.05,
                y0: y - size[1] / 2.0,
                y1: y + size[1] / 2.0,
            };
            if !self.wall_free(&span) {
                continue;
            }
            let p = w.point(&self.room, u, size[2] / 2.0);
            let i = self.push(c, [p.x, y, p.y], w.yaw(), size, None);
            self.wall_spans.push(span);
            return Some(i);
        }
        None
    }

    /// Puts a small item on top of one of `hosts`.
    fn on_host(&mut self, c: Category, hosts: &[usize]) -> Option<usize> {
        if hosts.is_empty() {
            return None;
        }
        let size = self.size(c);
        for _ in 0..30 {
            let h = *hosts.choose(self.rng).unwrap();
            let host = self.objects[h].clone();
            let (hw, hd) = (host.size[0] / 2.0 - 0.04, host.size[2] / 2.0 - 0.04);
            // things with a front (TVs, laptops, clocks, lamps) face where the host faces
            let fronted =
                matches!(c, Category::Television | Category::Laptop | Category::AlarmClock | Category::DeskLamp);
            let yaw_local = if fronted { 0.0 } else { *[0.0f32, 90.0, 180.0, 270.0].choose(self.rng).unwrap() };
            let fp = Self::footprint(yaw_local, Point2::origin(), size);
            let (ex, ez) = (fp.max.x, fp.max.y);
            if ex >= hw || ez >= hd {
                continue;
            }
            let local =
                Vector2::new(self.rng.random_range(-hw + ex..=hw - ex), self.rng.random_range(-hd + ez..=hd - ez));
            let local_rect = Rect::around(Point2::from(local), 2.0 * ex, 2.0 * ez);
            if self.on_host.iter().any(|(o, r)| *o == h && r.overlaps(&local_rect, 0.02)) {
                continue;
            }
            let yaw = crate::geometry::wrap_deg(host.yaw + yaw_local);
            let rot = crate::geometry::yaw_rotation(host.yaw);
            let world = rot * nalgebra::Vector3::new(local.x, 0.0, local.y);
            let top = host.position[1] + host.size[1] / 2.0;
            let pos = [host.position[0] + world.x, top + size[1] / 2.0 + 0.001, host.position[2] + world.z];
            let i = self.push(c, pos, yaw, size, Some(h));
            self.on_host.push((h, local_rect));
            return Some(i);
        }
        None
    }

    /// Hangs a towel under its holder.
    fn hang_on(&mut self, c: Category, holder: usize) -> usize {
        let hd = self.objects[holder].clone();
        let mut size = self.size(c);
        size[0] = size[0].min(hd.size[0] * 0.95);
        let n = heading(hd.yaw);
        let off = hd.size[2] / 2.0 + size[2] / 2.0 - 0.02;
        let y = hd.position[1] - size[1] / 2.0 + hd.size[1] * 0.3;
        self.push(
            c,
            [hd.position[0] + n.x * off, y.max(size[1] / 2.0 + 0.05), hd.position[2] + n.y * off],
            hd.yaw,
            size,
            Some(holder),
        )
    }

    fn chance(&mut self, p: f64) -> bool {
        self.rng.random_bool(p)
    }

    /// Chairs around a table, facing it.
    fn chairs_around(&mut self, table: usize, n: usize) {
        let t = self.objects[table].clone();
        let quarter = ((t.yaw / 90.0).round() as i32).rem_euclid(2) == 1;
        let (tx, tz) = if quarter { (t.size[2], t.size[0]) } else { (t.size[0], t.size[2]) };
        let c = Point2::new(t.position[0], t.position[2]);
        let mut sides = vec![(0.0f32, -1.0f32), (0.0, 1.0), (-1.0, 0.0), (1.0, 0.0)];
        // long sides first
        if tx > tz {
            sides.swap(2, 0);
            sides.swap(3, 1);
            sides.swap(0, 2);
        }
        let mut placed = 0;
        for (sx, sz) in sides {
            if placed >= n {
                break;
            }
            let size = self.size(Category::Chair);
            let p = c + Vector2::new(sx * (tx / 2.0 + size[2] / 2.0 + 0.05), sz * (tz / 2.0 + size[2] / 2.0 + 0.05));
            // the chair faces the table: its front (+z local) points at the table
            let yaw = crate::geometry::yaw_of(c - p);
            if self.on_floor_at(Category::Chair, p, yaw, size, 0.0).is_some() {
                placed += 1;
            }
        }
    }

    /// A run of counters (with stove, sink, fridge) along a wall starting at one corner.
    fn counter_run(&mut self, wall: Wall, fraction: f32, with_fridge: bool) -> Vec<usize> {
        let len = wall.length(&self.room);
        let mut u = -len / 2.0 + 0.02;
        let end = -len / 2.0 + len * fraction;
        let mut hosts = Vec::new();
        if with_fridge {
            let size = self.size(Category::Fridge);
            if self.against_wall_at(Category::Fridge, wall, u + size[0] / 2.0, size).is_some() {
                u += size[0] + 0.02;
            }
        }
        let mut placed_stove = false;
        let mut placed_sink = false;
        while u < end - 0.6 {
            let c = if !placed_stove && self.chance(0.35) {
                placed_stove = true;
                Category::Stove
            } else if !placed_sink && self.chance(0.35) {
                placed_sink = true;
                Category::Sink
            } else {
                Category::CounterTop
            };
            let mut size = self.size(c);
            size[0] = size[0].min(end - u);
            if size[0] < 0.55 {
                break;
            }
            if let Some(i) = self.against_wall_at(c, wall, u + size[0] / 2.0, size) {
                if c == Category::CounterTop {
                    hosts.push(i);
                }
            }
            u += size[0] + 0.001;
        }
        hosts
    }
}

fn surfaces(rng: &mut ChaCha8Rng, t: SceneType) -> (Surface, Surface, Surface) {
    let floor_wood = [[0.55, 0.38, 0.22], [0.42, 0.28, 0.16], [0.68, 0.52, 0.34]];
    let floor_tile = [[0.80, 0.80, 0.78], [0.55, 0.55, 0.58], [0.70, 0.66, 0.60]];
    let walls = [[0.92, 0.90, 0.85], [0.80, 0.85, 0.88], [0.88, 0.82, 0.72], [0.75, 0.80, 0.72], [0.90, 0.78, 0.78]];
    let tile = matches!(t, SceneType::Kitchen | SceneType::Bathroom) && rng.random_bool(0.7);
    let floor = if tile {
        Surface { color: *floor_tile.choose(rng).unwrap(), material: Material::Tile }
    } else {
        Surface { color: *floor_wood.choose(rng).unwrap(), material: Material::Wood }
    };
    let wall = Surface { color: *walls.choose(rng).unwrap(), material: Material::Matte };
    let ceiling = Surface { color: [0.95, 0.95, 0.95], material: Material::Matte };
    (floor, wall, ceiling)
}

/// One attempt at a room of `id`'s type: its shell, then its type's recipe (`furnish`).
fn layout(id: SceneId, seed: u64, rng: &mut ChaCha8Rng) -> Scene {
    let t = id.scene_type;
    let room = shell(t, rng);
    let mut l =
        Layout { rng, room, objects: Vec::new(), floor: Vec::new(), wall_spans: Vec::new(), on_host: Vec::new() };
    let main = *Wall::ALL.choose(l.rng).unwrap();
    match t {
        SceneType::Kitchen => l.kitchen(main),
        SceneType::LivingRoom => l.living_room(main),
        SceneType::Bedroom => l.bedroom(main),
        SceneType::Bathroom => l.bathroom(main),
    }
    Scene { name: id.name(), scene_type: t, seed, room: l.room, walls: Vec::new(), objects: l.objects }
}

/// The empty room: its size on a 25 cm grid within its type's range, its height and surfaces.
fn shell(t: SceneType, rng: &mut ChaCha8Rng) -> Room {
    let (wr, dr) = match t {
        SceneType::Kitchen => ((4.5, 6.5), (4.0, 6.0)),
        SceneType::LivingRoom => ((5.5, 8.0), (5.0, 7.5)),
        SceneType::Bedroom => ((4.5, 6.5), (4.0, 6.0)),
        SceneType::Bathroom => ((3.0, 4.5), (3.0, 4.5)),
    };
    let snap = |v: f32| (v * 4.0).round() / 4.0;
    let width = snap(rng.random_range(wr.0..=wr.1));
    let depth = snap(rng.random_range(dr.0..=dr.1));
    let height = rng.random_range(2.6..=3.0f32);
    let (floor, walls, ceiling) = surfaces(rng, t);
    Room { width, depth, height, floor, walls, ceiling }
}

/// Along-wall coordinate of a floor point (inverse of `Wall::point` for u).
fn along(room: &Room, wall: Wall, p: Point2<f32>) -> f32 {
    let n = heading(wall.yaw());
    let t = Vector2::new(n.y, -n.x);
    let _ = room;
    t.dot(&p.coords)
}

/// The wall something with this yaw stands against.
fn wall_of(yaw: f32) -> Wall {
    let k = ((yaw / 90.0).round() as i32).rem_euclid(4);
    [Wall(0), Wall(3), Wall(2), Wall(1)][k as usize]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::targets_of;
    use std::collections::{BTreeMap, BTreeSet};

    #[test]
    fn wall_points_face_into_the_room() {
        let s = Surface { color: [0.5; 3], material: Material::Matte };
        let room = Room { width: 6.0, depth: 4.0, height: 2.7, floor: s, walls: s, ceiling: s };
        for w in Wall::ALL {
            let p = w.point(&room, 0.5, 0.2);
            assert!(room.contains(p.x, p.y, 0.19), "{w:?} {p:?}");
            assert!((along(&room, w, p) - 0.5).abs() < 1e-5);
            assert_eq!(wall_of(w.yaw()), w);
            // one step along the facing direction moves away from the wall
            let q = p + heading(w.yaw()) * 0.1;
            assert!(room.contains(q.x, q.y, 0.29));
        }
    }

    #[test]
    fn same_seed_gives_byte_identical_scene_json() {
        for id in [SceneId::new(SceneType::Kitchen, 3), SceneId::new(SceneType::Bathroom, 28)] {
            let a = generate(id, 7).to_json();
            let b = generate(id, 7).to_json();
            assert_eq!(a, b);
            assert_ne!(a, generate(id, 8).to_json());
            // and it survives a reload
            assert_eq!(Scene::from_json(&a, "mem").unwrap().to_json(), a);
        }
    }

    #[test]
    fn every_room_is_valid_and_the_catalogue_is_covered() {
        let scenes = generate_all(1);
        assert_eq!(scenes.len(), 120);
        let mut seen: BTreeMap<SceneType, BTreeSet<Category>> = BTreeMap::new();
        let mut repeated: BTreeMap<SceneType, usize> = BTreeMap::new();
        for s in &scenes {
            s.validate().unwrap_or_else(|(f, m)| panic!("{}: {f}: {m}", s.name));
            let mut counts: BTreeMap<Category, usize> = BTreeMap::new();
            for o in &s.objects {
                if targets_of(s.scene_type).contains(&o.category) {
                    *counts.entry(o.category).or_default() += 1;
                    seen.entry(s.scene_type).or_default().insert(o.category);
                }
            }
            assert!(counts.len() >= 5, "{} has only {} target categories", s.name, counts.len());
            if counts.values().any(|&n| n > 1) {
                *repeated.entry(s.scene_type).or_default() += 1;
            }
        }
        for t in SceneType::ALL {
            let have = &seen[&t];
            for c in targets_of(t) {
                assert!(have.contains(c), "{t:?} never has a {c:?} in 30 rooms");
            }
            let rep = repeated.get(&t).copied().unwrap_or(0);
            assert!(rep * 4 >= 30, "{t:?}: only {rep}/30 rooms repeat a target category");
        }
    }
}
