//! PPO (§4.3.1–§4.3.2, Algorithm 1, T4.1), readable top to bottom in the order it happens:
//!
//! 1. **collect** — every step message: record the feedback of the previous action, act, store
//!    ([`Trainer::step`]);
//! 2. **bootstrap** — when T steps are stored, the value of the next observation;
//! 3. **GAE** — advantages and returns ([`gae`]);
//! 4. **learn** — for each epoch, for each minibatch of whole envs (the GRU is re-run over their
//!    full sequences from the stored initial memory): probability ratio, clipped policy loss,
//!    value loss, entropy bonus, Adam step with the gradient norm clipped ([`learn`]).
//!
//! The learning rate decays linearly from 3e-4 to 0 over the run's frames (§4.3.2).
//!
//! With `ppo.overlap_update` the update of a full rollout runs on a thread, on a copy of the
//! network ([`Overlap`]), while the agent collects the next rollout with the weights before it;
//! the copy's weights come back when that rollout is full (a policy lag of one update).

use std::thread::JoinHandle;
use std::time::Instant;

use farm::config::{PpoConfig, RunConfig};
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

use crate::logs::metrics::{EpisodeWindow, UpdateMetrics};
use crate::net::agent::{ActMode, Actions, Agent, AgentError};
use crate::net::network::PolicyNet;
use crate::obs::{EnvBatch, EnvStep, ObsError};
use crate::ppo::optim::Adam;
use crate::ppo::rollout::{FeedbackCounts, Rollout, flags};
use crate::stages::{Stage, StageClock};

/// Adam's ε: 1e-5, the usual choice for PPO (torch's default is 1e-8).
const ADAM_EPS: f64 = 1e-5;

/// The linearly annealed learning rate after `frames` of the run's `total_frames`.
pub fn lr_at(p: &PpoConfig, total_frames: u64, frames: u64) -> f64 {
    p.lr * (1.0 - frames as f64 / total_frames.max(1) as f64).max(0.0)
}

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
    /// `ppo.overlap_update`: the copy that learns beside acting, and its work.
    overlap: Option<Overlap>,
    /// Asked before every minibatch: true ends the update's epochs there (a stop signal), so a
    /// stop never waits for a whole update.
    pub interrupted: fn() -> bool,
}

/// `ppo.overlap_update`: a full rollout is queued at the step that completes it and handed to a
/// thread at the next step, with a copy of the network, Adam and the minibatch order as they are
/// then; the copy's weights, moments and order come back into the trainer when the next rollout is
/// full. Between steps the trainer's own state is always that after its last joined update, so a
/// checkpoint written at any step is consistent (the rollouts queued or in flight are not in it).
#[derive(Debug)]
struct Overlap {
    /// The learning copy (built like the agent; its frozen parts copied once), `None` while in flight.
    copy: Option<Learner>,
    queued: Option<Queued>,
    in_flight: Option<JoinHandle<Learned>>,
    /// The rollout of the last joined update, collected into next.
    spare: Option<Rollout>,
}

/// A network with Adam over its trainable variables.
#[derive(Debug)]
struct Learner {
    agent: Agent,
    opt: Adam,
    /// The frozen variables (never stepped) have been copied from the acting agent.
    frozen_copied: bool,
}

/// A full rollout waiting for its update: V(o_T) per env and the update that collected it.
#[derive(Debug)]
struct Queued {
    rollout: Rollout,
    bootstrap: Vec<f32>,
    collected_by: u64,
}

/// What an overlapped update hands back.
#[derive(Debug)]
struct Learned {
    copy: Learner,
    rng: ChaCha8Rng,
    rollout: Rollout,
    metrics: UpdateMetrics,
}

