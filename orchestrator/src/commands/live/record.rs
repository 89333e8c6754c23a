//! Every live episode recorded, the recorder's role in §3.2.3: a live session becomes data.
//!
//! ```text
//! SESSION/episode-001/dataset/      GOND's files of the one program, holding the gesture the
//!                                   person performed (the program's own or the webcam's)
//! SESSION/episode-001/config.toml   the run's config as the episode ran (one env, that dataset)
//! SESSION/episode-001/steps.jsonl   per step: the robot, the gesture shown and the angle rule's,
//!                                   the action, the policy's probabilities and value
//! SESSION/episode-001/episode.json  the program, checkpoint, gesture source, who called the
//!                                   interventions, the episode run beside it (two checkpoints
//!                                   compared: each side is an episode of its own), and the
//!                                   outcome (SR/SPL/DTS)
//! ```
//!
//! `orchestrator replay val:0 --dataset …/dataset` shows the gesture, `follow`/`eval` run any
//! checkpoint on it, and `orchestrator live replay …/episode-001` steps the simulator through the
//! recorded actions (and the person's calls) and checks the robot takes the same path.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use farm::config::RunConfig;
use farm::stepper::PayloadBuf;
use shm_schema::{ObsShape, ObsView, gesture_kind};
use worker::env::{EnvPool, PoolSpec, ProgramSource};

use super::wire::{GestureSource, Interventions, Outcome, StepRecord};

/// What an episode was and how it ended.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EpisodeRecord {
    pub program: String,
    pub checkpoint: PathBuf,
    pub gesture: GestureSource,
    pub interventions: Interventions,
    /// The episode run beside this one on the same program (two checkpoints compared).
    #[serde(default)]
    pub beside: Option<usize>,
    #[serde(flatten)]
    pub outcome: Outcome,
}

impl EpisodeRecord {
    /// A finished episode's record, from `dir/episode.json` (written last, when it ended).
    pub fn load(dir: &Path) -> anyhow::Result<EpisodeRecord> {
        let path = dir.join("episode.json");
        let text = std::fs::read_to_string(&path).with_context(|| format!("{}: no episode.json", dir.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}", path.display()))
    }
}

/// Where an episode's files go, and the steps file being written.
pub struct Recorder {
    pub dir: PathBuf,
    steps: std::io::BufWriter<std::fs::File>,
}

impl Recorder {
    /// `dir` holds the episode's dataset already; writes the config it runs with.
    pub fn new(dir: &Path, cfg: &RunConfig) -> anyhow::Result<Recorder> {
        farm::files::write_atomic(&dir.join("config.toml"), cfg.to_toml().as_bytes())?;
        let path = dir.join("steps.jsonl");
        let f = std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        Ok(Recorder { dir: dir.to_path_buf(), steps: std::io::BufWriter::new(f) })
    }

    pub fn step(&mut self, s: &StepRecord) -> anyhow::Result<()> {
        serde_json::to_writer(&mut self.steps, s)?;
        self.steps.write_all(b"\n")?;
        Ok(())
    }

    pub fn finish(&mut self, e: &EpisodeRecord) -> anyhow::Result<()> {
        self.steps.flush()?;
        farm::files::write_atomic(&self.dir.join("episode.json"), serde_json::to_string_pretty(e)?.as_bytes())?;
        Ok(())
    }
}

/// The simulator of one recorded (or live) episode: one env over the episode's one-program
/// dataset, as `eval` runs it, and the observation buffer it writes.
pub struct Sim {
    pub pool: EnvPool,
    pub buf: PayloadBuf,
    pub shape: ObsShape,
}

impl Sim {
    /// Starts the episode; `person` lets the person call the interventions from the first
    /// observation on.
    pub fn start(cfg: &RunConfig, person: bool) -> anyhow::Result<Sim> {
        let spec =
            PoolSpec { worker_id: 0, generation: 0, programs: ProgramSource::Sequence(vec![0]), expert_hints: false };
        // the page shows the frames: they come back to the host whatever the run trained with
        let mut cfg = cfg.clone();
        cfg.env.frames = farm::config::FramePath::SharedMemory;
        let mut pool = EnvPool::new(&cfg, spec)?;
        if person {
            pool.set_person_calls(0, Some(false));
        }
        let shape = ObsShape::new(1, cfg.env.width, cfg.env.height);
        let mut buf = PayloadBuf::new(&pool.layout());
        pool.reset(buf.bytes_mut())?;
        Ok(Sim { pool, buf, shape })
    }

    pub fn view(&self) -> ObsView<'_> {
        ObsView::new(self.shape, self.buf.bytes()).expect("the pool's own layout")
    }

    /// The observation's bytes, as a worker sends them.
    pub fn payload(&self) -> &[u8] {
        &self.buf.bytes()[..self.shape.layout.total_len as usize]
    }

    pub fn step(&mut self, action: u8) -> anyhow::Result<()> {
        self.pool.step(&[action], self.buf.bytes_mut())
    }
}

/// The run config an episode runs with: the checkpoint's, one env, the episode's dataset,
/// unlimited stops within the step limit (as `eval`).
pub fn episode_config(run: &RunConfig, dataset: &Path, split: worker::scene::Split) -> RunConfig {
    let mut cfg = run.clone();
    cfg.run.dataset = dataset.to_path_buf();
    cfg.run.split = split;
    cfg.run.scenes.clear();
    cfg.run.max_programs = None;
    cfg.env.envs_per_worker = 1;
    cfg.task.max_stops = 0;
    cfg
}

/// How a replay compared with the record.
#[derive(Debug)]
pub struct Replayed {
    pub steps: usize,
    /// The first step where the robot stood elsewhere, or saw another gesture, than recorded.
    pub first_difference: Option<(u32, String)>,
}

/// Steps the simulator through a recorded episode's actions (and the person's calls) and
/// compares every observation's robot pose and gesture with the record.
pub fn replay(dir: &Path) -> anyhow::Result<Replayed> {
    let cfg = RunConfig::load(&dir.join("config.toml"))?;
    let episode = EpisodeRecord::load(dir)?;
    let steps: Vec<StepRecord> = farm::files::read_jsonl(&dir.join("steps.jsonl"))?;
    anyhow::ensure!(!steps.is_empty(), "{}/steps.jsonl: no steps", dir.display());
    let person = episode.interventions == Interventions::Person;
    let mut sim = Sim::start(&cfg, person)?;
    for (k, s) in steps.iter().enumerate() {
        let r = sim.view().records()[0];
        let differs = |what: String| Ok(Replayed { steps: k, first_difference: Some((s.step, what)) });
        let d = ((r.robot[0] - s.robot[0]).powi(2) + (r.robot[1] - s.robot[1]).powi(2)).sqrt();
        if d > 1e-3 || (r.robot[2] - s.robot[2]).abs() > 1e-2 {
            return differs(format!("the robot at {:?}, recorded at {:?}", r.robot, s.robot));
        }
        if r.gesture_kind != s.shown {
            return differs(format!("gesture {} shown, {} recorded", r.gesture_kind, s.shown));
        }
        if let Some(next) = steps.get(k + 1).filter(|_| person) {
            sim.pool.set_person_calls(0, Some(next.shown == gesture_kind::INTERVENTION));
        }
        sim.step(s.action)?;
    }
    Ok(Replayed { steps: steps.len(), first_difference: None })
}
