//! `orchestrator encoder pretrain`: renders labelled RGB-D frames from the training rooms
//! (`frames`), writes them as one frame-set file (`farm::frame_set`), then runs
//! `learner pretrain-encoder` on it, which writes `OUT.safetensors` and `OUT.json`.

pub mod frames;

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Args, Subcommand};

use farm::files::with_ext;
use farm::rooms::SceneId;
use worker::dataset::{Dataset, Verify};
use worker::scene::Scene;

use crate::report::progress::Bar;
use frames::{FrameOptions, render_set};

#[derive(Subcommand, Debug)]
pub enum EncoderCmd {
    /// Render frames from the training rooms and pretrain the frozen RGB-D encoder on them.
    Pretrain(PretrainArgs),
}

#[derive(Args, Debug)]
pub struct PretrainArgs {
    /// Output stem: OUT.safetensors (weights), OUT.json (seed, rooms, accuracy, sha256).
    #[arg(long, default_value = "encoders/rgbd64")]
    pub out: PathBuf,
    /// Frames to render (a tenth of them in the held-out rooms).
    #[arg(long, default_value_t = 16_000)]
    pub frames: usize,
    /// Frame width = height (a multiple of 8); a run's `env.width` must match it.
    #[arg(long, default_value_t = 64)]
    pub size: u32,
    /// Seed of the frames and of the training.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Passes over the training frames.
    #[arg(long, default_value_t = 12)]
    pub epochs: usize,
    /// Renderer threads (default: one per core; the frames do not depend on it).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Take the rooms from this dataset; without one there, they are generated from --room-seed.
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Seed the rooms are generated from when there is no dataset (`dataset build`'s default: 1).
    #[arg(long, default_value_t = 1)]
    pub room_seed: u64,
    /// Keep the rendered frames (OUT.frames) after training.
    #[arg(long)]
    pub keep_frames: bool,
    /// Training device: cpu (reproducible, the default), cuda or auto.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Folder holding the `learner` program (default: beside this one, or GESTHOR_BIN_DIR).
    #[arg(long)]
    pub bin_dir: Option<PathBuf>,
}

/// OpenMP's wait policy for torch's threads. Spinning (the default) wastes the cores a
/// shared machine's other processes need: passive waiting trained 3–4× faster on two busy cores
/// (same weights).
const OMP_WAIT_ENV: &str = "OMP_WAIT_POLICY";

pub fn run(cmd: EncoderCmd) -> anyhow::Result<()> {
    match cmd {
        EncoderCmd::Pretrain(a) => pretrain(a),
    }
}

/// Where a room's scene comes from: the dataset the workers use, or the generator.
fn scene_source(a: &PretrainArgs) -> anyhow::Result<Box<dyn Fn(SceneId) -> anyhow::Result<Scene> + Sync>> {
    if a.dataset.join("manifest.json").is_file() {
        let ds = Dataset::open(&a.dataset, Verify::Quick)?;
        eprintln!("rooms from the dataset in {}", a.dataset.display());
        Ok(Box::new(move |id| Ok(ds.scene(id)?)))
    } else {
        eprintln!("no dataset in {}: rooms generated from seed {}", a.dataset.display(), a.room_seed);
        let seed = a.room_seed;
        Ok(Box::new(move |id| Ok(worker::scene::generate::generate(id, seed))))
    }
}

fn pretrain(a: PretrainArgs) -> anyhow::Result<()> {
    let learner = crate::supervise::binaries::sibling_in(a.bin_dir.as_deref(), "learner")?;
    let scene_of = scene_source(&a)?;
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let opts = FrameOptions { frames: a.frames, size: a.size, seed: a.seed, threads: threads.max(1) };

    let bar = Bar::new("render", a.frames as u64, "frames", Duration::from_secs(10));
    let finished = AtomicUsize::new(0);
    let done = |n: usize| {
        let before = finished.fetch_add(n, Ordering::Relaxed);
        bar.set((before + n) as u64, "");
    };
    let t = Instant::now();
    let set = render_set(&opts, scene_of.as_ref(), &done)?;
    bar.finish();
    let secs = t.elapsed().as_secs_f64();
    let frames_path = with_ext(&a.out, "frames");
    set.write(&frames_path)?;
    let persons = set.flags.iter().filter(|&&f| f & farm::frame_set::FLAG_PERSON != 0).count();
    eprintln!(
        "rendered {} frames of {}×{} in {secs:.1} s ({:.0} frames/s, {} with the person) into {}",
        set.len(),
        a.size,
        a.size,
        set.len() as f64 / secs,
        persons,
        frames_path.display()
    );
    drop(set);

    let mut learn = std::process::Command::new(&learner);
    if std::env::var_os(OMP_WAIT_ENV).is_none() {
        learn.env(OMP_WAIT_ENV, "PASSIVE");
    }
    let status = learn
        .args(["--device", &a.device, "pretrain-encoder", "--frames"])
        .arg(&frames_path)
        .arg("--out")
        .arg(&a.out)
        .args(["--seed", &a.seed.to_string(), "--epochs", &a.epochs.to_string()])
        .status()
        .with_context(|| format!("starting {}", learner.display()))?;
    anyhow::ensure!(status.success(), "{} pretrain-encoder failed ({status})", learner.display());
    if !a.keep_frames {
        std::fs::remove_file(&frames_path).with_context(|| format!("removing {}", frames_path.display()))?;
    }
    println!(
        "encoder weights {} and report {} ({:.0} s in all)",
        with_ext(&a.out, "safetensors").display(),
        with_ext(&a.out, "json").display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