/// What an update reads besides the rollout and the state it changes.
#[derive(Clone, Debug)]
struct UpdateSettings {
    hp: PpoConfig,
    lr: f64,
    interrupted: fn() -> bool,
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
            true => {
                // built without its weight files: every variable is copied from the agent at the
                // first update, after a checkpoint has been loaded into it
                let copy = Agent::build(cfg, 1, device, false)?;
                let opt = Adam::new(&copy.vs, hp.lr, ADAM_EPS);
                let copy = Learner { agent: copy, opt, frozen_copied: false };
                Some(Overlap { copy: Some(copy), queued: None, in_flight: None, spare: None })
            }
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
        let (x, starts) = self.agent.prepare_at(at, obs)?;
        let n = starts.len();
        if self.wants_all() && n != self.rollout.envs {
            return Err(ObsError::Shape(format!(
                "envs {at}..{} alone at the end of a rollout: the update needs every env",
                at + n
            )));
        }
        let mut fwd = self.agent.forward_at(at, &x, starts.clone());

        // 1. The feedback of the previous action: reward, end of episode, truncation bootstrap.
        let c = self.rollout.record_feedback_at(at, obs.envs, &fwd.values, self.hp.gamma as f32);
        self.counts.bootstrapped += c.bootstrapped;
        self.counts.truncated_without_final += c.truncated_without_final;
        self.counts.lost += c.lost;
        self.track_episodes(at, obs.envs);
        self.agent.stages.lap(Stage::ActStore);

        // 2.–4. A full rollout: bootstrap from V(o_T) (the old policy's), learn, and act on o_T
        //       with the new policy from the same memory. Overlapped: the last rollout's update
        //       is joined and this one queued.
        let mut update = None;
        if self.rollout.is_full() {
            let bootstrap = fwd.values.clone();
            update = match self.overlap.is_some() {
                false => Some(self.update(&bootstrap)),
                true => self.join_and_queue(bootstrap),
            };
            self.rollout.begin(self.agent.hidden());
            self.collected_by = self.updates;
            fwd = self.agent.forward(&x, starts);
        }

        // 1. (cont.) Act and store. A final observation's action is ignored by the env.
        let acted = self.agent.choose(&fwd, ActMode::Sample);
        self.agent.stages.lap(Stage::ActSample);
        let valid: Vec<bool> = obs.envs.iter().map(|e| !e.lost && !e.is_final_observation()).collect();
        self.rollout.push_at(at, &x, &fwd.starts, &acted, &valid);
        self.last_real[at..at + n].copy_from_slice(&valid);
        self.agent.commit_at(at, fwd, obs);
        self.agent.stages.lap(Stage::ActStore);
        Ok(StepOutput { actions: acted, update })
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
            learn(&self.agent.net, &mut self.opt, &mut self.rng, &self.rollout, bootstrap, &how, &self.agent.stages);
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

    /// Overlapped, at a full rollout: the update in flight joined (its weights act from now on),
    /// and the full rollout queued for the next step, which hands it to a thread.
    fn join_and_queue(&mut self, bootstrap: Vec<f32>) -> Option<UpdateMetrics> {
        let m = self.join();
        let ov = self.overlap.as_mut().expect("overlapped");
        let spare =
            ov.spare.take().unwrap_or_else(|| Rollout::new(self.hp.rollout, self.rollout.envs, &self.rollout.h0));
        let rollout = std::mem::replace(&mut self.rollout, spare);
        ov.queued = Some(Queued { rollout, bootstrap, collected_by: self.collected_by });
        m
    }

    /// Overlapped: hands the queued rollout to a thread that learns it on the copy, from the
    /// trainer's weights, moments and minibatch order as they are now.
    fn launch_queued(&mut self) {
        let how = self.update_settings();
        let Some(ov) = self.overlap.as_mut() else { return };
        let Some(q) = ov.queued.take() else { return };
        let mut copy = ov.copy.take().expect("the copy is back before a rollout is queued");
        if !copy.frozen_copied {
            copy.agent.vs.copy(&self.agent.vs).expect("the copy is built like the agent");
            if let Some(f) = copy.agent.net.frozen() {
                f.refresh(&copy.agent.vs);
            }
            copy.frozen_copied = true;
        }
        copy.opt.copy_from(&self.opt);
        let mut rng = self.rng.clone();
        let policy_lag = self.updates - q.collected_by;
        ov.in_flight = Some(std::thread::spawn(move || {
            let started = Instant::now();
            // its stages are not timed: they run beside acting's
            let stages = StageClock::default();
            let mut metrics = learn(&copy.agent.net, &mut copy.opt, &mut rng, &q.rollout, &q.bootstrap, &how, &stages);
            metrics.update_seconds = started.elapsed().as_secs_f64();
            metrics.policy_lag = policy_lag;
            Learned { copy, rng, rollout: q.rollout, metrics }
        }));
    }

