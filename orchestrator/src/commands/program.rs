//! `orchestrator program export` writes a program in the original recorder's folder layout;
//! `orchestrator replay` renders the person performing a program's gesture, as the robot sees it
//! from its start and from above, as PNG frames and an animated GIF.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector2};

use farm::config::EnvConfig;
use worker::camera::Camera;
use worker::dataset::build::HUMAN_EYE_HEIGHT;
use worker::dataset::{Dataset, Verify};
use worker::geometry::yaw_of;
use worker::gesture::motion::{Metadata, read_csv, write_csv};
use worker::gesture::{self, Motion};
use worker::humanoid::Humanoid;
use worker::program::Program;
use worker::render::{RenderConfig, Renderer, View, ViewOut};
use worker::scene::{Scene, SceneId, SceneType, Split};

#[derive(Subcommand, Debug)]
pub enum ProgramCmd {
    /// Write a program as the original recorder did: NAME.json, motions/NAME.csv, images/NAME.png.
    Export(ExportArgs),
}

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// The program: SPLIT:INDEX (e.g. val:17).
    pub program: String,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// SPLIT:INDEX of a dataset program, or a program's metadata JSON in the original format
    /// (its motion is found through the JSON's `motion` field or beside it as NAME.csv).
    pub program: String,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Perform intervention gesture K (0..20) instead of the program's referencing gesture.
    #[arg(long)]
    pub intervention: Option<usize>,
    /// Frame size of each view.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Use every Nth motion frame (the motion is 100 frames at 30 fps).
    #[arg(long, default_value_t = 2)]
    pub every: usize,
    /// Turn the robot at its start position toward the person (a viewing aid; the program's
    /// own start yaw is used otherwise).
    #[arg(long)]
    pub robot_faces_person: bool,
    /// Seed of generated rooms, when the dataset has none.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(cmd: ProgramCmd) -> anyhow::Result<()> {
    match cmd {
        ProgramCmd::Export(a) => export(a),
    }
}

pub(crate) fn parse_ref(s: &str) -> Option<(Split, usize)> {
    let (split, i) = s.split_once(':')?;
    Some((Split::from_name(split)?, i.parse().ok()?))
}

/// A program as `parse_ref` reads it: `val:17`.
pub(crate) fn program_ref(split: Split, i: u64) -> String {
    format!("{}:{i}", split.name())
}

/// A program and its motion, from the dataset.
pub(crate) fn dataset_program(ds: &Dataset, split: Split, i: usize) -> anyhow::Result<(Program, Motion)> {
    let file = ds.require(split)?;
    anyhow::ensure!(
        i < file.len(),
        "{}: split {} has {} programs, no program {i}",
        ds.dir.display(),
        split.name(),
        file.len()
    );
    let p = Program::from_record(i as u64, &file.record(i)).context("invalid program record")?;
    let m = Motion::from_flat(&file.motion(i)).context("motion size")?;
    Ok((p, m))
}

fn instruction(p: &Program) -> String {
    format!("go to this {}", p.target.name().to_lowercase())
}

/// The recorder's metadata of program `p` saved as `name`, with the files it names (image,
/// motion, audio; relative to the metadata's folder).
pub fn metadata(p: &Program, name: &str) -> (Metadata, [String; 3]) {
    let files = [format!("images/{name}.png"), format!("motions/{name}.csv"), format!("audios/{name}.wav")];
    let meta = Metadata::new(
        &instruction(p),
        p.scene_type.name(),
        p.scene_id().index as i64,
        p.target.name(),
        Point3::from(p.human_pos),
        p.human_yaw,
        p.target_center(),
        [&files[0], &files[1], &files[2]],
    );
    (meta, files)
}

fn export(a: ExportArgs) -> anyhow::Result<()> {
    let (split, i) =
        parse_ref(&a.program).with_context(|| format!("`{}` is not SPLIT:INDEX (e.g. val:17)", a.program))?;
    let ds = Dataset::open(&a.dataset, Verify::Quick)?;
    let (p, motion) = dataset_program(&ds, split, i)?;
    let scene = ds.scene(p.scene_id())?;
    let name = format!("{}_{}_{:06}", p.scene, split.name(), i);
    let (meta, files) = metadata(&p, &name);
    std::fs::create_dir_all(a.out.join("images"))?;
    std::fs::create_dir_all(a.out.join("motions"))?;
    meta.save(&a.out.join(format!("{name}.json")))?;
    write_csv(&a.out.join(&files[1]), &motion)?;
    // The person's first-person image: what they see from their eyes, facing their yaw.
    let eye = Camera::new(Point3::new(p.human_pos[0], HUMAN_EYE_HEIGHT, p.human_pos[2]), p.human_yaw);
    let img = render_views(&scene, &[eye], &[], 448)?;
    img[0].save(a.out.join(&files[0]))?;
    println!(
        "exported {} ({} → {}) to {} (no audio is recorded: {} is not written)",
        name,
        p.scene,
        p.target.name(),
        a.out.display(),
        files[2]
    );
    Ok(())
}

