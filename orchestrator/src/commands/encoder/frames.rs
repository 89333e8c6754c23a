//! The frames the visual encoder is pretrained on: random reachable poses in the *training*
//! rooms, the person standing 1–4 m in front of the robot in part of them, labelled per cell
//! from the renderer's id target (what the policy's target input names: a target category, the
//! person, or anything else) and per-cell mean depth.
//!
//! Every draw of frame `i` comes from `seed::rng(seed, &[KEY_FRAME, i])` and each view's bytes
//! do not depend on the chunk it is rendered in, so the set is the same whatever the thread count.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::Context;
use nalgebra::{Point2, Point3};
use rand::Rng;

use farm::config::EnvConfig;
use farm::frame_set::{CLASS_OTHER, CLASS_PERSON, CLASSES, FLAG_PERSON, FrameRef, FrameSet, FrameSetHeader};
use farm::rooms::{SceneId, SceneType, Split};
use worker::camera::Camera;
use worker::geometry::{ID_HUMAN, Part, heading, yaw_of};
use worker::gesture::{self, Motion};
use worker::humanoid::Humanoid;
use worker::nav::{GRID_STEP, NavGrid};
use worker::physics::{Physics, RobotBody};
use worker::render::{RenderConfig, Renderer, View, ViewOut};
use worker::scene::{Scene, object_index};

/// Cells per side of a frame's labels.
pub const GRID: u32 = 8;
/// Share of frames with the person in front of the robot.
pub const PERSON_SHARE: f64 = 0.5;
/// A cell is labelled with its most frequent target or person class when that class covers at
/// least this share of the cell (4 pixels of a 64×64 frame's 8×8 cell), else "other": small
/// objects a few metres away still count, stray edge pixels do not.
pub const MIN_CELL_SHARE: f32 = 1.0 / 16.0;
/// Room indices (of each type's 20 training rooms) whose frames are only for the held-out figure.
pub const HELD_OUT_INDICES: [u32; 2] = [19, 20];
/// Share of the frames rendered in the held-out rooms (as many per room as the others get).
const HELD_OUT_SHARE: f64 = 0.1;
const KEY_FRAME: u64 = 0xE4C0_DE01;
/// Person placement tries before the frame goes without one.
const PERSON_TRIES: usize = 12;

/// What to render.
#[derive(Clone, Debug)]
pub struct FrameOptions {
    pub frames: usize,
    /// Frame width = height in pixels.
    pub size: u32,
    pub seed: u64,
    /// Renderer threads (each owns a renderer; the set does not depend on it).
    pub threads: usize,
}

/// The rooms held out of training (2 of each type's 20 training rooms).
pub fn held_out_rooms() -> Vec<SceneId> {
    SceneType::ALL.iter().flat_map(|&t| HELD_OUT_INDICES.map(|i| SceneId::new(t, i))).collect()
}

/// The training rooms the encoder learns from.
pub fn learning_rooms() -> Vec<SceneId> {
    let held = held_out_rooms();
    SceneId::of_split(Split::Train).filter(|r| !held.contains(r)).collect()
}

/// Frames `0..held` go round the held-out rooms, the rest round the learning rooms.
pub fn room_of_frame(i: usize, frames: usize) -> SceneId {
    let held = held_out_rooms();
    let n_held = ((frames as f64 * HELD_OUT_SHARE).ceil() as usize).min(frames);
    if i < n_held {
        held[i % held.len()]
    } else {
        let learn = learning_rooms();
        learn[(i - n_held) % learn.len()]
    }
}

/// The class of each object of a scene (by index): its target index, or "other".
pub fn object_classes(scene: &Scene) -> Vec<u8> {
    scene.objects.iter().map(|o| o.category.target_index().map_or(CLASS_OTHER, |t| t as u8)).collect()
}

/// The class a pixel with instance id `id` shows.
pub fn pixel_class(id: u16, classes: &[u8]) -> u8 {
    if id == ID_HUMAN {
        return CLASS_PERSON;
    }
    object_index(id).and_then(|i| classes.get(i).copied()).unwrap_or(CLASS_OTHER)
}

