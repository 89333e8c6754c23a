//! A synthetic task that runs in-process, to show PPO learning end to end in seconds: the
//! person's gesture says "left" or "right"; the robot must step twice that way and stop.
//!
//! Each env: position −3..3 (start 0), a cue ±1 shown as a referencing gesture (half of the 95
//! muscle channels raised for the whole clip), goal = 2·cue. Actions: RotateLeft/RotateRight
//! step −1/+1, MoveAhead does nothing, Stop succeeds at the goal (+1, terminated; the env resets
//! at once) and costs −0.01 elsewhere; −0.001 per step, as §4.3.2. After `max_steps` the episode
//! is truncated the Gymnasium way our learner expects: the final observation is sent, its action
//! ignored, then the env resets. The RGB frame shows the position as a bright column; depth
//! encodes it as distance. An untrained policy succeeds a few percent of the time.

use std::path::Path;
use std::time::Instant;

use anyhow::Context;

use farm::config::RunConfig;
use half::f16;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES, TARGET_CATEGORIES, action};
use tch::Device;

use crate::LearnerError;
use crate::logs::metrics::{MetricsLog, UpdateMetrics};
use crate::net::agent::{ActMode, Agent};
use crate::obs::{EnvBatch, EnvStep, GestureKind, OwnedObs};
use crate::ppo::checkpoint;
use crate::ppo::trainer::Trainer;

/// N copies of the cue task, stepped together.
#[derive(Debug)]
pub struct CueTask {
    obs: OwnedObs,
    pos: Vec<i32>,
    cue: Vec<i32>,
    steps: Vec<u32>,
    /// The last message was a truncated episode's final observation: reset on the next step.
    reset_next: Vec<bool>,
    pub max_steps: u32,
    rng: ChaCha8Rng,
}

impl CueTask {
    pub fn new(n: usize, side: usize, seed: u64) -> CueTask {
        let mut t = CueTask {
            obs: OwnedObs::new(n, side, side),
            pos: vec![0; n],
            cue: vec![1; n],
            steps: vec![0; n],
            reset_next: vec![false; n],
            max_steps: 8,
            rng: farm::seed::rng(seed, &[0x6375_6573]),
        };
        for k in 0..n {
            t.reset(k);
            t.render(k);
        }
        t
    }

    /// The current message.
    pub fn observation(&self) -> EnvBatch<'_> {
        self.obs.batch()
    }

    fn reset(&mut self, k: usize) {
        self.pos[k] = 0;
        self.cue[k] = if self.rng.random::<bool>() { 1 } else { -1 };
        self.steps[k] = 0;
        self.reset_next[k] = false;
        let e = &mut self.obs.envs[k];
        e.episode_start = true;
        e.gesture = GestureKind::Referencing;
        e.target = self.rng.random_range(0..TARGET_CATEGORIES as i64);
    }

    fn render(&mut self, k: usize) {
        let (h, w) = (self.obs.height, self.obs.width);
        let px = h * w;
        let col = ((self.pos[k] + 3) as usize * (w - 1)) / 6;
        for y in 0..h {
            for x in 0..w {
                let i = (k * px + y * w + x) * 3;
                let lit = if x == col { 255 } else { 20 };
                self.obs.rgb[i..i + 3].copy_from_slice(&[lit, lit / 2, 40]);
            }
        }
        let d = ((self.pos[k] + 3) as f32 / 6.0 * 65535.0) as u16;
        self.obs.depth[k * px..(k + 1) * px].iter_mut().for_each(|v| *v = d);
        let g = GESTURE_FRAMES * GESTURE_DIMS;
        let half = GESTURE_DIMS / 2;
        for f in 0..GESTURE_FRAMES {
            for c in 0..GESTURE_DIMS {
                let on = if self.cue[k] < 0 { c < half } else { c >= half };
                self.obs.gesture[k * g + f * GESTURE_DIMS + c] = f16::from_f32(if on { 0.5 } else { 0.0 });
            }
        }
    }

    /// Applies one action per env and prepares the next message.
    pub fn step(&mut self, actions: &[i64]) {
        for (k, &a) in actions.iter().enumerate() {
            let mut e =
                EnvStep { gesture: GestureKind::Referencing, target: self.obs.envs[k].target, ..Default::default() };
            if self.reset_next[k] {
                // the action on a final observation is ignored: reset, reward 0
                self.reset(k);
                e.episode_start = true;
                e.target = self.obs.envs[k].target;
            } else {
                self.steps[k] += 1;
                e.reward = -0.001;
                match a as u8 {
                    action::ROTATE_LEFT => self.pos[k] = (self.pos[k] - 1).max(-3),
                    action::ROTATE_RIGHT => self.pos[k] = (self.pos[k] + 1).min(3),
                    action::STOP if self.pos[k] == 2 * self.cue[k] => {
                        e.reward += 1.0;
                        e.terminated = true;
                        e.success = true;
                        e.spl = 3.0 / self.steps[k].max(3) as f32;
                    }
                    action::STOP => e.reward -= 0.01,
                    _ => {}
                }
                if e.terminated {
                    self.reset(k);
                    e.episode_start = true;
                    e.target = self.obs.envs[k].target;
                } else if self.steps[k] >= self.max_steps {
                    e.truncated = true; // final observation: sent now, reset on the next step
                    self.reset_next[k] = true;
                }
            }
            self.obs.envs[k] = e;
            self.render(k);
        }
    }
}

