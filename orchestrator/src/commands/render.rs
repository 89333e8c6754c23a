//! `orchestrator render --scene FloorPlan201 --out DIR`: what the robot sees from a spot in a room
//! (RGB and depth, four headings or one given pose) and a top-down map with the reachable grid.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nalgebra::Point2;

use farm::config::EnvConfig;
use worker::camera::Camera;
use worker::dataset::{Dataset, Verify};
use worker::nav::{GRID_STEP, NavGrid};
use worker::physics::{Physics, RobotBody};
use worker::render::{RenderConfig, Renderer, View, ViewOut};
use worker::scene::{Scene, SceneId};

use crate::report::map::TopDownMap;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Room name (FloorPlan1 … FloorPlan430) or a scene JSON file.
    #[arg(long)]
    pub scene: String,
    /// Folder to write PNGs into.
    #[arg(long)]
    pub out: PathBuf,
    /// Take the room from this dataset (else it is generated from --seed).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Robot position x, z (metres) and yaw (degrees); default: the free spot nearest the
    /// room's centre, looking four ways.
    #[arg(long, num_args = 3, value_names = ["X", "Z", "YAW"], allow_hyphen_values = true)]
    pub pose: Option<Vec<f32>>,
    #[arg(long, default_value_t = 224)]
    pub width: u32,
    #[arg(long, default_value_t = 224)]
    pub height: u32,
}

fn load_scene(a: &RenderArgs) -> anyhow::Result<Scene> {
    if a.scene.ends_with(".json") {
        return Ok(Scene::load(std::path::Path::new(&a.scene))?);
    }
    let id = SceneId::parse(&a.scene)
        .with_context(|| format!("--scene: `{}` is not a room name like FloorPlan201 or a .json file", a.scene))?;
    match &a.dataset {
        Some(d) => Ok(Dataset::open(d, Verify::Quick)?.scene(id)?),
        None => Ok(worker::scene::generate::generate(id, a.seed)),
    }
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    let scene = load_scene(&a)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let env = EnvConfig::default();
    let parts = scene.parts();
    let physics = Physics::new(&parts, RobotBody { radius: env.robot_radius, height: env.robot_height });
    let grid = NavGrid::build(&physics, &scene.room, GRID_STEP);
    let (label, largest) = grid.components();
    let main: Vec<usize> = grid.free_cells().filter(|&c| Some(label[c]) == largest).collect();

    let poses: Vec<(f32, f32, f32)> = match &a.pose {
        Some(p) => vec![(p[0], p[1], p[2])],
        None => {
            let c = main
                .iter()
                .copied()
                .min_by(|&x, &y| grid.point(x).coords.norm().total_cmp(&grid.point(y).coords.norm()))
                .with_context(|| format!("{}: the robot fits nowhere in this room", scene.name))?;
            let p = grid.point(c);
            [0.0, 90.0, 180.0, 270.0].iter().map(|&y| (p.x, p.y, y)).collect()
        }
    };
    for &(x, z, _) in &poses {
        if !physics.robot_fits(Point2::new(x, z)) {
            eprintln!("warning: the robot does not fit at ({x}, {z}); rendering from there anyway");
        }
    }

    let cfg =
        RenderConfig { width: a.width, height: a.height, fov_deg: env.fov_deg, max_views_per_submit: poses.len() };
    let mut renderer = Renderer::new(&cfg)?;
    let handle = renderer.upload_scene(&parts);
    let px = (a.width * a.height) as usize;
    let mut rgb = vec![vec![0u8; px * 3]; poses.len()];
    let mut depth = vec![vec![0u16; px]; poses.len()];
    let views: Vec<View> = poses
        .iter()
        .map(|&(x, z, yaw)| View {
            scene: handle,
            camera: Camera::new(nalgebra::Point3::new(x, env.camera_height, z), yaw),
            dynamic: &[],
        })
        .collect();
    let mut outs: Vec<ViewOut> =
        rgb.iter_mut().zip(depth.iter_mut()).map(|(r, d)| ViewOut { rgb: r, depth: d, ids: None }).collect();
    renderer.render(&views, &mut outs)?;
    drop(outs);
    for (i, &(_, _, yaw)) in poses.iter().enumerate() {
        let tag = format!("yaw{:03}", yaw.round() as i32);
        image::save_buffer(a.out.join(format!("rgb_{tag}.png")), &rgb[i], a.width, a.height, image::ColorType::Rgb8)?;
        // 16-bit grey: 0..10 m linear, exactly the values the robot receives
        let bytes: Vec<u8> = depth[i].iter().flat_map(|v| v.to_be_bytes()).collect();
        image::save_buffer(a.out.join(format!("depth_{tag}.png")), &bytes, a.width, a.height, image::ColorType::L16)?;
    }

    let reachable: Vec<[f32; 2]> = main.iter().map(|&c| [grid.point(c).x, grid.point(c).y]).collect();
    let mut map = TopDownMap::new(&scene, 80.0);
    map.reachable(&reachable);
    let (x, z, yaw) = poses[0];
    map.robot([x, z], yaw).title(&format!(
        "{} ({:?}): {} objects, {} reachable grid points",
        scene.name,
        scene.scene_type,
        scene.objects.len(),
        reachable.len()
    ));
    map.save_png(&a.out.join("map.png"))?;
    println!(
        "{}: wrote {} RGB + depth views and map.png to {} ({})",
        scene.name,
        poses.len(),
        a.out.display(),
        renderer.adapter_info()
    );
    Ok(())
}