/// Per-cell labels of one view (`size × size` ids and depth): the class (see
/// [`MIN_CELL_SHARE`]; ties go to the lower class) and the mean depth.
pub fn cell_labels(ids: &[u16], depth: &[u16], size: u32, grid: u32, classes: &[u8]) -> (Vec<u8>, Vec<u16>) {
    let (size, grid) = (size as usize, grid as usize);
    let side = size / grid;
    let min = (MIN_CELL_SHARE * (side * side) as f32).ceil() as u32;
    let mut class = Vec::with_capacity(grid * grid);
    let mut mean = Vec::with_capacity(grid * grid);
    let mut counts = [0u32; CLASSES as usize];
    for cy in 0..grid {
        for cx in 0..grid {
            counts.fill(0);
            let mut sum = 0u64;
            for y in cy * side..(cy + 1) * side {
                for x in cx * side..(cx + 1) * side {
                    counts[pixel_class(ids[y * size + x], classes) as usize] += 1;
                    sum += u64::from(depth[y * size + x]);
                }
            }
            let (best, n) = counts[..CLASS_OTHER as usize]
                .iter()
                .enumerate()
                .fold((CLASS_OTHER as usize, 0), |acc, (c, &n)| if n > acc.1 { (c, n) } else { acc });
            class.push(if n >= min { best as u8 } else { CLASS_OTHER });
            mean.push(((sum + (side * side / 2) as u64) / (side * side) as u64) as u16);
        }
    }
    (class, mean)
}

/// A room ready for drawing poses: where the robot can stand, what collides.
struct RoomSetup {
    scene: Scene,
    physics: Physics,
    grid: NavGrid,
    reachable: Vec<usize>,
    classes: Vec<u8>,
    /// Target objects' centres (what a referencing gesture points at).
    targets: Vec<Point3<f32>>,
}

impl RoomSetup {
    fn new(scene: Scene, env: &EnvConfig) -> anyhow::Result<RoomSetup> {
        let physics = Physics::new(&scene.parts(), RobotBody { radius: env.robot_radius, height: env.robot_height });
        let grid = NavGrid::build(&physics, &scene.room, GRID_STEP);
        let (label, largest) = grid.components();
        let reachable: Vec<usize> = grid.free_cells().filter(|&c| Some(label[c]) == largest).collect();
        anyhow::ensure!(!reachable.is_empty(), "{}: the robot fits nowhere in this room", scene.name);
        let classes = object_classes(&scene);
        let targets = scene.objects.iter().filter(|o| o.category.is_target()).map(|o| o.center()).collect();
        Ok(RoomSetup { scene, physics, grid, reachable, classes, targets })
    }
}

/// One frame's drawn pose and person.
struct Shot {
    camera: Camera,
    person: Vec<Part>,
    /// The person's yaw minus the yaw from them to the robot (`FrameRef::person_facing`).
    person_facing: f32,
}

/// Draws frame `i`'s robot pose and, in [`PERSON_SHARE`] of frames, the person posed by a random
/// frame of a referencing (at a target of the room) or intervention gesture.
fn draw_shot(room: &RoomSetup, env: &EnvConfig, seed: u64, i: usize, interventions: &[Motion]) -> Shot {
    let mut r = farm::seed::rng(seed, &[KEY_FRAME, i as u64]);
    let cell = room.reachable[r.random_range(0..room.reachable.len())];
    let c = room.grid.point(cell);
    let h = GRID_STEP / 2.0;
    let jittered = Point2::new(c.x + r.random_range(-h..h), c.y + r.random_range(-h..h));
    let at = if room.physics.robot_fits(jittered) { jittered } else { c };
    let yaw = r.random_range(0.0..360.0f32);
    let camera = Camera::new(Point3::new(at.x, env.camera_height, at.y), yaw);
    let (mut person, mut person_facing) = (Vec::new(), f32::NAN);
    if r.random_bool(PERSON_SHARE) {
        for _ in 0..PERSON_TRIES {
            let d = r.random_range(1.0..4.0f32);
            let bearing = r.random_range(-35.0..35.0f32);
            let p = at.coords + heading(yaw + bearing) * d;
            if !(room.scene.room.contains(p.x, p.y, env.robot_radius) && room.physics.robot_fits(Point2::from(p))) {
                continue;
            }
            let facing = r.random_range(-60.0..60.0f32);
            let p_yaw = yaw_of(at.coords - p) + facing;
            let feet = Point3::new(p.x, 0.0, p.y);
            let motion_seed: u64 = r.random();
            let frame = r.random_range(0..gesture::FRAMES);
            let referencing = !room.targets.is_empty() && r.random_bool(0.5);
            let motion = if referencing {
                let target = room.targets[r.random_range(0..room.targets.len())];
                gesture::referencing(motion_seed, feet, p_yaw, target).0
            } else {
                interventions[r.random_range(0..interventions.len())].clone()
            };
            let human = Humanoid::seeded(motion_seed);
            person = human.parts(&human.pose(motion.frame(frame), feet, p_yaw));
            person_facing = facing;
            break;
        }
    }
    Shot { camera, person, person_facing }
}

/// One rendered, labelled frame.
struct Rendered {
    flags: u8,
    person_facing: f32,
    rgb: Vec<u8>,
    depth: Vec<u16>,
    class: Vec<u8>,
    cell_depth: Vec<u16>,
}

