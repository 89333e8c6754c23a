//! Trajectory pictures like Figs 4.2/4.3: a top-down map of an episode (path, person, target
//! instance, the other instances of its category, where intervention gestures were shown, where
//! the robot stopped) and an animated GIF of the robot's view with the gesture state.
//!
//! The learner records the pose, action and perceived gesture of every step of an evaluation
//! episode (`trajectories.jsonl`); the views are re-rendered here from those poses.

use std::path::Path;

use anyhow::Context;
use image::{Rgb, RgbImage};
use nalgebra::Point3;

use farm::config::RunConfig;
use farm::metrics::Trajectory;
use worker::dataset::Dataset;
use worker::gesture::{self, Motion};
use worker::humanoid::Humanoid;
use worker::program::Program;
use worker::render::{RenderConfig, Renderer, View, ViewOut};
use worker::robot::{Action, RobotPose};
use worker::scene::Split;

use super::map::TopDownMap;
use super::tables::{EvalMode, Evaluation};

pub fn read(path: &Path) -> anyhow::Result<Vec<Trajectory>> {
    farm::files::read_jsonl(path)
}

/// Picks `n` episodes to draw: successes and failures alternately, preferring episodes that
/// saw intervention gestures and targets with several instances (the interesting cases).
pub fn choose(trajs: &[Trajectory], programs: &[Program], n: usize) -> Vec<usize> {
    let score = |t: &Trajectory| {
        let iv = t.steps.iter().filter(|s| s.gesture == 2).count().min(10);
        let multi = (programs[t.program as usize].instances > 1) as usize;
        iv + 5 * multi
    };
    let mut wins: Vec<usize> = (0..trajs.len()).filter(|&i| trajs[i].success).collect();
    let mut losses: Vec<usize> = (0..trajs.len()).filter(|&i| !trajs[i].success).collect();
    wins.sort_by_key(|&i| (std::cmp::Reverse(score(&trajs[i])), trajs[i].program));
    losses.sort_by_key(|&i| (std::cmp::Reverse(score(&trajs[i])), trajs[i].program));
    let mut out = Vec::new();
    let (mut w, mut l) = (wins.into_iter(), losses.into_iter());
    while out.len() < n {
        match (w.next(), l.next()) {
            (None, None) => break,
            (a, b) => out.extend(a.into_iter().chain(b).take(n - out.len())),
        }
    }
    out
}

/// The top-down map of one episode.
pub fn map(ds: &Dataset, p: &Program, t: &Trajectory, title: &str) -> anyhow::Result<TopDownMap> {
    let scene = ds.scene(p.scene_id())?;
    let mut m = TopDownMap::new(&scene, 90.0);
    let path: Vec<[f32; 2]> = t.steps.iter().map(|s| [s.x, s.z]).collect();
    let stops: Vec<[f32; 2]> = t.steps.iter().filter(|s| s.action == Action::Stop as u8).map(|s| [s.x, s.z]).collect();
    let interventions: Vec<[f32; 2]> = t.steps.iter().filter(|s| s.gesture == 2).map(|s| [s.x, s.z]).collect();
    let others: Vec<usize> = scene.instances(p.target).filter(|&i| i != p.target_object).collect();
    m.path(&path)
        .person([p.human_pos[0], p.human_pos[2]], p.human_yaw)
        .target(p.target_object)
        .other_instances(&others);
    if !interventions.is_empty() {
        m.interventions(&interventions);
    }
    if !stops.is_empty() {
        m.stops(&stops);
    }
    if let Some(s) = t.steps.first() {
        m.robot([s.x, s.z], s.yaw);
    }
    m.title(title);
    Ok(m)
}

const GESTURE_COLOURS: [[u8; 3]; 3] = [[120, 120, 120], [40, 110, 220], [220, 60, 40]];

/// Frames of the robot's view along the episode, each with a band showing the gesture state.
pub fn views(cfg: &RunConfig, ds: &Dataset, p: &Program, t: &Trajectory, size: u32) -> anyhow::Result<Vec<RgbImage>> {
    let scene = ds.scene(p.scene_id())?;
    let file = ds.require(cfg.run.split)?;
    let referencing = Motion::from_flat(&file.motion(p.id as usize)).context("motion size")?;
    let human = Humanoid::seeded(p.seed);
    let rcfg = RenderConfig { width: size, height: size, fov_deg: cfg.env.fov_deg, max_views_per_submit: 1 };
    let mut r = Renderer::new(&rcfg)?;
    let h = r.upload_scene(&scene.parts());
    let px = (size * size) as usize;
    let band = (size / 12).max(8);
    let mut frames = Vec::with_capacity(t.steps.len());
    for (i, s) in t.steps.iter().enumerate() {
        let motion = if s.gesture == 2 {
            gesture::intervention(s.intervention as usize % gesture::INTERVENTIONS)
        } else {
            referencing.clone()
        };
        let f = if s.gesture == 0 { 0 } else { (i * 3) % gesture::FRAMES };
        let pose = human.pose(motion.frame(f), Point3::from(p.human_pos), p.human_yaw);
        let parts = human.parts(&pose);
        let cam = RobotPose { x: s.x, z: s.z, yaw: s.yaw }.camera(&cfg.env);
        let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
        r.render(
            &[View { scene: h, camera: cam, dynamic: &parts }],
            &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }],
        )?;
        let view = RgbImage::from_raw(size, size, rgb).expect("size");
        let mut frame = RgbImage::from_pixel(size, size + band, Rgb([255, 255, 255]));
        image::imageops::overlay(&mut frame, &view, 0, band as i64);
        let g = (s.gesture as usize).min(2);
        // the band: gesture state as colour, progress through the episode as its length
        let len = ((i + 1) as f32 / t.steps.len() as f32 * size as f32) as u32;
        for y in 0..band {
            for x in 0..size {
                let c = if x < len { GESTURE_COLOURS[g] } else { [235, 235, 235] };
                frame.put_pixel(x, y, Rgb(c));
            }
        }
        if s.action == Action::Stop as u8 {
            // a white frame around the view where the robot stopped
            for x in 0..size {
                for y in [band, band + 1, size + band - 2, size + band - 1] {
                    frame.put_pixel(x, y, Rgb([255, 255, 255]));
                }
            }
        }
        frames.push(frame);
    }
    Ok(frames)
}