    /// Overlapped: waits for the update in flight, if any, and takes its weights, moments and
    /// minibatch order.
    fn join(&mut self) -> Option<UpdateMetrics> {
        let ov = self.overlap.as_mut()?;
        let handle = ov.in_flight.take()?;
        let waited = Instant::now();
        let l = handle.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        self.learning_s += waited.elapsed().as_secs_f64();
        self.opt.copy_from(&l.copy.opt);
        self.rng = l.rng;
        ov.copy = Some(l.copy);
        ov.spare = Some(l.rollout);
        Some(self.count_update(l.metrics))
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

/// The PPO update of a full rollout on `net`, whose trainable variables `opt` steps: GAE, then
/// the epochs of minibatches; the counters are the trainer's ([`Trainer::count_update`]).
fn learn(
    net: &PolicyNet,
    opt: &mut Adam,
    rng: &mut ChaCha8Rng,
    r: &Rollout,
    bootstrap: &[f32],
    how: &UpdateSettings,
    stages: &StageClock,
) -> UpdateMetrics {
    let hp = &how.hp;
    let (t_len, n) = (r.steps, r.envs);
    opt.lr = how.lr;
    let mut m = UpdateMetrics { lr: how.lr, ..Default::default() };
    let valid_count = r.valid.iter().filter(|v| **v).count();
    m.valid_fraction = valid_count as f64 / (t_len * n) as f64;
    if net.spec().random() || valid_count == 0 {
        return m;
    }

    // GAE (Eq. 4.3–4.5), on the host: T×N scalars.
    let (advantages, returns) =
        gae(&r.rewards, &r.values, &r.ends, bootstrap, n, hp.gamma as f32, hp.gae_lambda as f32);
    m.explained_variance = explained_variance(&r.values, &returns, &r.valid);

    let b_adv = r.to_device(&advantages);
    let b_ret = r.to_device(&returns);
    let b_logp = r.to_device(&r.log_probs);
    let b_val = r.to_device(&r.values);
    let b_act = r.to_device(&r.actions);
    let b_valid = flags(r, &r.valid);
    let per_mb = n.div_ceil(hp.minibatches);
    let mut envs: Vec<i64> = (0..n as i64).collect();
    let mut sums = [0.0f64; 6];
    let mut batches = 0.0;

    'epochs: for _epoch in 0..hp.epochs {
        envs.shuffle(rng);
        for mb in envs.chunks(per_mb) {
            if (how.interrupted)() {
                m.cut_short = true;
                break 'epochs;
            }
            let idx = Tensor::from_slice(mb).to_device(r.device());
            let sel = |t: &Tensor| t.index_select(1, &idx);
            let starts: Vec<bool> =
                (0..t_len).flat_map(|t| mb.iter().map(move |&k| r.starts[t * n + k as usize])).collect();
            let valid = sel(&b_valid);
            let x = r.minibatch(&idx).expect("a full rollout has inputs");
            stages.lap(Stage::UpdatePrepare);

            // Re-run the network over the minibatch's whole sequences.
            let (logits, values) = net.evaluate(&x, &r.h0.index_select(1, &idx), &starts);
            let logp_all = logits.log_softmax(-1, Kind::Float);
            let new_logp = logp_all.gather(-1, &sel(&b_act).unsqueeze(-1), false).squeeze_dim(-1);
            let entropy = -(logp_all.exp() * &logp_all).sum_dim_intlist(-1, false, Kind::Float);

            // Probability ratio r_t of Eq. 4.2, and how far the policy moved.
            let log_ratio = new_logp - sel(&b_logp);
            let ratio = log_ratio.exp();
            let (approx_kl, clip_fraction) = tch::no_grad(|| {
                let kl = masked_mean(&((&ratio - 1.0) - &log_ratio), &valid).double_value(&[]);
                let clipped = (&ratio - 1.0).abs().gt(hp.clip).to_kind(Kind::Float);
                (kl, masked_mean(&clipped, &valid).double_value(&[]))
            });

            // Advantages normalised over the minibatch's learnable steps.
            let adv = normalize_masked(&sel(&b_adv), &valid);
            let pg_loss = clipped_policy_loss(&ratio, &adv, &valid, hp.clip);
            let v_loss = value_loss(&values, &sel(&b_val), &sel(&b_ret), &valid, hp.clip_value_loss.then_some(hp.clip));
            let ent = masked_mean(&entropy, &valid);
            let loss = &pg_loss - hp.entropy_coef * &ent + hp.value_coef * &v_loss;

            opt.zero_grad();
            loss.backward();
            stages.lap(Stage::UpdateBackward);
            let grad_norm = opt.clip_grad_norm(hp.max_grad_norm);
            if grad_norm.is_finite() {
                opt.step();
                stages.lap(Stage::UpdateStep);
            } else {
                // one bad minibatch must not poison every weight with NaN
                m.skipped_steps += 1;
                continue;
            }

            for (s, v) in sums.iter_mut().zip([
                pg_loss.double_value(&[]),
                v_loss.double_value(&[]),
                ent.double_value(&[]),
                approx_kl,
                clip_fraction,
                grad_norm,
            ]) {
                *s += v;
            }
            batches += 1.0;
        }
    }
    let batches = f64::max(batches, 1.0);
    m.policy_loss = sums[0] / batches;
    m.value_loss = sums[1] / batches;
    m.entropy = sums[2] / batches;
    m.approx_kl = sums[3] / batches;
    m.clip_fraction = sums[4] / batches;
    m.grad_norm = sums[5] / batches;
    m
}

/// Generalised advantage estimation over `[T, N]` host arrays (index `t * N + n`):
/// δ_t = r_t + γ·V(s_{t+1})·(1 − end_t) − V(s_t),  A_t = δ_t + γλ·(1 − end_t)·A_{t+1}.
/// `bootstrap[n]` is V of the observation after the last step. Truncations already carry γ·V of
/// their final observation in `rewards`, and `ends` there, so one rule covers both endings.
/// Returns (advantages, returns = advantages + values).
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    ends: &[bool],
    bootstrap: &[f32],
    envs: usize,
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let steps = rewards.len() / envs;
    let mut adv = vec![0.0f32; rewards.len()];
    for n in 0..envs {
        let mut last = 0.0f32;
        for t in (0..steps).rev() {
            let i = t * envs + n;
            let next_value = if t + 1 == steps { bootstrap[n] } else { values[i + envs] };
            let not_end = if ends[i] { 0.0 } else { 1.0 };
            let delta = rewards[i] + gamma * next_value * not_end - values[i];
            last = delta + gamma * lambda * not_end * last;
            adv[i] = last;
        }
    }
    let returns = adv.iter().zip(values).map(|(a, v)| a + v).collect();
    (adv, returns)
}

