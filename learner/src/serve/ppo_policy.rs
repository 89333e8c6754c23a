//! PPO served to the farm: every round, the workers' messages (`WorkerBatch`) become one
//! `EnvBatch` of all N = workers × E envs — or of one group's, with `ppo.env_groups` — read in
//! place from the workers' shared-memory samples; the `Trainer` acts and, every `rollout` steps,
//! learns. In evaluation the network only acts (sampled or greedy), optionally with its visual
//! inputs zeroed (blind mode, RGB-only and depth-only ablations).
//!
//! A worker missing from a round (crashed, restarting, slow) contributes zero frames and its envs
//! are flagged `lost`: that step and the one before stay out of the loss and the envs' memory is
//! reset. The first observation of a restarted worker starts fresh episodes anyway.

use std::path::{Path, PathBuf};

use half::f16;
use tch::Device;

use farm::config::RunConfig;
use shm_schema::EnvRecord;

use crate::logs::metrics::{MetricsLog, UpdateMetrics};
use crate::net::agent::{ActMode, Agent};
use crate::obs::{DeviceFrames, EnvBatch, EnvStep, FrameView, GestureKind, GestureView};
use crate::ppo::checkpoint;
use crate::ppo::trainer::Trainer;
use crate::serve::batch::{WorkerBatch, WorkerObs};
use crate::serve::frames::FrameImports;
use crate::serve::policy::Policy;

/// What the network does with the batches.
pub enum Mode {
    /// Act and learn; checkpoints and metrics go to the run directory.
    Train { trainer: Box<Trainer>, log: MetricsLog, checkpoints: PathBuf },
    /// Act only, from a checkpoint.
    Eval { agent: Box<Agent>, greedy: bool },
}

/// Inputs to blank during evaluation (T4.6, T4.7).
#[derive(Clone, Copy, Debug, Default)]
pub struct Blank {
    pub rgb: bool,
    pub depth: bool,
}

/// The PPO agent as a served [`Policy`]: trains, or evaluates a checkpoint.
pub struct PpoPolicy {
    mode: Mode,
    cfg: RunConfig,
    workers: usize,
    envs: usize,
    blank: Blank,
    /// What a missing worker's envs (and a blanked input) show.
    zeros: Zeros,
    steps: Vec<EnvStep>,
    /// Generation last seen per worker (a new one marks a restart).
    generations: Vec<Option<u32>>,
    /// Seconds spent learning (updates, their records, checkpoints), for the profile.
    learning: f64,
    /// The server's latest progress record, logged with the next update (one point per update,
    /// at the update's frame count).
    farm_progress: Option<farm::progress::Progress>,
    /// `env.frames = "device"`: the workers' frames, imported from their GPU memory.
    imports: Option<FrameImports>,
}

impl PpoPolicy {
    /// Training from scratch, or from the run directory's latest checkpoint when `resume`.
    pub fn train(
        cfg: &RunConfig,
        workers: usize,
        device: Device,
        run_dir: &Path,
        resume: bool,
    ) -> anyhow::Result<PpoPolicy> {
        let n = workers * cfg.env.envs_per_worker;
        let checkpoints = farm::checkpoints::dir_of(run_dir);
        let partial = farm::checkpoints::remove_partial(&checkpoints);
        if partial > 0 {
            tracing::warn!("removed {partial} unfinished checkpoint write(s) in {}", checkpoints.display());
        }
        let (latest, skipped) =
            if resume { farm::checkpoints::latest_verified(&checkpoints) } else { (None, Vec::new()) };
        for (p, why) in &skipped {
            tracing::warn!("--resume: skipped {}: {why}", p.display());
        }
        let mut trainer = match (resume, latest) {
            (true, Some(path)) => {
                let t = checkpoint::resume_trainer(cfg, n, device, &path)?;
                tracing::info!("resumed from {} at update {} ({} frames)", path.display(), t.updates, t.frames);
                t
            }
            (true, None) if skipped.is_empty() => {
                anyhow::bail!("--resume: {} holds no checkpoint", checkpoints.display())
            }
            (true, None) => anyhow::bail!(
                "--resume: {} holds no usable checkpoint ({})",
                checkpoints.display(),
                farm::checkpoints::describe_skipped(&skipped).replace('\n', "; ")
            ),
            (false, _) => Trainer::new(cfg, n, device)?,
        };
        // A stop (Ctrl-C, or the time budget spent) during an update cuts it short; the final
        // checkpoint follows.
        trainer.interrupted = farm::process::stop_requested;
        for note in trainer.agent.notes() {
            tracing::info!("{note}");
        }
        let mut log = MetricsLog::open(run_dir)?;
        log.started_at(trainer.frames, &cfg.to_toml())?;
        Ok(PpoPolicy::with_mode(
            Mode::Train { trainer: Box::new(trainer), log, checkpoints },
            cfg,
            workers,
            Blank::default(),
        ))
    }

