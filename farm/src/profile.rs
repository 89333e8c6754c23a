//! Where a training run's time goes: the learner's timeline (and, when it times them, its acting
//! and updates by stage) and its workers' loops, as cumulative seconds. The learner writes one
//! into every progress record (`farm.jsonl`, field `profile`); `orchestrator bench train` reads
//! the last one.

use serde::{Deserialize, Serialize};
use shm_schema::WorkerTiming;

/// Cumulative seconds since the learner started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LearnerTime {
    /// Waiting for the workers' observations (they step, render and send meanwhile).
    pub wait_s: f64,
    /// Taking observations in: integrity checks, batching, records.
    pub receive_s: f64,
    /// The policy's forward pass and sampling (acting).
    pub infer_s: f64,
    /// Sending actions and waking the workers.
    pub send_s: f64,
    /// PPO updates (the workers wait meanwhile unless collection overlaps learning).
    pub update_s: f64,
    /// Processor seconds of the learner process (all its threads) in updates and in acting:
    /// over the wall seconds above, the cores each phase keeps busy — what collection running
    /// beside learning would have to share. A round that ends a rollout is split between the two
    /// in proportion to their wall time.
    pub update_cpu_s: f64,
    pub infer_cpu_s: f64,
    /// Processor seconds of the learner process so far, whatever it did (torch's threads spinning
    /// while the learner waits included).
    pub cpu_s: f64,
}

impl LearnerTime {
    /// Wall seconds accounted for.
    pub fn total(&self) -> f64 {
        self.wait_s + self.receive_s + self.infer_s + self.send_s + self.update_s
    }
}

/// Processor seconds used by this process so far, all threads together.
pub fn process_cpu_seconds() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(0.0)
}

/// Cumulative seconds of the workers' loops, summed over the workers' current processes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct WorkerTime {
    /// Stepping envs (physics, task, gestures) and writing observations, rendering excluded.
    pub sim_s: f64,
    pub render_s: f64,
    /// Loaning, sending, notifying.
    pub send_s: f64,
    /// Waiting for the learner's actions.
    pub wait_s: f64,
}

impl WorkerTime {
    /// Adds one worker's cumulative timing as its observation header carries it.
    pub fn add(&mut self, t: &WorkerTiming) {
        let s = |ns: u64| ns as f64 * 1e-9;
        self.sim_s += s(t.sim_ns);
        self.render_s += s(t.render_ns);
        self.send_s += s(t.send_ns);
        self.wait_s += s(t.wait_ns);
    }

    pub fn total(&self) -> f64 {
        self.sim_s + self.render_s + self.send_s + self.wait_s
    }
}

/// Cumulative wall seconds of the learner's acting and updates, stage by stage (`learner serve
/// --profile-stages`). A GPU is synchronized after each stage, so that a stage is charged its own
/// work rather than whatever the device still had queued — which slows the run down.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StageTimes {
    /// Acting: the frames and gestures onto the device (host copy into pinned staging and
    /// upload, or the copies out of the workers' device frames), and the other inputs.
    pub act_inputs_s: f64,
    /// Acting: the visual encoders: the frozen trunk or pretrained encoder whose features the
    /// rollout stores, and the network's visual branches (their heads, or whole trained CNNs).
    pub act_visual_s: f64,
    /// Acting: the rest of the forward: gesture network, target and pose layers, GRU, heads.
    pub act_rest_s: f64,
    /// Acting: the logits' and values' copy to the host, and sampling the actions.
    pub act_sample_s: f64,
    /// Acting: the previous action's feedback and this step stored in the rollout, the memory
    /// committed.
    pub act_store_s: f64,
    /// Updating: GAE, the rollout's arrays onto the device, each minibatch's selection, the
    /// update's books.
    pub update_prepare_s: f64,
    /// Updating: each minibatch's forward over its sequences, the losses, the backward pass.
    pub update_backward_s: f64,
    /// Updating: gradient clipping and the optimizer's steps.
    pub update_step_s: f64,
    /// Acting calls timed (a round, or one group's round with `ppo.env_groups`).
    pub rounds: u64,
    /// Updates timed.
    pub updates: u64,
}

impl StageTimes {
    /// The acting stages, by name, in the order they run.
    pub fn acting(&self) -> [(&'static str, f64); 5] {
        [
            ("inputs onto the device", self.act_inputs_s),
            ("visual encoders", self.act_visual_s),
            ("rest of the forward (gesture, GRU, heads)", self.act_rest_s),
            ("actions to the host, sampling", self.act_sample_s),
            ("storing the step", self.act_store_s),
        ]
    }

    /// The update's stages, by name, in the order they run.
    pub fn updating(&self) -> [(&'static str, f64); 3] {
        [
            ("GAE, minibatches", self.update_prepare_s),
            ("forward + backward", self.update_backward_s),
            ("gradient clipping + optimizer step", self.update_step_s),
        ]
    }
}

/// The profile of a run so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Profile {
    pub learner: LearnerTime,
    pub workers: WorkerTime,
    /// Only when the learner times its stages: without, its records stay as they were.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stages: Option<StageTimes>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_nanoseconds_add_up_as_seconds() {
        let mut w = WorkerTime::default();
        let t = WorkerTiming { sim_ns: 1_500_000_000, render_ns: 500_000_000, send_ns: 0, wait_ns: 2_000_000_000 };
        w.add(&t);
        w.add(&t);
        assert_eq!((w.sim_s, w.render_s, w.wait_s), (3.0, 1.0, 4.0));
        assert_eq!(w.total(), 8.0);
        let p: Profile = serde_json::from_str(r#"{"learner": {"update_s": 2.5}}"#).unwrap();
        assert_eq!(p.learner.update_s, 2.5);
        assert_eq!(p.workers, WorkerTime::default());
        let spent = process_cpu_seconds();
        let mut x = 0u64;
        for i in 0..20_000_000u64 {
            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(i));
        }
        assert!(process_cpu_seconds() > spent, "{x}");
    }

    /// A learner that times no stages writes the records it wrote before stages existed.
    #[test]
    fn stage_times_are_written_only_when_timed() {
        assert!(!serde_json::to_string(&Profile::default()).unwrap().contains("stages"));
        let timed = Profile {
            stages: Some(StageTimes { act_visual_s: 1.5, rounds: 3, ..Default::default() }),
            ..Default::default()
        };
        let back: Profile = serde_json::from_str(&serde_json::to_string(&timed).unwrap()).unwrap();
        assert_eq!(back, timed);
    }
}