/// Renders views of a scene with extra (dynamic) parts; returns one image per camera.
fn render_views(
    scene: &Scene,
    cameras: &[Camera],
    dynamic: &[worker::geometry::Part],
    size: u32,
) -> anyhow::Result<Vec<RgbImage>> {
    let cfg = RenderConfig { width: size, height: size, fov_deg: 90.0, max_views_per_submit: cameras.len().max(1) };
    let mut r = Renderer::new(&cfg)?;
    let h = r.upload_scene(&scene.parts());
    let px = (size * size) as usize;
    let mut rgb = vec![vec![0u8; px * 3]; cameras.len()];
    let mut depth = vec![vec![0u16; px]; cameras.len()];
    let views: Vec<View> = cameras.iter().map(|c| View { scene: h, camera: *c, dynamic }).collect();
    let mut outs: Vec<ViewOut> =
        rgb.iter_mut().zip(depth.iter_mut()).map(|(r, d)| ViewOut { rgb: r, depth: d, ids: None }).collect();
    r.render(&views, &mut outs)?;
    drop(outs);
    Ok(rgb.into_iter().map(|b| RgbImage::from_raw(size, size, b).expect("buffer size")).collect())
}

/// A camera above and behind the person, looking down at them and toward the target.
fn above_camera(scene: &Scene, person: Point3<f32>, target: Point3<f32>) -> Camera {
    let to_target = Vector2::new(target.x - person.x, target.z - person.z);
    let dir = if to_target.norm() > 1e-3 { to_target.normalize() } else { Vector2::new(0.0, 1.0) };
    let side = Vector2::new(dir.y, -dir.x);
    let (hx, hz) = scene.room.half();
    let c = Vector2::new(person.x, person.z) - dir * 1.8 + side * 0.9;
    let c = Vector2::new(c.x.clamp(-hx + 0.15, hx - 0.15), c.y.clamp(-hz + 0.15, hz - 0.15));
    let height = (scene.room.height - 0.25).min(2.5);
    let look = Vector2::new(person.x, person.z) + dir * 0.8;
    let horiz = (look - c).norm().max(0.3);
    let pitch = -((height - 1.0) / horiz).atan().to_degrees();
    Camera { position: Point3::new(c.x, height, c.y), yaw_deg: yaw_of(look - c), pitch_deg: pitch }
}

/// A program with its room, motion and a label: `program` is SPLIT:INDEX of the dataset or a
/// recorder metadata JSON (`seed` generates its room when there is no dataset).
pub fn resolve(program: &str, dataset: &Path, seed: u64) -> anyhow::Result<(Scene, Program, Motion, String)> {
    let ds = Dataset::open(dataset, Verify::Quick).ok();
    if let Some((split, i)) = parse_ref(program) {
        let ds =
            ds.as_ref().with_context(|| format!("{}: no dataset to take program {program} from", dataset.display()))?;
        let (p, m) = dataset_program(ds, split, i)?;
        let scene = ds.scene(p.scene_id())?;
        let label = format!("{} {}:{} → {}", p.scene, split.name(), i, p.target.name());
        Ok((scene, p, m, label))
    } else {
        from_metadata(program, seed, ds.as_ref())
    }
}