    /// Evaluation of a checkpoint: actions sampled from the policy as in training (seeded from
    /// the run seed), or its most likely action with `greedy`.
    pub fn eval(
        cfg: &RunConfig,
        workers: usize,
        device: Device,
        checkpoint: &Path,
        blank: Blank,
        greedy: bool,
    ) -> anyhow::Result<PpoPolicy> {
        tch::manual_seed(cfg.run.seed as i64);
        let n = workers * cfg.env.envs_per_worker;
        let agent = checkpoint::load_agent(cfg, n, device, checkpoint)?;
        for note in agent.notes() {
            tracing::info!("{note}");
        }
        Ok(PpoPolicy::with_mode(Mode::Eval { agent: Box::new(agent), greedy }, cfg, workers, blank))
    }

    fn with_mode(mode: Mode, cfg: &RunConfig, workers: usize, blank: Blank) -> PpoPolicy {
        let e = cfg.env.envs_per_worker;
        let px = (cfg.env.width * cfg.env.height) as usize;
        PpoPolicy {
            mode,
            cfg: cfg.clone(),
            workers,
            envs: e,
            blank,
            zeros: Zeros {
                rgb: vec![0; e * px * 3],
                depth: vec![0; e * px],
                gesture: vec![f16::ZERO; e * shm_schema::GESTURE_FRAMES * shm_schema::GESTURE_DIMS],
            },
            steps: vec![EnvStep { lost: true, ..Default::default() }; workers * e],
            generations: vec![None; workers],
            learning: 0.0,
            farm_progress: None,
            imports: None,
        }
    }

    /// Reads the workers' frames from the GPU memory they hand over `imports` (`env.frames =
    /// "device"`) instead of from their observations' shared memory.
    pub fn with_device_frames(mut self, imports: FrameImports) -> PpoPolicy {
        self.imports = Some(imports);
        self
    }

    /// Times training's acting and updates stage by stage (`--profile-stages`): each stage then
    /// waits for the device, which slows the run. Evaluation has nothing to time.
    pub fn with_stage_times(mut self) -> PpoPolicy {
        if let Mode::Train { trainer, .. } = &mut self.mode {
            trainer.time_stages();
        }
        self
    }

    /// The round's workers are the run's, each sending the configured envs.
    fn check(&self, batch: &WorkerBatch<'_>) -> anyhow::Result<()> {
        let (e, workers) = (self.envs, &batch.workers);
        anyhow::ensure!(workers.end <= self.workers, "workers {workers:?} outside the run's {}", self.workers);
        for p in &batch.parts {
            let w = p.worker as usize;
            anyhow::ensure!(workers.contains(&w), "worker {w} is outside the round's workers {workers:?}");
            anyhow::ensure!(p.num_envs() == e, "worker {w} sends {} envs, the config says {e}", p.num_envs());
        }
        Ok(())
    }

    /// Each env's step of the round's workers: from its record, or lost where its worker sent
    /// nothing. A restarted worker's envs lose the step the previous process never applied.
    fn read_records(&mut self, batch: &WorkerBatch<'_>) {
        let e = self.envs;
        let mut parts = batch.parts.iter().peekable();
        for w in batch.workers.clone() {
            let Some(p) = parts.next_if(|p| p.worker as usize == w) else {
                self.steps[w * e..(w + 1) * e].fill(EnvStep { lost: true, ..Default::default() });
                continue;
            };
            let restarted = p.new_generation || self.generations[w].is_some_and(|g| g != p.generation);
            self.generations[w] = Some(p.generation);
            for (k, r) in p.records().iter().enumerate() {
                let mut s = env_step(r);
                s.lost |= restarted && r.episode_start == 0;
                self.steps[w * e + k] = s;
            }
        }
    }

