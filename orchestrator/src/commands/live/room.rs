//! A program the person places on the page: a room of a split, one of its reachable targets,
//! where the person stands and where the robot starts. The person faces the target and points at
//! it with a referencing gesture synthesised as the dataset's were (its seed drawn from the
//! dataset's and the placement); the program is checked as a built one is
//! (`worker::dataset::build::with_poses`: the person sees the target, the robot can reach it).

use anyhow::Context;
use nalgebra::{Point2, Point3};

use farm::config::EnvConfig;
use farm::seed;
use worker::dataset::Dataset;
use worker::dataset::build::{RoomContext, synthesize, with_poses};
use worker::geometry::{wrap_deg, yaw_of};
use worker::gesture::Motion;
use worker::program::Program;
use worker::robot::RobotPose;
use worker::scene::{SceneId, Split};

use super::picture::png_base64;
use super::wire::{Placement, RoomView, TargetView};
use crate::report::map::TopDownMap;

const PLACED_KEY: u64 = 0x11FE_0001;

/// Each split's rooms, in the order its programs first use them.
pub fn rooms(ds: &Dataset) -> Vec<(String, Vec<String>)> {
    ds.manifest
        .splits
        .keys()
        .filter_map(|name| {
            let split = Split::from_name(name)?;
            let file = ds.split(split)?;
            let mut rooms: Vec<String> = Vec::new();
            for i in 0..file.len() {
                let scene = ds.program(split, i)?.scene;
                if !rooms.contains(&scene) {
                    rooms.push(scene);
                }
            }
            Some((name.clone(), rooms))
        })
        .collect()
}

/// The room `room` of split `split`, checked against the dataset.
fn room_of(ds: &Dataset, split: &str, room: &str) -> anyhow::Result<(Split, SceneId)> {
    let s = Split::from_name(split).with_context(|| format!("split `{split}`: train, val or test"))?;
    let id = SceneId::parse(room).with_context(|| format!("room `{room}` is not a room's name (e.g. FloorPlan21)"))?;
    anyhow::ensure!(id.split() == s, "room {room} is not one of split {split}'s rooms");
    ds.require(s)?;
    Ok((s, id))
}

/// A room from above and its reachable targets.
pub fn view(ds: &Dataset, split: &str, room: &str) -> anyhow::Result<RoomView> {
    let (_, id) = room_of(ds, split, room)?;
    let scene = ds.scene(id).with_context(|| format!("room {room}"))?;
    let ctx = RoomContext::new(id, scene, &EnvConfig::default(), ds.manifest.build.success_distance);
    let map = TopDownMap::new(&ctx.scene, 60.0);
    let targets = ctx
        .targets
        .iter()
        .map(|(&object, t)| TargetView { object, name: t.category.name().into(), at: [t.center.x, t.center.z] })
        .collect();
    Ok(RoomView {
        split: split.into(),
        room: room.into(),
        map_png: png_base64(&map.to_rgb_image())?,
        map_transform: map.transform(),
        targets,
    })
}

/// The program `placed` describes, its split and the person's referencing gesture.
pub fn program(ds: &Dataset, placed: &Placement) -> anyhow::Result<(Split, Program, Motion)> {
    let (split, id) = room_of(ds, &placed.split, &placed.room)?;
    let scene = ds.scene(id).with_context(|| format!("room {}", placed.room))?;
    // whether the robot can reach and see it, with_poses checks below
    let t = scene
        .objects
        .get(placed.target)
        .with_context(|| format!("target {}: {} has no such object", placed.target, placed.room))?;
    let (category, center) = (t.category, t.center());
    let [x, z] = placed.person;
    let [rx, rz, ryaw] = placed.robot;
    anyhow::ensure!(
        [x, z, rx, rz, ryaw].iter().all(|v| v.is_finite()),
        "the person's or the robot's place is not a number"
    );
    let human = Point2::new(x, z);
    let human_yaw = wrap_deg(yaw_of(Point2::new(center.x, center.z) - human).round());
    let at_cm = |v: f32| (v * 100.0).round() as i64 as u64;
    let key = [PLACED_KEY, id.floorplan() as u64, placed.target as u64, at_cm(x), at_cm(z)];
    let program_seed = seed::mix(ds.manifest.build.seed, &key);
    let pointing = ds.manifest.build.pointing;
    let s = synthesize(pointing, program_seed, Point3::new(x, 0.0, z), human_yaw, center);
    let placed_program = Program {
        id: 0,
        scene: id.name(),
        scene_type: id.scene_type,
        target: category,
        target_object: placed.target,
        target_pos: [center.x, center.y, center.z],
        instances: scene.instances(category).count() as u32,
        human_pos: [x, 0.0, z],
        human_yaw,
        robot_pos: [rx, 0.0, rz],
        robot_yaw: wrap_deg(ryaw),
        // with_poses measures these
        geodesic: 0.0,
        target_geodesic: 0.0,
        starts_successful: false,
        robot_human_distance: 0.0,
        gesture_accuracy: s.accuracy,
        hand: s.hand,
        style: s.style,
        seed: program_seed,
    };
    let robot = RobotPose { x: rx, z: rz, yaw: ryaw };
    let p = with_poses(&scene, &placed_program, None, Some(robot), ds.manifest.build.success_distance)
        .map_err(|e| anyhow::anyhow!("the program placed in {}: {e}", placed.room))?;
    let motion = Motion::from_flat(&s.motion).context("the synthesised motion's size")?;
    Ok((split, p, motion))
}