pub fn replay(a: ReplayArgs) -> anyhow::Result<()> {
    let (scene, program, motion, label) = resolve(&a.program, &a.dataset, a.seed)?;
    let (motion, label) = match a.intervention {
        Some(k) => {
            anyhow::ensure!(
                k < gesture::INTERVENTIONS,
                "--intervention: {k} is not one of 0..{}",
                gesture::INTERVENTIONS
            );
            (gesture::intervention(k), format!("{label}; intervention: {}", gesture::INTERVENTION_NAMES[k]))
        }
        None => (motion, label),
    };
    std::fs::create_dir_all(a.out.join("frames"))?;
    let env = EnvConfig::default();
    let mut start = program.robot_start();
    if a.robot_faces_person {
        start.yaw = yaw_of(program.human_xz() - start.xz());
    }
    let robot = start.camera(&env);
    let person = Point3::from(program.human_pos);
    let above = above_camera(&scene, person, program.target_center());
    let human = Humanoid::seeded(program.seed);
    let frames: Vec<usize> = (0..gesture::FRAMES).step_by(a.every.max(1)).collect();
    let cfg = RenderConfig { width: a.size, height: a.size, fov_deg: 90.0, max_views_per_submit: 2 };
    let mut r = Renderer::new(&cfg)?;
    let h = r.upload_scene(&scene.parts());
    let px = (a.size * a.size) as usize;
    let mut gif_frames = Vec::with_capacity(frames.len());
    for (n, &f) in frames.iter().enumerate() {
        let pose = human.pose(motion.frame(f), person, program.human_yaw);
        let parts = human.parts(&pose);
        let mut rgb = [vec![0u8; px * 3], vec![0u8; px * 3]];
        let mut depth = [vec![0u16; px], vec![0u16; px]];
        let views =
            [View { scene: h, camera: robot, dynamic: &parts }, View { scene: h, camera: above, dynamic: &parts }];
        {
            let [r0, r1] = &mut rgb;
            let [d0, d1] = &mut depth;
            let mut outs = [ViewOut { rgb: r0, depth: d0, ids: None }, ViewOut { rgb: r1, depth: d1, ids: None }];
            r.render(&views, &mut outs)?;
        }
        let [r0, r1] = rgb;
        let robot_img = RgbImage::from_raw(a.size, a.size, r0).expect("size");
        let above_img = RgbImage::from_raw(a.size, a.size, r1).expect("size");
        robot_img.save(a.out.join("frames").join(format!("robot_{n:03}.png")))?;
        above_img.save(a.out.join("frames").join(format!("above_{n:03}.png")))?;
        gif_frames.push(side_by_side(&robot_img, &above_img));
    }
    crate::report::trajectory::write_gif(&a.out.join("replay.gif"), &gif_frames, 1000 * a.every.max(1) as u32 / 30)?;
    std::fs::write(
        a.out.join("README.txt"),
        format!("{label}\nleft: the robot's start view; right: from above\n{} frames\n", frames.len()),
    )?;
    println!("{label}: {} frames (robot view + from above) and replay.gif in {}", frames.len(), a.out.display());
    Ok(())
}

/// An original-format metadata JSON (e.g. the recorder's own), replayed in our room of that
/// scene type and number. The robot starts 2.5 m in front of the person, facing them.
fn from_metadata(program: &str, seed: u64, ds: Option<&Dataset>) -> anyhow::Result<(Scene, Program, Motion, String)> {
    let path = Path::new(program);
    anyhow::ensure!(
        path.is_file(),
        "{program}: neither SPLIT:INDEX (train, val or test, e.g. val:61) nor a recorder metadata JSON file"
    );
    let meta = Metadata::load(path)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let beside = path.with_extension("csv");
    let motion_path =
        [dir.join(&meta.motion), beside.clone()].into_iter().find(|p| p.is_file()).with_context(|| {
            format!(
                "{}: motion not found at {} nor {}",
                path.display(),
                dir.join(&meta.motion).display(),
                beside.display()
            )
        })?;
    let motion = read_csv(&motion_path)?;
    let t = SceneType::from_name(&meta.scene_type)
        .with_context(|| format!("{}: field `sceneType`: `{}` is not a scene type", path.display(), meta.scene_type))?;
    anyhow::ensure!(
        (1..=30).contains(&meta.scene_num),
        "{}: field `sceneNum`: {} is not in 1..=30",
        path.display(),
        meta.scene_num
    );
    let id = SceneId::new(t, meta.scene_num as u32);
    let scene = match ds {
        Some(ds) => ds.scene(id)?,
        None => worker::scene::generate::generate(id, seed),
    };
    let human = meta.human_position();
    let yaw = meta.human_yaw_deg();
    let fwd = worker::geometry::heading(yaw);
    let start = Vector2::new(human.x, human.z) + fwd * 2.5;
    let robot_yaw = yaw_of(Vector2::new(human.x, human.z) - start);
    let target = meta.target_position();
    let category = worker::scene::Category::from_name(&meta.target_type).unwrap_or(worker::scene::Category::Cup);
    let program = Program {
        id: 0,
        scene: id.name(),
        scene_type: t,
        target: category,
        target_object: 0,
        target_pos: [target.x, target.y, target.z],
        instances: 1,
        human_pos: [human.x, 0.0, human.z],
        human_yaw: yaw,
        robot_pos: [start.x, 0.0, start.y],
        robot_yaw,
        geodesic: 0.0,
        target_geodesic: 0.0,
        starts_successful: false,
        robot_human_distance: 2.5,
        gesture_accuracy: gesture::accuracy(&motion, human, yaw, target, gesture::DEFAULT_RADIUS),
        hand: worker::program::Hand::Right,
        style: 0,
        seed: 0,
    };
    let label = format!(
        "{} ({}): \"{}\", gesture accuracy {:.2}",
        path.display(),
        id.name(),
        meta.instruction,
        program.gesture_accuracy
    );
    Ok((scene, program, motion, label))
}

fn side_by_side(a: &RgbImage, b: &RgbImage) -> RgbImage {
    let (w, h) = a.dimensions();
    let gap = 4;
    let mut out = RgbImage::from_pixel(2 * w + gap, h, Rgb([255, 255, 255]));
    image::imageops::overlay(&mut out, a, 0, 0);
    image::imageops::overlay(&mut out, b, (w + gap) as i64, 0);
    out
}