    /// The training loop's hook after each update: its metrics logged, a plot every 5 updates, a
    /// checkpoint every `checkpoint.every_updates`. The time counts as learning.
    fn after_update(&mut self, m: &UpdateMetrics) -> anyhow::Result<()> {
        let began = std::time::Instant::now();
        let Mode::Train { trainer, log, .. } = &mut self.mode else { return Ok(()) };
        log.append(m)?;
        if let Some(p) = self.farm_progress.take() {
            log.farm(m.frames, &p)?;
        }
        tracing::info!("{}", update_line(m, self.cfg.ppo.overlap_update));
        if trainer.updates % 5 == 0 {
            log.plot()?;
        }
        if trainer.updates % self.cfg.checkpoint.every_updates.max(1) == 0 {
            self.save_checkpoint()?;
        }
        self.learning += began.elapsed().as_secs_f64();
        Ok(())
    }

    fn save_checkpoint(&mut self) -> anyhow::Result<()> {
        if let Mode::Train { trainer, checkpoints, .. } = &self.mode {
            if trainer.updates > 0 {
                let path = checkpoint::save_in_dir(checkpoints, trainer, self.cfg.checkpoint.keep)?;
                tracing::info!("checkpoint {}", path.display());
            }
        }
        Ok(())
    }
}

/// The agent's per-env fields of a worker's record.
pub(crate) fn env_step(r: &EnvRecord) -> EnvStep {
    let done = r.terminated != 0 || r.truncated != 0;
    let s = &r.summary;
    let spl = if done && s.success != 0 {
        farm::metrics::spl(s.shortest_path as f64, s.path_length as f64) as f32
    } else {
        0.0
    };
    EnvStep {
        reward: r.reward,
        terminated: r.terminated != 0,
        truncated: r.truncated != 0,
        episode_start: r.episode_start != 0,
        // an idle env (evaluation ran out of programs) has nothing to learn from
        lost: r.idle != 0,
        gesture: GestureKind::from_u8(r.gesture_kind).unwrap_or_default(),
        target: r.target_category as i64,
        person_pose: r.person_rel,
        success: r.success != 0,
        spl,
    }
}

/// Zero frames and gestures of one worker's envs.
struct Zeros {
    rgb: Vec<u8>,
    depth: Vec<u16>,
    gesture: Vec<f16>,
}

/// One frame group per worker of the round, in worker order, read in place; a missing worker's
/// (and a blanked input) are zeros.
fn frame_views<'a>(
    batch: &WorkerBatch<'a>,
    envs: usize,
    zeros: &'a Zeros,
    blank: Blank,
    imports: Option<&'a FrameImports>,
) -> Vec<FrameView<'a>> {
    let mut parts = batch.parts.iter().peekable();
    let missing = || FrameView {
        envs,
        rgb: &zeros.rgb,
        depth: &zeros.depth,
        gesture: GestureView::F16(&zeros.gesture),
        device: None,
    };
    let present = |p: &WorkerObs<'a>| FrameView {
        envs,
        rgb: if blank.rgb { &zeros.rgb } else { p.rgb() },
        depth: if blank.depth { &zeros.depth } else { p.depth() },
        gesture: GestureView::F16(p.gesture()),
        device: imports.and_then(|i| i.frames(p.worker)).map(|frames| DeviceFrames {
            frames,
            rgb: !blank.rgb,
            depth: !blank.depth,
        }),
    };
    batch.workers.clone().map(|w| parts.next_if(|p| p.worker as usize == w).map_or_else(missing, present)).collect()
}

/// The log's line for an update.
fn update_line(m: &UpdateMetrics, overlapped: bool) -> String {
    format!(
        "update {} frames {} fps {:.0} success {} loss π {:.3} v {:.3} entropy {:.3}{}",
        m.update,
        m.frames,
        m.fps,
        m.success_rate.map_or("-".into(), |s| format!("{:.2}", s)),
        m.policy_loss,
        m.value_loss,
        m.entropy,
        if overlapped { format!(" policy lag {}", m.policy_lag) } else { String::new() }
    )
}

