//! The PPO trainer (§4.3.1–§4.3.2, Algorithm 1, T4.1). Each step message, in this order
//! ([`Trainer::step_at`]):
//!
//! 1. **feedback** — the previous action's reward and end of episode, into the rollout;
//! 2. **learn**, when the message completes a rollout — bootstrap from V(o_T), then GAE and the
//!    epochs of [`super::update`], in place or on a thread beside acting ([`super::overlap`]);
//! 3. **act** — sample the actions (after an update, the new policy's on the same o_T and memory)
//!    and store them.
//!
//! The learning rate decays linearly from 3e-4 to 0 over the run's frames (§4.3.2).

use std::time::Instant;

use farm::config::{PpoConfig, RunConfig};
use rand_chacha::ChaCha8Rng;
use tch::Device;

use crate::inputs::Inputs;
use crate::logs::metrics::{EpisodeWindow, UpdateMetrics};
use crate::net::agent::{ActMode, Actions, Agent, AgentError, Forward};
use crate::obs::{EnvBatch, EnvStep, ObsError};
use crate::ppo::optim::Adam;
use crate::ppo::overlap::Overlap;
use crate::ppo::rollout::{FeedbackCounts, Rollout};
use crate::ppo::update::{UpdateSettings, lr_at, update};
use crate::stages::{Stage, StageClock};

/// Adam's ε: 1e-5, the usual choice for PPO (torch's default is 1e-8).
const ADAM_EPS: f64 = 1e-5;

/// What [`Trainer::step`] gives back: the actions to send, and the update's metrics when this
/// message completed a rollout.
#[derive(Debug)]
pub struct StepOutput {
    pub actions: Actions,
    pub update: Option<UpdateMetrics>,
}

/// The PPO agent being trained: the acting agent, optimizer, rollout, counters.
#[derive(Debug)]
pub struct Trainer {
    pub cfg: RunConfig,
    /// `cfg.ppo`, with at most one minibatch per env.
    pub hp: PpoConfig,
    pub agent: Agent,
    pub opt: Adam,
    pub rollout: Rollout,
    /// PPO updates done.
    pub updates: u64,
    /// Environment frames in the rollouts learned from (drives the lr schedule).
    pub frames: u64,
    /// Minibatch order; part of the checkpoint.
    pub(crate) rng: ChaCha8Rng,
    episodes: EpisodeWindow,
    ep_return: Vec<f64>,
    ep_length: Vec<u32>,
    /// The env's last stored step was a real action (its feedback counts for the episode).
    last_real: Vec<bool>,
    counts: FeedbackCounts,
    last_update_at: Instant,
    /// Updates done when the rollout being collected began: the weights that collect it.
    collected_by: u64,
    /// Seconds steps spent learning: whole updates in place, waits for them overlapped.
    learning_s: f64,
    /// `ppo.overlap_update`: the copy that learns beside acting, and its work; `None`: in place.
    overlap: Option<Overlap>,
    /// Asked before every minibatch: true ends the update's epochs there (a stop signal), so a
    /// stop never waits for a whole update.
    pub interrupted: fn() -> bool,
}

impl Trainer {
    /// A fresh agent for `n_envs` envs.
    pub fn new(cfg: &RunConfig, n_envs: usize, device: Device) -> Result<Trainer, AgentError> {
        Trainer::build(cfg, n_envs, device, true)
    }

    /// `load_weights`: read the configured ResNet-18 file (not when a checkpoint is about to
    /// overwrite every variable: `crate::ppo::checkpoint::resume_trainer`).
    pub(crate) fn build(
        cfg: &RunConfig,
        n_envs: usize,
        device: Device,
        load_weights: bool,
    ) -> Result<Trainer, AgentError> {
        let agent = Agent::build(cfg, n_envs, device, load_weights)?;
        let mut hp = cfg.ppo.clone();
        if hp.minibatches > n_envs {
            tracing::warn!("ppo.minibatches = {} > {n_envs} envs: using {n_envs}", hp.minibatches);
            hp.minibatches = n_envs;
        }
        let opt = Adam::new(&agent.vs, hp.lr, ADAM_EPS);
        let rollout = Rollout::new(hp.rollout, n_envs, agent.hidden());
        let overlap = match hp.overlap_update {
            false => None,
            true => Some(Overlap::new(cfg, &hp, device, ADAM_EPS)?),
        };
        Ok(Trainer {
            rng: farm::seed::rng(cfg.run.seed, &[0x7070_6f5f]),
            cfg: cfg.clone(),
            hp,
            agent,
            opt,
            rollout,
            updates: 0,
            frames: 0,
            episodes: EpisodeWindow::default(),
            ep_return: vec![0.0; n_envs],
            ep_length: vec![0; n_envs],
            last_real: vec![false; n_envs],
            counts: FeedbackCounts::default(),
            last_update_at: Instant::now(),
            collected_by: 0,
            learning_s: 0.0,
            overlap,
            interrupted: || false,
        })
    }