/// Renders the frames `indices` of one room.
fn render_room(
    r: &mut Renderer,
    room: &RoomSetup,
    env: &EnvConfig,
    opts: &FrameOptions,
    indices: &[usize],
    interventions: &[Motion],
    done: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Vec<Rendered>> {
    let handle = r.upload_scene(&room.scene.parts());
    let px = (opts.size * opts.size) as usize;
    let mut out = Vec::with_capacity(indices.len());
    for chunk in indices.chunks(r.views_per_submit()) {
        let shots: Vec<Shot> = chunk.iter().map(|&i| draw_shot(room, env, opts.seed, i, interventions)).collect();
        let views: Vec<View> =
            shots.iter().map(|s| View { scene: handle, camera: s.camera, dynamic: &s.person }).collect();
        let mut rgb = vec![0u8; px * 3 * chunk.len()];
        let mut depth = vec![0u16; px * chunk.len()];
        let mut ids = vec![0u16; px * chunk.len()];
        let mut outs = ViewOut::split(&mut rgb, &mut depth, &mut ids, px);
        r.render(&views, &mut outs)?;
        drop(outs);
        for (k, shot) in shots.iter().enumerate() {
            let (d, id) = (&depth[k * px..(k + 1) * px], &ids[k * px..(k + 1) * px]);
            let (class, cell_depth) = cell_labels(id, d, opts.size, GRID, &room.classes);
            out.push(Rendered {
                flags: if shot.person.is_empty() { 0 } else { FLAG_PERSON },
                person_facing: shot.person_facing,
                rgb: rgb[k * px * 3..(k + 1) * px * 3].to_vec(),
                depth: d.to_vec(),
                class,
                cell_depth,
            });
        }
        done(chunk.len());
    }
    r.release_scene(handle);
    Ok(out)
}

/// Renders and labels `opts.frames` frames; `scene_of` gives a room's scene, `done(n)` reports
/// n more frames finished (from any thread).
pub fn render_set(
    opts: &FrameOptions,
    scene_of: &(dyn Fn(SceneId) -> anyhow::Result<Scene> + Sync),
    done: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<FrameSet> {
    anyhow::ensure!(opts.frames > 0, "--frames: at least one frame");
    anyhow::ensure!(
        opts.size >= GRID && opts.size.is_multiple_of(GRID),
        "--size: {} must be a multiple of the {GRID}-cell grid",
        opts.size
    );
    let env = EnvConfig::default();
    let mut by_room: Vec<(SceneId, Vec<usize>)> = Vec::new();
    for i in 0..opts.frames {
        let room = room_of_frame(i, opts.frames);
        match by_room.iter_mut().find(|(r, _)| *r == room) {
            Some((_, v)) => v.push(i),
            None => by_room.push((room, vec![i])),
        }
    }
    let interventions: Vec<Motion> = (0..gesture::INTERVENTIONS).map(gesture::intervention).collect();
    let cfg = RenderConfig { width: opts.size, height: opts.size, fov_deg: env.fov_deg, max_views_per_submit: 16 };
    let slots: Mutex<Vec<Option<Rendered>>> = Mutex::new((0..opts.frames).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    let threads = opts.threads.clamp(1, by_room.len());
    std::thread::scope(|s| -> anyhow::Result<()> {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| -> anyhow::Result<()> {
                    let mut r = Renderer::new(&cfg)?;
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some((id, indices)) = by_room.get(k) else { return Ok(()) };
                        let room = RoomSetup::new(scene_of(*id)?, &env)?;
                        let frames = render_room(&mut r, &room, &env, opts, indices, &interventions, done)
                            .with_context(|| format!("rendering {}", id.name()))?;
                        let mut slots = slots.lock().expect("no thread panicked holding the slots");
                        for (&i, f) in indices.iter().zip(frames) {
                            slots[i] = Some(f);
                        }
                    }
                })
            })
            .collect();
        for h in handles {
            h.join().map_err(|_| anyhow::anyhow!("a render thread panicked"))??;
        }
        Ok(())
    })?;
    let header = FrameSetHeader {
        width: opts.size,
        height: opts.size,
        grid: GRID,
        classes: CLASSES,
        seed: opts.seed,
        held_out: held_out_rooms().iter().map(|r| r.floorplan() as u16).collect(),
    };
    let mut set = FrameSet::new(header)?;
    for (i, f) in slots.into_inner().expect("threads done").into_iter().enumerate() {
        let f = f.expect("every frame rendered");
        set.push(&FrameRef {
            room: room_of_frame(i, opts.frames).floorplan() as u16,
            flags: f.flags,
            person_facing: f.person_facing,
            rgb: &f.rgb,
            depth: &f.depth,
            cell_class: &f.class,
            cell_depth: &f.cell_depth,
        })?;
    }
    Ok(set)
}

