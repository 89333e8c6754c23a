//! `orchestrator bench sim`: the simulator's speed on this machine, in one process.
//!
//! 1. the renderer alone: views per second at `--size` (224 by default) and 1, 8 and 16 views
//!    per submit (RGB, depth and ids read back), on a generated living room with the person
//!    in it;
//! 2. physics + task without rendering: env steps per second with random actions (visibility
//!    for Stop judged geometrically, as an env without a renderer does);
//! 3. a single-process env loop with rendering: an `EnvPool` of `--envs` envs (16) stepping
//!    random actions, each step rendering all views in one submit into an observation buffer,
//!    and the share of its time spent rendering.
//!
//! On a CPU (lavapipe) one renderer keeps about one core busy; `GESTHOR_RENDER_LANES=2
//! LP_NUM_THREADS=0` lets this one process use two (see worker::render, "Lanes").

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use clap::Args;
use rand::Rng;

use farm::config::RunConfig;
use farm::stepper::{PayloadBuf, Stepper};
use worker::dataset::build::{BuildOptions, build, default_interventions, default_synth};
use worker::dataset::{Dataset, Verify};
use worker::env::{Env, EnvPool, PoolSpec, ProgramSource, Rooms};
use worker::gesture::Motion;
use worker::humanoid::Humanoid;
use worker::program::Program;
use worker::render::{RenderConfig, Renderer, bench_views};
use worker::robot::Action;
use worker::scene::{SceneId, Split};

#[derive(Args, Debug)]
pub struct SimArgs {
    /// Seconds per measurement.
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Frame size for the rendering measurements.
    #[arg(long, default_value_t = 224)]
    pub size: u32,
    /// Envs in the rendering env loop.
    #[arg(long, default_value_t = 16)]
    pub envs: usize,
    /// Also write the table (Markdown) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: SimArgs) -> anyhow::Result<()> {
    let (mut rows, info) = renderer_alone(&a)?;
    // a small dataset for the env measurements
    let dir = tempfile::tempdir()?;
    let (ds, cfg) = small_dataset(&a, dir.path())?;
    let mut rng = farm::seed::rng(1, &[7]);
    let v = env_without_rendering(&a, &cfg, &ds, &mut rng)?;
    rows.push(("env steps, physics + task + visibility rays, no rendering".into(), v, "steps/s"));
    let (v, render_share) = env_loop(&a, &cfg, &ds, &mut rng)?;
    rows.push((format!("env loop with rendering, {} envs, {}×{} RGB-D", a.envs, a.size, a.size), v, "frames/s"));
    let mut md = format!(
        "Simulator benchmark ({info}), {:.0} s per row\n\n| measurement | rate | unit | ms each |\n|---|---:|---|---:|\n",
        a.seconds
    );
    for (name, v, unit) in &rows {
        md += &format!("| {name} | {v:.0} | {unit} | {:.3} |\n", 1000.0 / v);
    }
    md += &format!("\nThe env loop spent {:.0}% of its time rendering.\n", 100.0 * render_share);
    println!("{md}");
    if let Some(out) = a.out {
        farm::files::write_atomic(&out, md.as_bytes())?;
    }
    Ok(())
}