/// The smoke run's config: tiny network (16×16 frames, small CNN, hidden 64, 1-layer GRU),
/// short rollouts, and a faster learning rate than T4.1 so it learns within seconds.
pub fn config(updates: u64, envs: usize) -> RunConfig {
    let rollout = 16;
    let text = format!(
        "[run]\nmethod = \"both\"\ntotal_frames = {}\n\
         [env]\nwidth = 16\nheight = 16\nenvs_per_worker = {envs}\n\
         [model]\nencoder = \"small_cnn\"\nhidden = 64\ngru_layers = 1\n\
         [ppo]\nrollout = {rollout}\nminibatches = 2\nlr = 0.002\ngae_lambda = 0.95\n\
         [checkpoint]\nevery_updates = 10\nkeep = 2\n",
        updates * (rollout * envs) as u64
    );
    RunConfig::from_toml(&text, "smoke").expect("smoke config is valid")
}

/// Success rate of `agent` over at least `episodes` finished episodes of a fresh task.
pub fn success_rate(agent: &mut Agent, episodes: usize, mode: ActMode, seed: u64) -> Result<f64, LearnerError> {
    let mut task = CueTask::new(agent.n_envs(), agent.spec.height as usize, seed);
    agent.reset();
    let (mut done, mut won) = (0usize, 0usize);
    let mut guard = 0;
    while done < episodes && guard < 100_000 {
        let acted = agent.act(&task.observation(), mode)?;
        task.step(&acted.actions);
        for e in &task.obs.envs {
            if e.terminated || e.truncated {
                done += 1;
                won += e.success as usize;
            }
        }
        guard += 1;
    }
    Ok(won as f64 / done.max(1) as f64)
}

/// What the smoke run shows.
#[derive(Clone, Debug)]
pub struct SmokeReport {
    /// Success of the policy at the start, sampling (chance level when untrained).
    pub before: f64,
    /// Success after training, greedy (None when the run was stopped early).
    pub after: Option<f64>,
    pub updates: u64,
    pub seconds: f64,
    pub metrics: Vec<UpdateMetrics>,
}

/// Trains until `updates` PPO updates are done on the cue task; `on_update` sees each update
/// (logging, checkpoints) and may stop the run early by returning false.
pub fn run(
    cfg: &RunConfig,
    device: Device,
    updates: u64,
    on_update: impl FnMut(&Trainer, &UpdateMetrics) -> bool,
) -> Result<(SmokeReport, Trainer), LearnerError> {
    run_from(cfg, device, updates, None, on_update)
}