impl Policy for PpoPolicy {
    fn name(&self) -> &str {
        match self.mode {
            Mode::Train { .. } => "ppo",
            Mode::Eval { .. } => "ppo-eval",
        }
    }

    fn learning_seconds(&self) -> f64 {
        self.learning
    }

    fn stage_times(&self) -> Option<farm::profile::StageTimes> {
        match &self.mode {
            Mode::Train { trainer, .. } => trainer.stage_times(),
            Mode::Eval { .. } => None,
        }
    }

    fn groups_now(&self) -> usize {
        match &self.mode {
            Mode::Train { trainer, .. } if !trainer.wants_all() => self.cfg.ppo.env_groups.min(self.workers),
            _ => 1,
        }
    }

    /// check → import device frames → read the records → act (and learn) → answer.
    fn act(&mut self, batch: &WorkerBatch<'_>) -> anyhow::Result<Vec<u8>> {
        let (e, workers) = (self.envs, batch.workers.clone());
        self.check(batch)?;
        if let Some(imports) = &mut self.imports {
            for p in &batch.parts {
                imports.ensure(p.worker, p.generation)?;
            }
        }
        self.read_records(batch);
        let frames = frame_views(batch, e, &self.zeros, self.blank, self.imports.as_ref());
        let envs = workers.start * e..workers.end * e;
        let obs = EnvBatch { height: batch.height, width: batch.width, frames, envs: &self.steps[envs.clone()] };
        let actions = match &mut self.mode {
            Mode::Train { trainer, .. } => {
                let learned_before = trainer.learning_seconds();
                let out = trainer.step_at(envs.start, &obs)?;
                self.learning += trainer.learning_seconds() - learned_before;
                if let Some(m) = &out.update {
                    self.after_update(m)?;
                }
                out.actions.actions
            }
            Mode::Eval { agent, greedy } => {
                anyhow::ensure!(envs.len() == self.workers * e, "evaluation acts on every env at once");
                let a = agent.act(&obs, if *greedy { ActMode::Greedy } else { ActMode::Sample })?;
                a.actions
            }
        };
        // The answer lets each worker draw over its slots: the copies out of them must be done.
        // The actions' copy to the host already waited for them (they were queued before the
        // forward on the same stream); this keeps it so should an answer ever not need a forward.
        if let Some(imports) = &self.imports {
            imports.finish_copies();
        }
        // Answer only the workers that sent, in batch order.
        let mut out = Vec::with_capacity(batch.num_envs());
        for p in &batch.parts {
            let w = p.worker as usize - workers.start;
            out.extend(actions[w * e..(w + 1) * e].iter().map(|&a| a as u8));
        }
        Ok(out)
    }

    fn finish(&mut self, checkpoint: bool) -> anyhow::Result<()> {
        // the rollouts an overlapped update has not learned yet, so the checkpoint holds them
        if checkpoint && let Mode::Train { trainer, log, .. } = &mut self.mode {
            for m in trainer.settle() {
                tracing::info!(
                    "update {} frames {} policy lag {} (learned at the stop)",
                    m.update,
                    m.frames,
                    m.policy_lag
                );
                log.append(&m)?;
            }
        }
        // The checkpoint first: a plot that fails (a full disk) must not cost the training.
        if checkpoint && let Mode::Train { checkpoints, .. } = &self.mode {
            // While this marker exists the orchestrator waits instead of escalating.
            let marker = checkpoints.join(farm::checkpoints::FINAL_WRITE_MARKER);
            std::fs::create_dir_all(checkpoints)?;
            std::fs::write(&marker, std::process::id().to_string())?;
            tracing::info!("writing the final checkpoint");
            let saved = self.save_checkpoint();
            let _ = std::fs::remove_file(&marker);
            saved?;
        }
        if let Mode::Train { log, .. } = &mut self.mode {
            log.plot_final()?;
        }
        Ok(())
    }

    fn report(&mut self, progress: &farm::progress::Progress) -> anyhow::Result<()> {
        if let Mode::Train { log, .. } = &mut self.mode {
            if progress.stop_reason.is_some() {
                log.farm_final(progress)?;
            } else {
                self.farm_progress = Some(progress.clone());
            }
        }
        Ok(())
    }
}