#[cfg(test)]
mod tests {
    use super::*;
    use worker::geometry::{ID_NONE, ID_STRUCTURE};
    use worker::scene::{Category, object_id};

    #[test]
    fn held_out_rooms_get_frames_but_are_kept_apart() {
        assert_eq!(held_out_rooms().len(), 8);
        assert_eq!(learning_rooms().len(), 72);
        let rooms: Vec<SceneId> = (0..64).map(|i| room_of_frame(i, 64)).collect();
        let held = held_out_rooms();
        assert_eq!(rooms.iter().filter(|r| held.contains(r)).count(), 7);
        assert!(rooms.iter().all(|r| r.split() == Split::Train));
    }

    #[test]
    fn pixel_classes_follow_the_id_target() {
        let classes = [Category::Cup.target_index().unwrap() as u8, CLASS_OTHER];
        assert_eq!(pixel_class(object_id(0), &classes), Category::Cup.target_index().unwrap() as u8);
        assert_eq!(pixel_class(object_id(1), &classes), CLASS_OTHER);
        assert_eq!(pixel_class(ID_HUMAN, &classes), CLASS_PERSON);
        assert_eq!(pixel_class(ID_STRUCTURE, &classes), CLASS_OTHER);
        assert_eq!(pixel_class(ID_NONE, &classes), CLASS_OTHER);
        assert_eq!(pixel_class(object_id(9), &classes), CLASS_OTHER);
    }

    #[test]
    fn cells_take_a_class_covering_enough_of_them() {
        // 16×16 frame, 2×2 cells of 64 pixels: the threshold is 4 pixels.
        let classes = [5u8];
        let mut ids = vec![ID_STRUCTURE; 256];
        let depth: Vec<u16> = (0..256).map(|i| if i % 16 < 8 { 100 } else { 300 }).collect();
        for y in 0..4 {
            ids[y * 16] = object_id(0); // top-left cell: 4 pixels of object 0
        }
        ids[8] = ID_HUMAN; // top-right: 3 pixels of the person, not enough
        ids[9] = ID_HUMAN;
        ids[10] = ID_HUMAN;
        for y in 8..16 {
            for x in 8..16 {
                ids[y * 16 + x] = if x < 12 { ID_HUMAN } else { object_id(0) }; // bottom-right: a tie
            }
        }
        let (class, mean) = cell_labels(&ids, &depth, 16, 2, &classes);
        assert_eq!(class, vec![5, CLASS_OTHER, CLASS_OTHER, 5]);
        assert_eq!(mean, vec![100, 300, 100, 300]);
    }

    /// A room holding one sofa, seen from two metres: the cell under the sofa's centre says
    /// "Sofa", and no cell names anything else.
    #[test]
    fn a_rendered_target_labels_its_cells() {
        let mut scene = worker::scene::generate::generate(SceneId::parse("FloorPlan201").unwrap(), 1);
        let mut sofa = scene.objects.iter().find(|o| o.category == Category::Sofa).expect("a sofa").clone();
        sofa.on = None;
        scene.objects = vec![sofa.clone()];
        let c = sofa.center();
        let to_middle = -nalgebra::Vector2::new(c.x, c.z).normalize();
        let eye = nalgebra::Vector2::new(c.x, c.z) + to_middle * 2.0;
        assert!(scene.room.contains(eye.x, eye.y, 0.2), "camera inside the room");
        let camera = Camera::new(Point3::new(eye.x, 1.5, eye.y), yaw_of(-to_middle));
        let size = 64;
        let cfg = RenderConfig { width: size, height: size, fov_deg: 90.0, max_views_per_submit: 1 };
        let mut r = Renderer::new(&cfg).unwrap();
        let h = r.upload_scene(&scene.parts());
        let px = (size * size) as usize;
        let (mut rgb, mut depth, mut ids) = (vec![0u8; px * 3], vec![0u16; px], vec![0u16; px]);
        r.render(
            &[View { scene: h, camera, dynamic: &[] }],
            &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: Some(&mut ids) }],
        )
        .unwrap();
        let (class, _) = cell_labels(&ids, &depth, size, GRID, &object_classes(&scene));
        let sofa_class = Category::Sofa.target_index().unwrap() as u8;
        let (col, row, _) = worker::render::project(&camera, &cfg, c).expect("the sofa is in view");
        let cell = (row as usize / 8) * GRID as usize + col as usize / 8;
        assert_eq!(class[cell], sofa_class, "cells: {class:?}");
        assert!(class.iter().all(|&k| k == sofa_class || k == CLASS_OTHER), "{class:?}");
        assert!(class.iter().filter(|&&k| k == sofa_class).count() >= 4, "{class:?}");
    }
}