    /// One step message in, actions out. When the message completes a rollout, the PPO update
    /// runs first (the returned actions then come from the updated policy).
    pub fn step(&mut self, obs: &EnvBatch) -> Result<StepOutput, ObsError> {
        self.step_at(0, obs)
    }

    /// [`Trainer::step`] for envs `at..at + obs.n()`: one group of an acting round
    /// (`ppo.env_groups`). Each env's feedback, action and memory are those of a round for all;
    /// a step is stored once every group has acted, and the step that completes a rollout must
    /// be a round for all (the update needs every env's next observation; [`Trainer::wants_all`]).
    pub fn step_at(&mut self, at: usize, obs: &EnvBatch) -> Result<StepOutput, ObsError> {
        self.launch_queued();
        self.agent.stages.start(true);
        let (x, starts) = self.agent.prepare(at, obs)?;
        self.check_round(at, starts.len())?;
        let mut fwd = self.agent.forward(at, &x, starts.clone());
        self.record_feedback(at, obs, &fwd.values);
        let mut update = None;
        if self.rollout.is_full() {
            update = self.learn_full_rollout(fwd.values.clone());
            fwd = self.agent.forward(0, &x, starts);
        }
        let actions = self.act_and_store(at, obs, &x, fwd);
        Ok(StepOutput { actions, update })
    }

    /// The step that completes a rollout must be a round for all envs.
    fn check_round(&self, at: usize, n: usize) -> Result<(), ObsError> {
        if self.wants_all() && n != self.rollout.envs {
            return Err(ObsError::Shape(format!(
                "envs {at}..{} alone at the end of a rollout: the update needs every env",
                at + n
            )));
        }
        Ok(())
    }

    /// 1. The feedback of the previous action: reward, end of episode, truncation bootstrap.
    fn record_feedback(&mut self, at: usize, obs: &EnvBatch, values: &[f32]) {
        let c = self.rollout.record_feedback_at(at, obs.envs, values, self.hp.gamma as f32);
        self.counts.bootstrapped += c.bootstrapped;
        self.counts.truncated_without_final += c.truncated_without_final;
        self.counts.lost += c.lost;
        self.track_episodes(at, obs.envs);
        self.agent.stages.lap(Stage::ActStore);
    }

    /// 2. The full rollout learned from V(o_T) (the old policy's `bootstrap`): in place now, or
    /// queued for the next step's thread with the previous rollout's update joined.
    fn learn_full_rollout(&mut self, bootstrap: Vec<f32>) -> Option<UpdateMetrics> {
        let update = match self.overlap.is_some() {
            false => Some(self.update(&bootstrap)),
            true => {
                let joined = self.join();
                let ov = self.overlap.as_mut().expect("overlapped");
                ov.queue(&mut self.rollout, bootstrap, self.collected_by);
                joined
            }
        };
        self.rollout.begin(self.agent.hidden());
        self.collected_by = self.updates;
        update
    }

    /// 3. Act and store. A final observation's action is ignored by the env.
    fn act_and_store(&mut self, at: usize, obs: &EnvBatch, x: &Inputs, fwd: Forward) -> Actions {
        let acted = self.agent.choose(&fwd, ActMode::Sample);
        self.agent.stages.lap(Stage::ActSample);
        let valid: Vec<bool> = obs.envs.iter().map(|e| !e.lost && !e.is_final_observation()).collect();
        self.rollout.push_at(at, x, &fwd.starts, &acted, &valid);
        self.last_real[at..at + valid.len()].copy_from_slice(&valid);
        self.agent.commit(at, fwd, obs);
        self.agent.stages.lap(Stage::ActStore);
        acted
    }

    /// Times acting and updates stage by stage from now on, synchronizing the device after each
    /// stage ([`Trainer::stage_times`]).
    pub fn time_stages(&mut self) {
        self.agent.stages = StageClock::on(self.agent.device());
    }

