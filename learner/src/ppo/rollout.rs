//! Rollout storage: T steps × N envs of what PPO needs, filled one step at a time.
//!
//! Network inputs stay on the device in their stored form (`[T, N, ..]`; frozen ResNet features,
//! or raw u8 frames for trained encoders); the per-step scalars (actions, log-probs, values,
//! rewards, flags) are small and live on the host, where GAE runs.
//!
//! Slot (t, n) holds observation o_t of env n, the action taken on it, and — once the next
//! message arrives — that action's reward and whether the episode ended after it. How the
//! message flags become `rewards`, `ends` and `valid` is [`Rollout::record_feedback`]; the step
//! protocol itself is described in [`crate::obs`].

use tch::{Device, Kind, Tensor};

use crate::inputs::Inputs;
use crate::net::agent::Actions;
use crate::obs::EnvStep;
use crate::ppo::gesture_table::GestureTable;

#[derive(Debug)]
pub struct Rollout {
    pub steps: usize,
    pub envs: usize,
    device: Device,
    /// `[T, N, ..]`, allocated at the first push (its shapes come from the network); gestures
    /// are kept apart, each distinct one once.
    inputs: Option<Inputs>,
    gestures: Option<GestureTable>,
    /// Recurrent state before step 0 (before its episode-start resets), `[L, N, H]`.
    pub h0: Tensor,
    /// Every vector below is `[T * N]`, index `t * N + n`.
    /// The observation starts an episode: memory is reset before it.
    pub starts: Vec<bool>,
    pub actions: Vec<i64>,
    pub log_probs: Vec<f32>,
    pub values: Vec<f32>,
    /// Reward of the action, plus γ·V(final observation) where the episode was truncated after it.
    pub rewards: Vec<f32>,
    /// The episode ended after this step: no value flows back across it in GAE.
    pub ends: Vec<bool>,
    /// The step is learned from (false: the action was ignored or its feedback was lost).
    pub valid: Vec<bool>,
    len: usize,
    /// Envs of step `len` stored so far (a round of one group of envs stores some of them).
    filled: Vec<bool>,
}

/// What one message's feedback did, for the run's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedbackCounts {
    /// Truncations bootstrapped from the final observation's value.
    pub bootstrapped: usize,
    /// Truncations that came with the next episode's observation instead of the final one
    /// (the worker reset at once): no bootstrap was possible; treated as terminated.
    pub truncated_without_final: usize,
    pub lost: usize,
}

impl Rollout {
    pub fn new(steps: usize, envs: usize, h0: &Tensor) -> Rollout {
        let n = steps * envs;
        Rollout {
            steps,
            envs,
            device: h0.device(),
            inputs: None,
            gestures: None,
            h0: h0.copy(),
            starts: vec![false; n],
            actions: vec![0; n],
            log_probs: vec![0.0; n],
            values: vec![0.0; n],
            rewards: vec![0.0; n],
            ends: vec![false; n],
            valid: vec![false; n],
            len: 0,
            filled: vec![false; envs],
        }
    }

    /// Starts a new rollout from memory `h0`; the stored tensors are reused.
    pub fn begin(&mut self, h0: &Tensor) {
        self.h0 = h0.copy();
        self.len = 0;
        self.filled.iter_mut().for_each(|f| *f = false);
        if let Some(g) = &mut self.gestures {
            g.clear();
        }
        self.rewards.iter_mut().for_each(|r| *r = 0.0);
        self.ends.iter_mut().for_each(|e| *e = false);
        self.valid.iter_mut().for_each(|v| *v = false);
    }