/// The renderer alone on one room with the person, at 1, 8 and 16 views per submit; the
/// adapter it ran on.
fn renderer_alone(a: &SimArgs) -> anyhow::Result<(Vec<(String, f64, &'static str)>, String)> {
    let mut rows: Vec<(String, f64, &str)> = Vec::new();
    let scene = worker::scene::generate::generate(SceneId::parse("FloorPlan201").unwrap(), 1);
    let mut parts = scene.parts();
    let person = Humanoid::seeded(1);
    let pose = person.pose(&worker::gesture::STANDING, nalgebra::Point3::new(0.5, 0.0, 0.5), 180.0);
    parts.extend(person.parts(&pose));
    let mut info = String::new();
    for vps in [1usize, 8, 16] {
        let cfg = RenderConfig { width: a.size, height: a.size, fov_deg: 90.0, max_views_per_submit: vps };
        let mut r = Renderer::new(&cfg)?;
        info = format!("{}, {} lane(s)", r.adapter_info(), r.lanes());
        let v = bench_views(&mut r, &parts, vps, a.seconds)?;
        eprintln!("render {vps:2} views/submit: {v:.0} views/s");
        rows.push((format!("render {}×{}, {vps} views/submit", a.size, a.size), v, "views/s"));
    }

    Ok((rows, info))
}

/// A dataset of two val programs per room in `dir`, and a config of +Both on it at the bench's size.
fn small_dataset(a: &SimArgs, dir: &Path) -> anyhow::Result<(Arc<Dataset>, RunConfig)> {
    let opts = BuildOptions { seed: 1, val_per_room: 2, splits: vec![Split::Val], ..Default::default() };
    build(dir, &opts, false, &default_synth, &default_interventions(), &|_, _, _| {})?;
    let ds = Arc::new(Dataset::open(dir, Verify::Quick)?);
    let mut cfg = RunConfig::from_toml("[run]\nmethod = \"both\"\nsplit = \"val\"\n", "bench")?;
    cfg.run.dataset = dir.to_path_buf();
    cfg.env.width = a.size;
    cfg.env.height = a.size;
    cfg.env.envs_per_worker = a.envs;

    Ok((ds, cfg))
}

/// Env steps without rendering: physics, the task and the visibility rays.
fn env_without_rendering(
    a: &SimArgs,
    cfg: &RunConfig,
    ds: &Arc<Dataset>,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> anyhow::Result<f64> {
    let file = ds.require(Split::Val)?;
    let mut rooms = Rooms::new(ds.clone(), cfg);
    let ivs = ds.interventions();
    let iv = Arc::new(Motion::from_flat(&ivs.motion(0)).expect("intervention size"));
    let next_env = |rng: &mut rand_chacha::ChaCha8Rng, rooms: &mut Rooms| -> anyhow::Result<Env> {
        let i = rng.random_range(0..file.len());
        let p = Program::from_record(i as u64, &file.record(i)).expect("valid record");
        let room = rooms.get(p.scene_id())?;
        let m = Motion::from_flat(&file.motion(i)).expect("motion size");
        Env::new(cfg, room, p, i as u64, m, (0, iv.clone()))
    };
    // warm the room cache so that the measurement is of stepping, not of loading rooms
    for id in SceneId::of_split(Split::Val) {
        rooms.get(id)?;
    }
    let mut env = next_env(rng, &mut rooms)?;
    let (mut steps, mut resets) = (0u64, 0u64);
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < a.seconds {
        env.update_visibility_geometric();
        env.step(Action::ALL[rng.random_range(0..4)]);
        steps += 1;
        if env.is_done() {
            env = next_env(rng, &mut rooms)?;
            resets += 1;
        }
    }
    let v = steps as f64 / t.elapsed().as_secs_f64();
    eprintln!("env steps without rendering: {v:.0} steps/s ({resets} episodes)");
    Ok(v)
}

/// The env loop with rendering (one worker's envs): frames/s and the share of time rendering.
fn env_loop(
    a: &SimArgs,
    cfg: &RunConfig,
    ds: &Arc<Dataset>,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> anyhow::Result<(f64, f64)> {
    let spec = PoolSpec { worker_id: 0, generation: 0, programs: ProgramSource::Sample, expert_hints: false };
    let mut pool = EnvPool::with_dataset(cfg, spec, ds.clone())?;
    let mut buf = PayloadBuf::new(&pool.layout());
    pool.reset(buf.bytes_mut())?;
    let mut actions = vec![0u8; a.envs];
    for _ in 0..3 {
        pool.step(&actions, buf.bytes_mut())?; // warm-up: first uploads of rooms
    }
    let render_ns0 = pool.render_ns();
    let t = Instant::now();
    let mut frames = 0u64;
    while t.elapsed().as_secs_f64() < a.seconds {
        for x in actions.iter_mut() {
            *x = rng.random_range(0..4);
        }
        pool.step(&actions, buf.bytes_mut())?;
        frames += a.envs as u64;
    }
    let elapsed = t.elapsed().as_secs_f64();
    let v = frames as f64 / elapsed;
    let render_share = (pool.render_ns() - render_ns0) as f64 * 1e-9 / elapsed;
    eprintln!("env loop with rendering: {v:.0} frames/s ({:.0}% of the time rendering)", 100.0 * render_share);
    Ok((v, render_share))
}
