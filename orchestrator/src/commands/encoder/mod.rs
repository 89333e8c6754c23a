//! `orchestrator encoder pretrain`: renders RGB-D frames from the training rooms (`frames`),
//! writes them as one frame-set file (`farm::frame_set`), then runs `learner pretrain-encoder`
//! on it, which writes `OUT.safetensors` and `OUT.json`. `orchestrator encoder probe`: renders
//! another set (another seed) and runs `learner probe-encoder`: linear probes of each encoder.

pub mod frames;

use std::path::{Path, PathBuf};
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
    /// Linear probes of frozen encoders in held-out rooms: the category per cell, the person's facing.
    Probe(ProbeArgs),
}

#[derive(Args, Debug)]
pub struct PretrainArgs {
    /// Output stem: OUT.safetensors (weights), OUT.json (seed, rooms, accuracy, sha256).
    #[arg(long, default_value = "encoders/contrast64")]
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
    /// `contrast`: dense contrast of two jittered views, no labels (the default encoder).
    /// `reconstruct`: RGB-D reconstruction through the feature map, no labels. `semantic`: the
    /// semantic sensor, trained on the id target's categories (an ablation: it reads the answer).
    #[arg(long, default_value = "contrast", value_parser = ["contrast", "reconstruct", "semantic"])]
    pub objective: String,
    /// `rgbd`: configs/tiny's early-fusion encoder. `resnet18`: configs/faithful's ResNet-18 (RGB
    /// and depth apart, torchvision's names; contrast only; `--size 224`, best with `--device
    /// cuda`), for `model.resnet_weights` where no ImageNet checkpoint is supplied.
    #[arg(long, default_value = "rgbd", value_parser = ["rgbd", "resnet18"])]
    pub trunk: String,
    /// Reconstruction: the share of 8×8-pixel cells hidden from the encoder in each frame.
    #[arg(long, default_value_t = 0.0)]
    pub mask: f64,
    #[command(flatten)]
    pub rooms: Rooms,
    /// Keep the rendered frames (OUT.frames) after training.
    #[arg(long)]
    pub keep_frames: bool,
    /// Training device: cpu (reproducible, the default), cuda or auto.
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// Where frames are rendered and which `learner` trains or probes on them.
#[derive(Args, Debug)]
pub struct Rooms {
    /// Renderer threads (default: one per core; the frames do not depend on it).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Take the rooms from this dataset; without one there, they are generated from --room-seed.
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Seed the rooms are generated from when there is no dataset (`dataset build`'s default: 1).
    #[arg(long, default_value_t = 1)]
    pub room_seed: u64,
    /// Folder holding the `learner` program (default: beside this one, or GESTHOR_BIN_DIR).
    #[arg(long)]
    pub bin_dir: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct ProbeArgs {
    /// NAME=WEIGHTS (an encoder's .safetensors), once per encoder; NAME=pixels probes the raw cells.
    #[arg(long = "encoder", required = true)]
    pub encoders: Vec<String>,
    /// Output stem: OUT.md (the table) and OUT.json.
    #[arg(long, default_value = "encoders/probes")]
    pub out: PathBuf,
    /// Frames to render (a tenth of them in the held-out rooms).
    #[arg(long, default_value_t = 8_000)]
    pub frames: usize,
    /// Frame width = height; the encoders' must match.
    #[arg(long, default_value_t = 64)]
    pub size: u32,
    /// Seed of the frames and the probes (not the encoders' 1: other poses than they trained on).
    #[arg(long, default_value_t = 2)]
    pub seed: u64,
    /// The frame set: read when it exists, else rendered there and kept (default: OUT.frames,
    /// removed afterwards).
    #[arg(long)]
    pub frame_set: Option<PathBuf>,
    #[command(flatten)]
    pub rooms: Rooms,
}

pub fn run(cmd: EncoderCmd) -> anyhow::Result<()> {
    match cmd {
        EncoderCmd::Pretrain(a) => pretrain(a),
        EncoderCmd::Probe(a) => probe(a),
    }
}

/// Where a room's scene comes from: the dataset the workers use, or the generator.
fn scene_source(
    dataset: &Path,
    room_seed: u64,
) -> anyhow::Result<Box<dyn Fn(SceneId) -> anyhow::Result<Scene> + Sync>> {
    if dataset.join("manifest.json").is_file() {
        let ds = Dataset::open(dataset, Verify::Quick)?;
        eprintln!("rooms from the dataset in {}", dataset.display());
        Ok(Box::new(move |id| Ok(ds.scene(id)?)))
    } else {
        eprintln!("no dataset in {}: rooms generated from seed {room_seed}", dataset.display());
        Ok(Box::new(move |id| Ok(worker::scene::generate::generate(id, room_seed))))
    }
}

/// Renders `frames` frames of `size`² from `seed` in the training rooms into `path`, with a
/// progress bar.
fn render_to(rooms: &Rooms, frames: usize, size: u32, seed: u64, path: &Path) -> anyhow::Result<()> {
    let threads = rooms.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).max(1);
    let opts = FrameOptions { frames, size, seed, threads };
    let scene_of = scene_source(&rooms.dataset, rooms.room_seed)?;
    let bar = Bar::new("render", opts.frames as u64, "frames", Duration::from_secs(10));
    let finished = AtomicUsize::new(0);
    let done = |n: usize| {
        let before = finished.fetch_add(n, Ordering::Relaxed);
        bar.set((before + n) as u64, "");
    };
    let t = Instant::now();
    let set = render_set(&opts, scene_of.as_ref(), &done)?;
    bar.finish();
    let secs = t.elapsed().as_secs_f64();
    set.write(path)?;
    let persons = set.flags.iter().filter(|&&f| f & farm::frame_set::FLAG_PERSON != 0).count();
    eprintln!(
        "rendered {} frames of {}×{} in {secs:.1} s ({:.0} frames/s, {} with the person) into {}",
        set.len(),
        opts.size,
        opts.size,
        set.len() as f64 / secs,
        persons,
        path.display()
    );
    Ok(())
}

/// The `learner` program, with torch's threads waiting passively.
pub(crate) fn learner_command(bin_dir: Option<&Path>) -> anyhow::Result<(PathBuf, std::process::Command)> {
    let learner = crate::supervise::binaries::sibling_in(bin_dir, "learner")?;
    let mut learn = std::process::Command::new(&learner);
    // the learner's thread waiting (`child::learner_env`): the same weights, sooner on busy cores
    learn.envs(crate::supervise::child::learner_env());
    Ok((learner, learn))
}

fn pretrain(a: PretrainArgs) -> anyhow::Result<()> {
    let (learner, mut learn) = learner_command(a.rooms.bin_dir.as_deref())?;
    anyhow::ensure!((0.0..1.0).contains(&a.mask), "--mask {}: a share of cells in 0..1", a.mask);
    let t = Instant::now();
    let frames_path = with_ext(&a.out, "frames");
    render_to(&a.rooms, a.frames, a.size, a.seed, &frames_path)?;
    let status = learn
        .args(["--device", &a.device, "pretrain-encoder", "--frames"])
        .arg(&frames_path)
        .arg("--out")
        .arg(&a.out)
        .args(["--seed", &a.seed.to_string(), "--epochs", &a.epochs.to_string()])
        .args(["--objective", &a.objective, "--trunk", &a.trunk, "--mask", &a.mask.to_string()])
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

fn probe(a: ProbeArgs) -> anyhow::Result<()> {
    let (learner, mut learn) = learner_command(a.rooms.bin_dir.as_deref())?;
    for e in &a.encoders {
        let (_, weights) = e.split_once('=').with_context(|| format!("--encoder {e}: NAME=WEIGHTS or NAME=pixels"))?;
        anyhow::ensure!(weights == "pixels" || Path::new(weights).is_file(), "--encoder {e}: no file {weights}");
    }
    let frames_path = a.frame_set.clone().unwrap_or_else(|| with_ext(&a.out, "frames"));
    if frames_path.is_file() {
        eprintln!("probe frames from {}", frames_path.display());
    } else {
        render_to(&a.rooms, a.frames, a.size, a.seed, &frames_path)?;
    }
    learn.args(["--device", "cpu", "probe-encoder", "--frames"]).arg(&frames_path).arg("--out").arg(&a.out);
    for e in &a.encoders {
        learn.args(["--encoder", e]);
    }
    let status = learn
        .args(["--seed", &a.seed.to_string()])
        .status()
        .with_context(|| format!("starting {}", learner.display()))?;
    anyhow::ensure!(status.success(), "{} probe-encoder failed ({status})", learner.display());
    if a.frame_set.is_none() {
        std::fs::remove_file(&frames_path).with_context(|| format!("removing {}", frames_path.display()))?;
    }
    println!("probes in {} and {}", with_ext(&a.out, "md").display(), with_ext(&a.out, "json").display());
    Ok(())
}