    /// Steps stored so far.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn is_full(&self) -> bool {
        self.len == self.steps
    }

    /// Stored per-row inputs `[T, N, ..]` (None before the first push); without the gestures,
    /// which [`Rollout::minibatch`] adds.
    pub fn inputs(&self) -> Option<&Inputs> {
        self.inputs.as_ref()
    }

    /// The distinct gestures stored (None before the first push or without gestures).
    pub fn gestures(&self) -> Option<&GestureTable> {
        self.gestures.as_ref()
    }

    /// The stored inputs of envs `idx` (a minibatch), `[T, B, ..]`: every per-row field selected,
    /// and the gestures as a table of the distinct ones these envs showed, with each row's index
    /// into it.
    pub fn minibatch(&self, idx: &Tensor) -> Option<Inputs> {
        let sel = |t: &Tensor| t.index_select(1, idx);
        let mut x = self.inputs.as_ref()?.map(sel);
        if let Some(g) = &self.gestures {
            // only this minibatch's rows: the per-frame network reads each of them once, and
            // none that another minibatch's envs showed
            let ids = sel(g.ids());
            let (used, inverse, _) = ids.flatten(0, -1).internal_unique2(true, true, false);
            x.gesture = Some(g.rows().index_select(0, &used));
            x.gesture_index = Some(inverse.view_as(&ids));
        }
        Some(x)
    }

    /// Appends one step: its inputs, memory resets, chosen actions, and which envs' steps can be
    /// learned from (a final observation's action is ignored by the env; a lost message is junk).
    pub fn push(&mut self, x: &Inputs, starts: &[bool], acted: &Actions, valid: &[bool]) {
        self.push_at(0, x, starts, acted, valid)
    }

    /// [`Rollout::push`] of envs `at..at + B` (one group of an acting round); the step is stored
    /// once every env has been.
    pub fn push_at(&mut self, at: usize, x: &Inputs, starts: &[bool], acted: &Actions, valid: &[bool]) {
        assert!(self.len < self.steps, "rollout is full: call the update first");
        let (n, b) = (self.envs, starts.len());
        let filled = &mut self.filled[at..at + b];
        assert!(filled.iter().all(|f| !f), "envs {at}..{} stored twice in step {}", at + b, self.len);
        filled.iter_mut().for_each(|f| *f = true);
        let (t, device) = (self.len, self.device);
        let stored = self.inputs.get_or_insert_with(|| {
            let mut s = x.map(|v| {
                let mut shape = vec![self.steps as i64, n as i64];
                shape.extend(&v.size()[1..]);
                Tensor::zeros(shape.as_slice(), (v.kind(), device))
            });
            s.gesture = None;
            s
        });
        tch::no_grad(|| {
            for ((_, dst), (_, src)) in stored.fields().iter().zip(x.fields()) {
                if let (Some(dst), Some(src)) = (dst, src) {
                    dst.get(t as i64).narrow(0, at as i64, b as i64).copy_(src);
                }
            }
        });
        if let Some(g) = &x.gesture {
            let (steps, envs) = (self.steps, self.envs);
            self.gestures
                .get_or_insert_with(|| GestureTable::new(steps, envs, &g.get(0).to_device(device)))
                .push_at(t, at, g);
        }
        let r = t * n + at..t * n + at + b;
        self.starts[r.clone()].copy_from_slice(starts);
        self.actions[r.clone()].copy_from_slice(&acted.actions);
        self.log_probs[r.clone()].copy_from_slice(&acted.log_probs);
        self.values[r.clone()].copy_from_slice(&acted.values);
        self.valid[r].copy_from_slice(valid);
        if self.filled.iter().all(|f| *f) {
            self.len += 1;
            self.filled.iter_mut().for_each(|f| *f = false);
        }
    }

    /// Records, in the last stored step, the feedback that the next message carries:
    /// - reward of the action; `ends` when the episode ended after it (terminated, truncated, or
    ///   the next observation starts a new episode);
    /// - truncated with the final observation: add γ·V(final observation) (`values_now`, the value
    ///   the policy just computed on that observation) — the Gymnasium bootstrap;
    /// - lost message: the step is not learned from.
    pub fn record_feedback(&mut self, envs: &[EnvStep], values_now: &[f32], gamma: f32) -> FeedbackCounts {
        self.record_feedback_at(0, envs, values_now, gamma)
    }

    /// [`Rollout::record_feedback`] of envs `at..at + envs.len()`.
    pub fn record_feedback_at(
        &mut self,
        at: usize,
        envs: &[EnvStep],
        values_now: &[f32],
        gamma: f32,
    ) -> FeedbackCounts {
        let mut counts = FeedbackCounts::default();
        let Some(t) = self.len.checked_sub(1) else { return counts };
        for (k, e) in envs.iter().enumerate() {
            let i = t * self.envs + at + k;
            if e.lost {
                self.rewards[i] = 0.0;
                self.ends[i] = true;
                self.valid[i] = false;
                counts.lost += 1;
                continue;
            }
            self.rewards[i] = e.reward;
            if e.bootstraps() {
                self.rewards[i] += gamma * values_now[k];
                counts.bootstrapped += 1;
            } else if e.truncated && !e.terminated {
                counts.truncated_without_final += 1;
            }
            self.ends[i] = e.terminated || e.truncated || e.episode_start;
        }
        counts
    }

    /// Host vector `[T, N]` → device tensor.
    pub fn to_device<T: tch::kind::Element + Copy>(&self, v: &[T]) -> Tensor {
        Tensor::from_slice(v).view([self.steps as i64, self.envs as i64]).to_device(self.device)
    }

    pub fn device(&self) -> Device {
        self.device
    }
}

/// `bool` host flags as 0/1 floats.
fn as_f32(v: &[bool]) -> Vec<f32> {
    v.iter().map(|b| if *b { 1.0 } else { 0.0 }).collect()
}