/// Mean of `x` over the entries where `valid` is 1.
pub fn masked_mean(x: &Tensor, valid: &Tensor) -> Tensor {
    (x * valid).sum(Kind::Float) / valid.sum(Kind::Float).clamp_min(1.0)
}

fn normalize_masked(x: &Tensor, valid: &Tensor) -> Tensor {
    let mean = masked_mean(x, valid);
    let std = masked_mean(&(x - &mean).square(), valid).sqrt();
    (x - mean) / (std + 1e-8)
}

/// The clipped surrogate of Eq. 4.2, as a loss to minimise:
/// mean over valid steps of max(−A·r, −A·clip(r, 1−ε, 1+ε)).
pub fn clipped_policy_loss(ratio: &Tensor, adv: &Tensor, valid: &Tensor, clip: f64) -> Tensor {
    let unclipped = -adv * ratio;
    let clipped = -adv * ratio.clamp(1.0 - clip, 1.0 + clip);
    masked_mean(&unclipped.maximum(&clipped), valid)
}

/// ½·mean (V − R)², or with `clip`, ½·mean max((V − R)², (V_old + clip(V − V_old, ±ε) − R)²).
pub fn value_loss(new: &Tensor, old: &Tensor, returns: &Tensor, valid: &Tensor, clip: Option<f64>) -> Tensor {
    let unclipped = (new - returns).square();
    let l = match clip {
        Some(c) => {
            let v_clipped = old + (new - old).clamp(-c, c);
            unclipped.maximum(&(v_clipped - returns).square())
        }
        None => unclipped,
    };
    0.5 * masked_mean(&l, valid)
}