/// As [`run`], continuing from a checkpoint when one is given.
pub fn run_from(
    cfg: &RunConfig,
    device: Device,
    updates: u64,
    resume: Option<&Path>,
    mut on_update: impl FnMut(&Trainer, &UpdateMetrics) -> bool,
) -> Result<(SmokeReport, Trainer), LearnerError> {
    let envs = cfg.env.envs_per_worker;
    let side = cfg.env.width as usize;
    let mut trainer = match resume {
        Some(path) => checkpoint::resume_trainer(cfg, envs, device, path)?,
        None => Trainer::new(cfg, envs, device)?,
    };
    let before = success_rate(&mut trainer.agent, 200, ActMode::Sample, 1)?;
    trainer.agent.reset();
    let mut task = CueTask::new(envs, side, cfg.run.seed);
    let started = Instant::now();
    let mut metrics = Vec::new();
    let mut stopped = false;
    while trainer.updates < updates && !stopped {
        let out = trainer.step(&task.observation())?;
        task.step(&out.actions.actions);
        if let Some(m) = out.update {
            stopped = !on_update(&trainer, &m);
            metrics.push(m);
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    let after = if stopped { None } else { Some(success_rate(&mut trainer.agent, 200, ActMode::Greedy, 2)?) };
    Ok((SmokeReport { before, after, updates: trainer.updates, seconds, metrics }, trainer))
}

/// `learner smoke`: trains `updates` updates of `envs` envs on the cue task in `run_dir`
/// (config.toml, metrics.jsonl, curves.png, checkpoints/), from its latest checkpoint when
/// `resume`, printing a line per update. A termination signal (`farm::process`, installed by the
/// caller) stops it after the current update, with a checkpoint.
pub fn run_in_dir(device: Device, updates: u64, envs: usize, run_dir: &Path, resume: bool) -> anyhow::Result<()> {
    let cfg = config(updates, envs);
    let ckpt_dir = farm::checkpoints::dir_of(run_dir);
    std::fs::create_dir_all(run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    farm::files::write_atomic(&run_dir.join("config.toml"), cfg.to_toml().as_bytes())
        .with_context(|| format!("writing {}", run_dir.join("config.toml").display()))?;
    let mut log = MetricsLog::open(run_dir)?;
    let from = if resume { checkpoint::latest(&ckpt_dir) } else { None };
    if resume && from.is_none() {
        anyhow::bail!("--resume: no checkpoint in {}", ckpt_dir.display());
    }
    let stop_requested = || farm::process::termination_signal().is_some();
    let mut failure = None;
    let on_update = |t: &Trainer, m: &UpdateMetrics| {
        println!(
            "update {:>3}  frames {:>6}  success {:>5}  return {:>7}  entropy {:.3}  kl {:.4}  lr {:.2e}  {:.0} fps",
            m.update,
            m.frames,
            m.success_rate.map(|s| format!("{s:.2}")).unwrap_or("-".into()),
            m.episode_return.map(|s| format!("{s:.3}")).unwrap_or("-".into()),
            m.entropy,
            m.approx_kl,
            m.lr,
            m.fps
        );
        let stop = stop_requested();
        let result = log.append(m).map_err(anyhow::Error::from).and_then(|_| {
            if stop || m.update % t.cfg.checkpoint.every_updates == 0 {
                let p = checkpoint::save_in_dir(&ckpt_dir, t, t.cfg.checkpoint.keep)?;
                println!("checkpoint {}", p.display());
            }
            Ok(())
        });
        if let Err(e) = result {
            failure = Some(e);
            return false;
        }
        !stop
    };
    let (report, trainer) = match from {
        Some(path) => {
            println!("resuming from {}", path.display());
            run_from(&cfg, device, updates, Some(&path), on_update)?
        }
        None => run_from(&cfg, device, updates, None, on_update)?,
    };
    if let Some(e) = failure {
        return Err(e);
    }
    for n in trainer.agent.notes() {
        println!("{n}");
    }
    log.plot()?;
    if stop_requested() {
        println!("stopped by signal after update {} (checkpoint written)", trainer.updates);
        return Ok(());
    }
    let p = checkpoint::save_in_dir(&ckpt_dir, &trainer, trainer.cfg.checkpoint.keep)?;
    println!(
        "success rate {:.2} (at start, sampling) → {:.2} (trained, greedy) after {} updates in {:.1} s\n\
         metrics {}  curves {}  checkpoint {}",
        report.before,
        report.after.unwrap_or(f64::NAN),
        report.updates,
        report.seconds,
        log.jsonl.display(),
        log.png.display(),
        p.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_protocol_terminates_and_truncates_like_gymnasium() {
        let mut t = CueTask::new(1, 16, 4);
        let goal_dir = if t.cue[0] > 0 { 2 } else { 1 };
        // two steps toward the goal, stop: success, terminated, reset at once
        t.step(&[goal_dir]);
        t.step(&[goal_dir]);
        t.step(&[3]);
        let e = t.obs.envs[0];
        assert!(e.terminated && e.success && e.episode_start && !e.truncated);
        assert!((e.reward - 0.999).abs() < 1e-6);
        // dither until the limit: the 8th action truncates and sends the final observation
        for i in 0..8 {
            t.step(&[0]);
            assert_eq!(t.obs.envs[0].truncated, i == 7);
        }
        assert!(t.obs.envs[0].is_final_observation());
        t.step(&[2]); // ignored
        let e = t.obs.envs[0];
        assert!(e.episode_start && e.reward == 0.0 && !e.truncated && t.pos[0] == 0);
    }

    /// A run resumed from the checkpoint of update 3 continues with update 4, the same frame
    /// count and the same point of the lr schedule as the uninterrupted run.
    #[test]
    fn resume_continues_the_step_count_and_lr_schedule() {
        let cfg = config(6, 4);
        let dir = tempfile::tempdir().unwrap();
        let (a, _) = run(&cfg, Device::Cpu, 6, |t, m| {
            if m.update == 3 {
                checkpoint::save_in_dir(dir.path(), t, 0).unwrap();
            }
            true
        })
        .unwrap();
        let ckpt = checkpoint::latest(dir.path()).unwrap();
        let (b, tb) = run_from(&cfg, Device::Cpu, 6, Some(&ckpt), |_, _| true).unwrap();
        let key = |m: &UpdateMetrics| (m.update, m.frames, m.lr);
        let tail: Vec<_> = a.metrics[3..].iter().map(key).collect();
        assert_eq!(b.metrics.iter().map(key).collect::<Vec<_>>(), tail);
        assert_eq!(tb.updates, 6);
        assert_eq!(tb.opt.step, 6 * 4 * 2); // 4 epochs × 2 minibatches per update
        assert!(b.metrics.last().unwrap().lr < b.metrics[0].lr);
    }

    /// The behaviour test: PPO learns the task — success goes from chance to nearly always.
    #[test]
    fn ppo_learns_the_cue_task() {
        let cfg = config(40, 16);
        let (report, trainer) = run(&cfg, Device::Cpu, 40, |_, _| true).unwrap();
        eprintln!(
            "smoke: success {:.2} → {:.2} in {} updates, {:.1} s",
            report.before,
            report.after.unwrap(),
            report.updates,
            report.seconds
        );
        assert!(report.before < 0.3, "chance level {}", report.before);
        assert!(report.after.unwrap() > 0.9, "after training {:?}", report.after);
        let last = report.metrics.last().unwrap();
        assert!(last.success_rate.unwrap() > 0.5, "{last:?}");
        assert!(last.bootstrapped + last.episodes > 0);
        assert_eq!(trainer.frames, 40 * 16 * 16);
        assert!(last.lr < report.metrics[0].lr);
    }
}