/// A `[T, N]` float tensor of flags.
pub fn flags(r: &Rollout, v: &[bool]) -> Tensor {
    r.to_device(&as_f32(v)).to_kind(Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn acted(n: usize, value: f32) -> Actions {
        Actions { actions: vec![1; n], log_probs: vec![-1.0; n], values: vec![value; n] }
    }

    fn no_inputs() -> Inputs {
        Inputs {
            rgb: None,
            depth: None,
            visual: None,
            gesture: None,
            gesture_index: None,
            target: Some(Tensor::from_slice(&[3i64])),
            pose: None,
        }
    }

    /// One env through: a terminated episode (worker resets at once), then a truncated one whose
    /// final observation is sent before the reset (next-step autoreset).
    #[test]
    fn terminated_and_truncated_feedback() {
        let h0 = Tensor::zeros([1, 1, 4], (Kind::Float, Device::Cpu));
        let mut r = Rollout::new(6, 1, &h0);
        let step = |reward, terminated, truncated, start| EnvStep {
            reward,
            terminated,
            truncated,
            episode_start: start,
            ..Default::default()
        };
        let gamma = 0.5;
        // t0: first observation
        r.push(&no_inputs(), &[true], &acted(1, 1.0), &[true]);
        // msg 1: reward 0.25 for a0, success → terminated, the worker reset: o1 starts an episode
        let m = step(0.25, true, false, true);
        assert_eq!(r.record_feedback(&[m], &[9.0], gamma), FeedbackCounts::default());
        r.push(&no_inputs(), &[true], &acted(1, 2.0), &[!m.is_final_observation()]);
        // msg 2: plain step
        let m = step(-0.5, false, false, false);
        r.record_feedback(&[m], &[3.0], gamma);
        r.push(&no_inputs(), &[false], &acted(1, 3.0), &[true]);
        // msg 3: step limit hit; o3 is the final observation, V(o3) = 4
        let m = step(-0.25, false, true, false);
        let c = r.record_feedback(&[m], &[4.0], gamma);
        assert_eq!(c.bootstrapped, 1);
        assert!(m.is_final_observation());
        r.push(&no_inputs(), &[false], &acted(1, 4.0), &[!m.is_final_observation()]);
        // msg 4: the reset after the final observation (its action was ignored)
        let m = step(0.0, false, false, true);
        r.record_feedback(&[m], &[5.0], gamma);
        r.push(&no_inputs(), &[true], &acted(1, 5.0), &[true]);

        assert_eq!(r.rewards[..4], [0.25, -0.5, -0.25 + 0.5 * 4.0, 0.0]);
        assert_eq!(r.ends[..4], [true, false, true, true]);
        assert_eq!(r.valid[..5], [true, true, true, false, true]);
        assert_eq!(r.starts[..5], [true, true, false, false, true]);
        assert_eq!(r.len(), 5);
        let stored = r.inputs().unwrap().target.as_ref().unwrap();
        assert_eq!(stored.size(), vec![6, 1]);
    }

    /// The farm's workers send the final observation of a terminated episode too (then reset):
    /// that step is not learned from and nothing is bootstrapped.
    #[test]
    fn terminated_with_a_final_observation() {
        let h0 = Tensor::zeros([1, 1, 4], (Kind::Float, Device::Cpu));
        let mut r = Rollout::new(4, 1, &h0);
        let step =
            |reward, terminated, start| EnvStep { reward, terminated, episode_start: start, ..Default::default() };
        r.push(&no_inputs(), &[true], &acted(1, 1.0), &[true]);
        // success: reward 1 for a0; o1 is the episode's final observation
        let m = step(1.0, true, false);
        assert!(m.is_final_observation() && !m.bootstraps());
        assert_eq!(r.record_feedback(&[m], &[7.0], 0.5), FeedbackCounts::default());
        r.push(&no_inputs(), &[false], &acted(1, 7.0), &[!m.is_final_observation()]);
        // the reset: its action was ignored, reward 0
        let m = step(0.0, false, true);
        r.record_feedback(&[m], &[2.0], 0.5);
        r.push(&no_inputs(), &[true], &acted(1, 2.0), &[true]);
        assert_eq!(r.rewards[..2], [1.0, 0.0]);
        assert_eq!(r.ends[..2], [true, true]);
        assert_eq!(r.valid[..3], [true, false, true]);
    }

    #[test]
    fn lost_messages_drop_the_step_and_truncation_without_final_is_counted() {
        let h0 = Tensor::zeros([1, 2, 4], (Kind::Float, Device::Cpu));
        let mut r = Rollout::new(4, 2, &h0);
        let x = Inputs {
            rgb: None,
            depth: None,
            visual: None,
            gesture: None,
            gesture_index: None,
            target: Some(Tensor::from_slice(&[3i64, 4])),
            pose: None,
        };
        r.push(&x, &[true, true], &acted(2, 1.0), &[true, true]);
        let lost = EnvStep { lost: true, reward: 7.0, ..Default::default() };
        let cut = EnvStep { truncated: true, episode_start: true, reward: 0.5, ..Default::default() };
        let c = r.record_feedback(&[lost, cut], &[1.0, 1.0], 0.9);
        assert_eq!(c, FeedbackCounts { bootstrapped: 0, truncated_without_final: 1, lost: 1 });
        assert_eq!(r.rewards[..2], [0.0, 0.5]);
        assert_eq!(r.valid[..2], [false, true]);
        assert_eq!(r.ends[..2], [true, true]);
    }
}