/// The episode `t` of the one program of dataset `one` (`write_subset`'s) as a GIF: the robot's
/// view re-rendered at each step's pose beside the episode's top-down map, also written as
/// `map.png` beside the GIF.
pub fn write_program_gif(
    cfg: &RunConfig,
    one: &Path,
    split: Split,
    t: &Trajectory,
    title: &str,
    gif: &Path,
) -> anyhow::Result<()> {
    let ds = Dataset::open(one, worker::dataset::Verify::Quick)?;
    let p = ds.program(split, 0).context("the one program")?;
    let map_png = gif.with_file_name("map.png");
    map(&ds, &p, t, title)?.save_png(&map_png)?;
    let map_img = image::open(&map_png)?.to_rgb8();
    let views = views(cfg, &ds, &p, t, 240)?;
    let h = views.first().map_or(240, |v| v.height());
    let map_img = image::imageops::resize(
        &map_img,
        map_img.width() * h / map_img.height().max(1),
        h,
        image::imageops::FilterType::Triangle,
    );
    let frames: Vec<RgbImage> = views
        .iter()
        .map(|v| {
            let mut f = RgbImage::from_pixel(v.width() + map_img.width(), h, Rgb([255, 255, 255]));
            image::imageops::overlay(&mut f, v, 0, 0);
            image::imageops::overlay(&mut f, &map_img, v.width() as i64, 0);
            f
        })
        .collect();
    write_gif(gif, &frames, 150)
}

/// Draws the chosen episodes of an evaluation's normal pass into `out/trajectories/`; returns
/// the maps written.
pub fn draw(
    cfg: &RunConfig,
    ds: &Dataset,
    split: Split,
    ev: &Evaluation,
    _checkpoint: Option<&Path>,
    out: &Path,
    n: usize,
) -> anyhow::Result<Vec<std::path::PathBuf>> {
    let path = out.join(EvalMode::Normal.name()).join("trajectories.jsonl");
    let trajs = read(&path)?;
    let dir = out.join("trajectories");
    std::fs::create_dir_all(&dir)?;
    let picks = choose(&trajs, ev.programs, n);
    let mut maps = Vec::with_capacity(picks.len());
    let mut md = String::from(
        "# Trajectories\n\nTop-down maps: path (blue), person and where they face, the target instance (ring), other instances of its category (thin rings), stops (squares), steps with an intervention gesture (red). GIFs: the robot's view; the band shows the gesture it perceives (blue referencing, red intervention, grey none).\n\n",
    );
    for (k, &i) in picks.iter().enumerate() {
        let t = &trajs[i];
        let p = &ev.programs[t.program as usize];
        let title = format!(
            "{} {}:{} target {} ({} instance{}) — {} in {} steps",
            p.scene,
            split.name(),
            p.id,
            p.target.name(),
            p.instances,
            if p.instances == 1 { "" } else { "s" },
            if t.success { "success" } else { "failure" },
            t.steps.len().saturating_sub(1)
        );
        let name = format!("{k:02}_{}_{:06}", if t.success { "success" } else { "failure" }, p.id);
        let png = dir.join(format!("{name}.png"));
        map(ds, p, t, &title)?.save_png(&png)?;
        maps.push(png);
        let frames = views(cfg, ds, p, t, 160)?;
        write_gif(&dir.join(format!("{name}.gif")), &frames, 150)?;
        md += &format!("## {title}\n\n![map]({name}.png) ![view]({name}.gif)\n\n");
    }
    farm::files::write_atomic(&dir.join("README.md"), md.as_bytes())?;
    eprintln!("[eval] drew {} trajectories in {}", picks.len(), dir.display());
    Ok(maps)
}

pub fn write_gif(path: &Path, frames: &[RgbImage], delay_ms: u32) -> anyhow::Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let tmp = path.with_extension("gif.partial");
    {
        let f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        let mut enc = GifEncoder::new_with_speed(f, 20);
        enc.set_repeat(Repeat::Infinite)?;
        for fr in frames {
            let rgba = image::DynamicImage::ImageRgb8(fr.clone()).to_rgba8();
            enc.encode_frame(image::Frame::from_parts(rgba, 0, 0, image::Delay::from_numer_denom_ms(delay_ms, 1)))?;
        }
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}