    /// The stage times so far; `None` unless [`Trainer::time_stages`] turned them on.
    pub fn stage_times(&self) -> Option<farm::profile::StageTimes> {
        self.agent.stages.times()
    }

    /// Whether the next step must be a round for all envs: it completes the rollout.
    pub fn wants_all(&self) -> bool {
        self.rollout.is_full()
    }

    /// Episode returns, lengths and outcomes of envs `at..`, from the feedback of real actions
    /// only.
    fn track_episodes(&mut self, at: usize, envs: &[EnvStep]) {
        for (i, e) in envs.iter().enumerate() {
            let k = at + i;
            if !self.last_real[k] || e.lost {
                if e.episode_start || e.lost {
                    self.ep_return[k] = 0.0;
                    self.ep_length[k] = 0;
                }
                continue;
            }
            self.ep_return[k] += e.reward as f64;
            self.ep_length[k] += 1;
            if e.terminated || e.truncated || e.episode_start {
                if e.terminated || e.truncated {
                    self.episodes.add(self.ep_return[k], self.ep_length[k], e.success, e.spl);
                }
                self.ep_return[k] = 0.0;
                self.ep_length[k] = 0;
            }
        }
    }

    /// The PPO update on the full rollout, on the agent's own network; `bootstrap` is V(o_T) per
    /// env.
    pub(crate) fn update(&mut self, bootstrap: &[f32]) -> UpdateMetrics {
        let started = Instant::now();
        self.agent.stages.start(false);
        let how = self.update_settings();
        let mut m =
            update(&self.agent.net, &mut self.opt, &mut self.rng, &self.rollout, bootstrap, &how, &self.agent.stages);
        m.update_seconds = started.elapsed().as_secs_f64();
        let m = self.count_update(m);
        self.agent.stages.lap(Stage::UpdatePrepare);
        self.learning_s += started.elapsed().as_secs_f64();
        m
    }

    /// Seconds the steps so far spent learning rather than acting: every update in place; with
    /// `ppo.overlap_update`, the waits for an update still running when the next rollout is full.
    pub fn learning_seconds(&self) -> f64 {
        self.learning_s
    }

    fn update_settings(&self) -> UpdateSettings {
        // Annealing the learning rate: 3e-4 → 0 linearly over the run's frames.
        let lr = lr_at(&self.hp, self.cfg.run.total_frames, self.frames);
        UpdateSettings { hp: self.hp.clone(), lr, interrupted: self.interrupted }
    }

    /// The counters an update moves, in the order a reader follows the run: frames learned,
    /// updates, the rate since the last update, the episodes and feedback counts since then.
    fn count_update(&mut self, mut m: UpdateMetrics) -> UpdateMetrics {
        let frames = (self.rollout.steps * self.rollout.envs) as u64;
        self.frames += frames;
        self.updates += 1;
        m.update = self.updates;
        m.frames = self.frames;
        let now = Instant::now();
        m.fps = frames as f64 / now.duration_since(self.last_update_at).as_secs_f64().max(1e-9);
        self.last_update_at = now;
        self.episodes.drain_into(&mut m);
        m.bootstrapped = std::mem::take(&mut self.counts.bootstrapped) as u64;
        m.truncated_without_final = std::mem::take(&mut self.counts.truncated_without_final) as u64;
        m.lost_messages = std::mem::take(&mut self.counts.lost) as u64;
        m
    }

    /// Overlapped: hands the queued rollout to a thread ([`Overlap::launch`]).
    fn launch_queued(&mut self) {
        let how = self.update_settings();
        if let Some(ov) = self.overlap.as_mut() {
            ov.launch(&self.agent, &self.opt, &self.rng, how, self.updates);
        }
    }

    /// Overlapped: waits for the update in flight, if any, and takes its weights, moments and
    /// minibatch order.
    fn join(&mut self) -> Option<UpdateMetrics> {
        let (m, waited) = self.overlap.as_mut()?.join(&mut self.opt, &mut self.rng)?;
        self.learning_s += waited;
        Some(self.count_update(m))
    }

    /// Learns every rollout still queued or in flight (`ppo.overlap_update`; nothing otherwise),
    /// so that a final checkpoint holds all the frames collected. Their metrics, in order.
    pub fn settle(&mut self) -> Vec<UpdateMetrics> {
        let mut out: Vec<UpdateMetrics> = self.join().into_iter().collect();
        self.launch_queued();
        out.extend(self.join());
        out
    }
}

#[cfg(test)]
mod tests;