/// 1 − Var(R − V) / Var(R) over valid steps (1: the critic explains the returns; ≤ 0: not at all).
pub fn explained_variance(values: &[f32], returns: &[f32], valid: &[bool]) -> f64 {
    let pairs: Vec<(f64, f64)> =
        values.iter().zip(returns).zip(valid).filter(|(_, v)| **v).map(|((v, r), _)| (*v as f64, *r as f64)).collect();
    if pairs.len() < 2 {
        return 0.0;
    }
    let var = |xs: &mut dyn Iterator<Item = f64>| {
        let v: Vec<f64> = xs.collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64
    };
    let var_r = var(&mut pairs.iter().map(|p| p.1));
    if var_r < 1e-12 {
        return 0.0;
    }
    1.0 - var(&mut pairs.iter().map(|p| p.1 - p.0)) / var_r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(v: &[f32]) -> Tensor {
        Tensor::from_slice(v)
    }

    /// γ = λ = 0.5, one env, V = [1, 2, 3, 4], r = 1 everywhere, the episode ends after step 1,
    /// V(next) = 8:
    /// t3: δ = 1 + .5·8 − 4 = 1                       A = 1
    /// t2: δ = 1 + .5·4 − 3 = 0                       A = 0 + .25·1 = 0.25
    /// t1: ended: δ = 1 − 2 = −1                      A = −1
    /// t0: δ = 1 + .5·2 − 1 = 1                       A = 1 + .25·(−1) = 0.75
    #[test]
    fn gae_by_hand_with_an_episode_end() {
        let (a, r) = gae(&[1.0; 4], &[1.0, 2.0, 3.0, 4.0], &[false, true, false, false], &[8.0], 1, 0.5, 0.5);
        assert_eq!(a, vec![0.75, -1.0, 0.25, 1.0]);
        assert_eq!(r, vec![1.75, 1.0, 3.25, 5.0]);
    }

    /// The rollout's view of a truncation (γ·V(final obs) folded into the reward, `ends` set)
    /// through GAE, with two envs interleaved: env 0 is truncated after step 0 with V(final) = 6,
    /// env 1 terminates after step 0 (no bootstrap).
    #[test]
    fn gae_truncated_bootstraps_terminated_does_not() {
        let gamma = 0.5;
        // env 0: r0 = 0.5 + γ·6 = 3.5 (truncation), step 1 is the ignored final observation.
        let rewards = [0.5 + gamma * 6.0, 1.0, 0.0, 0.0];
        let values = [2.0, 2.0, 6.0, 0.5];
        let ends = [true, true, true, false];
        let (a, _) = gae(&rewards, &values, &ends, &[9.0, 4.0], 2, gamma, 1.0);
        // env 0 t0: δ = 3.5 − 2 = 1.5 (= r + γ·V(final) − V), nothing flows back from t1
        assert_eq!(a[0], 1.5);
        // env 1 t0: terminated: δ = 1 − 2 = −1, V(s1) ignored
        assert_eq!(a[1], -1.0);
        // env 1 t1: δ = 0 + .5·4 − .5 = 1.5
        assert_eq!(a[3], 1.5);
    }

    /// ratio [0.5, 1, 1.5, 1.5], A [1, −1, 1, −1], ε = 0.2:
    /// max(−A·r, −A·clip(r)) = [max(−.5, −.8), max(1, 1), max(−1.5, −1.2), max(1.5, 1.2)]
    ///                       = [−0.5, 1, −1.2, 1.5] → mean 0.2; without the last step −0.7/3.
    #[test]
    fn clipped_loss_by_hand() {
        let ratio = t(&[0.5, 1.0, 1.5, 1.5]);
        let adv = t(&[1.0, -1.0, 1.0, -1.0]);
        let all = t(&[1.0; 4]);
        let l = clipped_policy_loss(&ratio, &adv, &all, 0.2).double_value(&[]);
        assert!((l - 0.2).abs() < 1e-6, "{l}");
        let l = clipped_policy_loss(&ratio, &adv, &t(&[1.0, 1.0, 1.0, 0.0]), 0.2).double_value(&[]);
        assert!((l + 0.7 / 3.0).abs() < 1e-6, "{l}");
    }

    /// old V [0, 0], new V [1, −0.1], R [2, 1], ε = 0.2:
    /// (1−2)² = 1 vs clipped (0.2−2)² = 3.24 → 3.24; (−0.1−1)² = 1.21 (inside the clip)
    /// → ½·(3.24 + 1.21)/2 = 1.1125; unclipped: ½·(1 + 1.21)/2 = 0.5525.
    #[test]
    fn value_loss_by_hand() {
        let (new, old, ret, all) = (t(&[1.0, -0.1]), t(&[0.0, 0.0]), t(&[2.0, 1.0]), t(&[1.0, 1.0]));
        let l = value_loss(&new, &old, &ret, &all, Some(0.2)).double_value(&[]);
        assert!((l - 1.1125).abs() < 1e-6, "{l}");
        let l = value_loss(&new, &old, &ret, &all, None).double_value(&[]);
        assert!((l - 0.5525).abs() < 1e-6, "{l}");
    }

    #[test]
    fn explained_variance_extremes() {
        let r = [1.0, 2.0, 3.0];
        assert!((explained_variance(&r, &r, &[true; 3]) - 1.0).abs() < 1e-9);
        assert!(explained_variance(&[0.0; 3], &r, &[true; 3]).abs() < 1e-9);
    }

    /// A stop during an update ends its epochs before the next minibatch: nothing more is
    /// learned from the rollout, the update is counted (its frames were collected) and says so.
    #[test]
    fn a_stop_cuts_the_update_short() {
        let mut cfg = crate::bench::tiny_config();
        cfg.ppo.rollout = 8;
        let mut t = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
        crate::bench::fill_rollout(&mut t, 1).unwrap();
        let before: Vec<Tensor> = t.agent.vs.trainable_variables().iter().map(|v| v.copy()).collect();
        t.interrupted = || true;
        let m = crate::bench::update_once(&mut t);
        assert!(m.cut_short && m.update == 1 && m.frames == 16, "{m:?}");
        let after = t.agent.vs.trainable_variables();
        assert!(before.iter().zip(&after).all(|(a, b)| a.equal(b)), "weights moved");
        crate::bench::fill_rollout(&mut t, 2).unwrap();
        t.interrupted = || false;
        let m = crate::bench::update_once(&mut t);
        assert!(!m.cut_short && m.update == 2);
        assert!(before.iter().zip(&t.agent.vs.trainable_variables()).any(|(a, b)| !a.equal(b)), "learned");
    }

    /// Env groups change when envs are inferred, not what they do or learn: a trainer acting on
    /// two halves of its envs in turn (each rollout's last step on all) takes the actions, stores
    /// the rollout and makes the updates of one acting on all at once — over two rollouts, with
    /// episodes ending and gestures changing in one half only.
    #[test]
    fn env_groups_act_and_learn_as_one_round() {
        let mut cfg = crate::bench::tiny_config();
        cfg.ppo.rollout = 4;
        cfg.ppo.minibatches = 2;
        let n = 4;
        let mut whole = Trainer::new(&cfg, n, Device::Cpu).unwrap();
        let mut halves = Trainer::new(&cfg, n, Device::Cpu).unwrap();
        let mut obs = crate::bench::random_obs(n, 64, 1);
        for step in 0..2 * cfg.ppo.rollout + 2 {
            if step > 0 {
                let next = crate::bench::random_obs(n, 64, step as u64 + 1);
                // envs 0 and 1 keep their gesture; 2 and 3 see a new one every step
                let g = obs.gesture.len() / 2;
                obs.gesture[g..].copy_from_slice(&next.gesture[g..]);
                obs.rgb = next.rgb;
                obs.depth = next.depth;
                for (i, e) in obs.envs.iter_mut().enumerate() {
                    let ends = i == 1 && step % 3 == 0;
                    e.episode_start = i == 1 && step % 3 == 1;
                    e.terminated = ends;
                    e.reward = if ends { 2.5 } else { -0.01 * (i + step) as f32 };
                }
            }
            let want = whole.step(&obs.batch()).unwrap();
            let (got, updated) = if halves.wants_all() {
                let o = halves.step(&obs.batch()).unwrap();
                (o.actions, o.update.is_some())
            } else {
                let a = halves.step_at(0, &obs.batch_of(0..2)).unwrap();
                let b = halves.step_at(2, &obs.batch_of(2..4)).unwrap();
                assert!(a.update.is_none() && b.update.is_none(), "an update on a group's round");
                let mut both = a.actions;
                both.actions.extend(b.actions.actions);
                both.log_probs.extend(b.actions.log_probs);
                both.values.extend(b.actions.values);
                (both, false)
            };
            assert_eq!(want.update.is_some(), updated, "step {step}");
            assert_eq!(want.actions.actions, got.actions, "step {step}");
            for (w, g) in
                want.actions.log_probs.iter().zip(&got.log_probs).chain(want.actions.values.iter().zip(&got.values))
            {
                assert!((w - g).abs() < 1e-4, "step {step}: {w} against {g}");
            }
        }
        assert_eq!((whole.updates, halves.updates), (2, 2));
        assert_eq!(whole.rollout.rewards, halves.rollout.rewards);
        assert_eq!(whole.rollout.starts, halves.rollout.starts);
        for (a, b) in whole.agent.vs.trainable_variables().iter().zip(&halves.agent.vs.trainable_variables()) {
            assert!(a.allclose(b, 1e-4, 1e-5, false), "the updates differ");
        }
        // a group alone cannot end a rollout: the update needs every env's next observation
        let mut t = Trainer::new(&cfg, n, Device::Cpu).unwrap();
        for _ in 0..cfg.ppo.rollout {
            t.step(&obs.batch()).unwrap();
        }
        let err = t.step_at(0, &obs.batch_of(0..2)).unwrap_err().to_string();
        assert!(err.contains("every env"), "{err}");
    }

    /// Untimed, a trainer keeps no stage times. Timed, a rollout and its update charge every
    /// stage of acting and of the update — on the small CNNs (visual branches in the forward)
    /// and on the frozen pretrained encoder (run while preparing the inputs) — and a call's
    /// stages never add up to more than its wall time.
    #[test]
    fn stage_times_fill_every_stage_within_each_call() {
        let dir = tempfile::tempdir().unwrap();
        let weights = crate::bench::random_encoder_weights(dir.path(), 64).unwrap();
        for mut cfg in [crate::bench::tiny_config(), crate::bench::tiny_frozen_config(&weights)] {
            (cfg.ppo.rollout, cfg.ppo.epochs, cfg.model.hidden) = (4, 1, 32);
            let mut t = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
            let obs = crate::bench::random_obs(2, 64, 1);
            t.step(&obs.batch()).unwrap();
            assert_eq!(t.stage_times(), None);
            t.time_stages();
            let sum =
                |s: farm::profile::StageTimes| s.acting().iter().chain(&s.updating()).map(|(_, v)| v).sum::<f64>();
            // the rollout's other steps, then the call that completes it and updates
            for _ in 0..cfg.ppo.rollout {
                let before = sum(t.stage_times().unwrap());
                let began = Instant::now();
                t.step(&obs.batch()).unwrap();
                let wall = began.elapsed().as_secs_f64();
                let charged = sum(t.stage_times().unwrap()) - before;
                assert!(charged <= wall, "{charged} s of stages in a {wall} s call");
            }
            let s = t.stage_times().unwrap();
            assert_eq!((s.rounds, s.updates), (cfg.ppo.rollout as u64, 1));
            for (name, v) in s.acting().iter().chain(&s.updating()) {
                assert!(*v > 0.0, "{:?}: {name} not charged: {s:?}", cfg.model.encoder);
            }
        }
    }

    /// `ppo.overlap_update`: a rollout is learned while the next is collected with the weights
    /// before it. Its first update, joined when the second rollout is full, gives the weights,
    /// moments and minibatch order of the in-place update of the same rollout; every later one
    /// reports a policy lag of 1. A checkpoint written while an update is in flight holds the
    /// trainer as it was after the last joined one, and a stop learns every rollout collected.
    #[test]
    fn an_overlapped_update_learns_the_in_place_one_a_rollout_later() {
        let mut cfg = crate::bench::tiny_config();
        (cfg.ppo.rollout, cfg.ppo.minibatches) = (4, 2);
        let t_len = cfg.ppo.rollout;
        let n = 2;
        let mut in_place = Trainer::new(&cfg, n, Device::Cpu).unwrap();
        cfg.ppo.overlap_update = true;
        let mut overlapped = Trainer::new(&cfg, n, Device::Cpu).unwrap();
        let weights = |t: &Trainer| t.agent.vs.trainable_variables().iter().map(|v| v.copy()).collect::<Vec<_>>();
        let mut first = None;
        let mut obs = crate::bench::random_obs(n, 64, 1);
        let dir = tempfile::tempdir().unwrap();
        for step in 0..=3 * t_len {
            if step > 0 {
                let next = crate::bench::random_obs(n, 64, step as u64 + 1);
                (obs.rgb, obs.depth) = (next.rgb, next.depth);
                obs.envs.iter_mut().enumerate().for_each(|(i, e)| e.reward = 0.1 * (i + step % 3) as f32);
            }
            let a = in_place.step(&obs.batch()).unwrap();
            let b = overlapped.step(&obs.batch()).unwrap();
            assert_eq!(a.update.as_ref().map(|m| m.policy_lag), (step % t_len == 0 && step > 0).then_some(0));
            if step == t_len {
                assert!(b.update.is_none(), "nothing was learned yet");
                first = Some((weights(&in_place), in_place.opt.step, in_place.rng.clone()));
            }
            if step == 2 * t_len {
                let m = b.update.as_ref().expect("the first rollout's update, joined");
                assert_eq!((m.update, m.frames, m.policy_lag), (1, (t_len * n) as u64, 0));
                let (w, adam_step, rng) = first.take().unwrap();
                assert!(weights(&overlapped).iter().zip(&w).all(|(a, b)| a.allclose(b, 1e-6, 1e-7, false)));
                assert_eq!((overlapped.opt.step, &overlapped.rng), (adam_step, &rng));
            }
            if step == 2 * t_len + 1 {
                // the second rollout's update is in flight: a checkpoint is the trainer after the first
                let path = dir.path().join("in-flight.safetensors");
                crate::ppo::checkpoint::save_trainer(&path, &overlapped).unwrap();
                let mut resumed = Trainer::new(&cfg, n, Device::Cpu).unwrap();
                crate::ppo::checkpoint::load_trainer(&path, &mut resumed).unwrap();
                assert_eq!(
                    (resumed.updates, resumed.frames, resumed.opt.step),
                    (1, (t_len * n) as u64, (cfg.ppo.epochs * 2) as i64)
                );
                assert!(weights(&resumed).iter().zip(&weights(&overlapped)).all(|(a, b)| a.equal(b)));
            }
            if step == 3 * t_len {
                let m = b.update.as_ref().expect("the second rollout's update");
                assert_eq!((m.update, m.policy_lag), (2, 1));
            }
        }
        // the third rollout is queued: a stop learns it
        let last = overlapped.settle();
        assert_eq!(last.iter().map(|m| (m.update, m.policy_lag)).collect::<Vec<_>>(), vec![(3, 1)]);
        assert_eq!((overlapped.updates, overlapped.frames), (in_place.updates, in_place.frames));
        assert!(overlapped.settle().is_empty() && in_place.settle().is_empty());
    }

    #[test]
    fn lr_decays_linearly_to_zero() {
        let cfg = RunConfig::from_toml("[run]\nmethod = \"both\"\ntotal_frames = 1000\n", "x.toml").unwrap();
        let lr = |frames| lr_at(&cfg.ppo, cfg.run.total_frames, frames);
        assert_eq!(lr(0), 3e-4);
        assert!((lr(250) - 2.25e-4).abs() < 1e-12);
        assert_eq!(lr(1000), 0.0);
        assert_eq!(lr(5000), 0.0);
    }
}
