//! The worker's role in the rollout farm, apart from how messages travel: something that
//! writes observations of E environments into a buffer it is given ([`Stepper`]).
//!
//! The simulator's `worker::env::EnvPool` is the real stepper; [`SyntheticStepper`] writes counters and
//! patterned frames without simulating anything, so that the farm's plumbing (transport,
//! supervision, batching) can be tested and measured on its own.

use shm_schema::{
    EnvRecord, EpisodeSummary, ObsLayout, ObsSections, ObsShape, SUMMARY_STOPS, StopSummary, action, gesture_kind,
};

/// What the worker loop drives: E environments that write their observations straight into a
/// payload buffer (shared memory in the farm) laid out as [`Stepper::layout`] says.
pub trait Stepper {
    fn num_envs(&self) -> usize;
    /// `ObsLayout::new(E, width, height)`.
    fn layout(&self) -> ObsLayout;
    /// Starts every env and writes its first observation (records, RGB, depth, gesture).
    fn reset(&mut self, payload: &mut [u8]) -> anyhow::Result<()>;
    /// Applies one action per env, advances (episode-end protocol of `shm_schema`), and writes
    /// the next observation of every env.
    fn step(&mut self, actions: &[u8], payload: &mut [u8]) -> anyhow::Result<()>;
    /// Every env is idle: its assigned programs are done (evaluation).
    fn finished(&self) -> bool;
    /// Nanoseconds spent rendering since this stepper was made (part of `reset` and `step`), for
    /// the training profile; 0 for steppers that do not render.
    fn render_ns(&self) -> u64 {
        0
    }
}

/// Per-env state of the synthetic stepper.
#[derive(Clone, Debug, Default)]
struct SynthEnv {
    record: EnvRecord,
    /// The next observation starts a new episode (the previous one sent its final observation).
    reset_pending: bool,
    episodes_started: u64,
}

/// A stepper without a simulator: episodes of a few steps whose length and outcome follow from
/// the program id, frames with a pattern that moves with the step counter, exact counters.
/// Follows the episode-boundary protocol of `shm_schema` like the real environment does.
pub struct SyntheticStepper {
    shape: ObsShape,
    worker_id: u32,
    envs: Vec<SynthEnv>,
    /// Programs still to run, in order (evaluation); `None` draws them forever.
    queue: Option<std::collections::VecDeque<u64>>,
    next_program: u64,
    expert_hints: bool,
}

impl SyntheticStepper {
    pub fn new(
        worker_id: u32,
        num_envs: usize,
        width: u32,
        height: u32,
        programs: Option<Vec<u64>>,
        expert_hints: bool,
    ) -> Self {
        SyntheticStepper {
            shape: ObsShape::new(num_envs, width, height),
            worker_id,
            envs: vec![SynthEnv::default(); num_envs],
            queue: programs.map(Into::into),
            next_program: worker_id as u64 * 1_000_000,
            expert_hints,
        }
    }

    /// Steps an episode of program `p` lasts before it ends.
    fn episode_len(p: u64) -> u32 {
        3 + (p % 5) as u32
    }

    fn take_program(&mut self) -> Option<u64> {
        match &mut self.queue {
            Some(q) => q.pop_front(),
            None => {
                self.next_program += 1;
                Some(self.next_program)
            }
        }
    }

    fn start_episode(&mut self, e: usize) {
        let program = self.take_program();
        let env = &mut self.envs[e];
        env.reset_pending = false;
        if program.is_some() {
            env.episodes_started += 1;
        }
        let started = env.episodes_started;
        let r = &mut env.record;
        match program {
            None => {
                r.idle = 1;
                r.terminated = 0;
                r.truncated = 0;
                r.episode_start = 0;
            }
            Some(p) => {
                r.episode = started;
                r.program = p;
                r.episode_step = 0;
                r.last_action = action::NONE as u32;
                r.reward = 0.0;
                r.terminated = 0;
                r.truncated = 0;
                r.episode_start = 1;
                r.success = 0;
                r.collided = 0;
                r.gesture_kind = gesture_kind::REFERENCING;
                r.idle = 0;
                r.stops = 0;
                r.target_category = (p % shm_schema::TARGET_CATEGORIES as u64) as u32;
                r.target_instances = 1 + (p % 3) as u32;
                r.distance = 3.0;
                r.geodesic = 3.5;
                r.summary = EpisodeSummary::default();
            }
        }
    }

    fn advance(&mut self, e: usize, action: u8) {
        if self.envs[e].record.idle == 1 {
            return;
        }
        if self.envs[e].reset_pending {
            self.start_episode(e);
            return;
        }
        let r = &mut self.envs[e].record;
        r.episode_step += 1;
        r.last_action = action as u32;
        r.episode_start = 0;
        r.reward = -0.001;
        r.distance = (r.distance - 0.25).max(0.0);
        r.geodesic = (r.geodesic - 0.25).max(0.0);
        if r.episode_step >= Self::episode_len(r.program) {
            let success = r.program % 2 == 0;
            r.success = success as u8;
            r.terminated = success as u8;
            r.truncated = (!success) as u8;
            if success {
                r.reward += 1.0;
            }
            let mut stops = [StopSummary::default(); SUMMARY_STOPS];
            stops[0] = StopSummary {
                step: r.episode_step,
                success: success as u32,
                distance: r.distance,
                path_length: 0.25 * r.episode_step as f32,
            };
            r.summary = EpisodeSummary {
                steps: r.episode_step,
                success: success as u32,
                collisions: 0,
                num_stops: 1,
                path_length: 0.25 * r.episode_step as f32,
                shortest_path: 3.5,
                final_distance: r.distance,
                total_reward: if success { 1.0 } else { 0.0 } - 0.001 * r.episode_step as f32,
                intervention_steps: 0,
                _pad: 0,
                stops,
            };
            self.envs[e].reset_pending = true;
        }
    }

    fn write(&mut self, payload: &mut [u8]) -> anyhow::Result<()> {
        let s = ObsSections::new(&self.shape, payload)?;
        let (w, h) = (self.shape.width, self.shape.height);
        let px = w * h;
        let g = shm_schema::GESTURE_FRAMES * shm_schema::GESTURE_DIMS;
        for (e, env) in self.envs.iter_mut().enumerate() {
            let r = &mut env.record;
            r.expert_action =
                if self.expert_hints { (r.episode_step as usize % action::COUNT) as u8 } else { action::NONE };
            s.records[e] = *r;
            // A diagonal band that moves one pixel per step: consecutive frames differ.
            let shift = (r.env_step as usize + e * 17) % w.max(1);
            let rgb = &mut s.rgb[e * px * 3..(e + 1) * px * 3];
            for y in 0..h {
                for x in 0..w {
                    let i = (y * w + x) * 3;
                    let band = ((x + y + shift) / 8) % 2 == 0;
                    rgb[i] = (x * 255 / w.max(1)) as u8;
                    rgb[i + 1] = (y * 255 / h.max(1)) as u8;
                    rgb[i + 2] = if band { 220 } else { 40 };
                }
            }
            let depth = &mut s.depth[e * px..(e + 1) * px];
            for (i, d) in depth.iter_mut().enumerate() {
                *d = ((i % w) * 65535 / w.max(1)) as u16;
            }
            s.gesture[e * g..(e + 1) * g].fill(0);
            r.env_step += 1;
        }
        Ok(())
    }

    pub fn worker_id(&self) -> u32 {
        self.worker_id
    }
}

impl Stepper for SyntheticStepper {
    fn num_envs(&self) -> usize {
        self.shape.num_envs
    }

    fn layout(&self) -> ObsLayout {
        self.shape.layout
    }

    fn reset(&mut self, payload: &mut [u8]) -> anyhow::Result<()> {
        for e in 0..self.envs.len() {
            self.envs[e] = SynthEnv::default();
            self.start_episode(e);
        }
        self.write(payload)
    }

    fn step(&mut self, actions: &[u8], payload: &mut [u8]) -> anyhow::Result<()> {
        anyhow::ensure!(actions.len() == self.envs.len(), "{} actions for {} envs", actions.len(), self.envs.len());
        for (e, &a) in actions.iter().enumerate() {
            anyhow::ensure!(a < 4, "env {e}: action {a} is not one of 0..4");
            self.advance(e, a);
        }
        self.write(payload)
    }

    fn finished(&self) -> bool {
        self.envs.iter().all(|e| e.record.idle == 1)
    }
}

/// An 8-byte aligned byte buffer for a payload outside shared memory (tests, tools).
pub struct PayloadBuf(Vec<u64>);

impl PayloadBuf {
    pub fn new(layout: &ObsLayout) -> PayloadBuf {
        PayloadBuf(vec![0; (layout.total_len as usize).div_ceil(8)])
    }

    pub fn bytes(&self) -> &[u8] {
        // SAFETY: an owned u64 buffer viewed as bytes.
        unsafe { std::slice::from_raw_parts(self.0.as_ptr() as *const u8, self.0.len() * 8) }
    }

    pub fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as above, uniquely borrowed.
        unsafe { std::slice::from_raw_parts_mut(self.0.as_mut_ptr() as *mut u8, self.0.len() * 8) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schema::ObsView;

    #[test]
    fn counters_are_consecutive_and_episodes_follow_the_protocol() {
        let mut s = SyntheticStepper::new(1, 3, 16, 8, None, true);
        let shape = ObsShape::new(3, 16, 8);
        let mut buf = PayloadBuf::new(&s.layout());
        s.reset(buf.bytes_mut()).unwrap();
        let mut prev: Vec<EnvRecord> = ObsView::new(shape, buf.bytes()).unwrap().records().to_vec();
        assert!(prev.iter().all(|r| r.episode_start == 1 && r.env_step == 0 && r.last_action == 255));
        let mut ends = 0;
        for t in 1..40u64 {
            s.step(&[0, 1, 3], buf.bytes_mut()).unwrap();
            let v = ObsView::new(shape, buf.bytes()).unwrap();
            for (e, r) in v.records().iter().enumerate() {
                assert_eq!(r.env_step, t);
                let p = prev[e];
                if p.terminated == 1 || p.truncated == 1 {
                    // the observation after a final one starts the next episode with reward 0
                    assert_eq!(r.episode_start, 1);
                    assert_eq!(r.reward, 0.0);
                    assert_eq!(r.episode, p.episode + 1);
                    ends += 1;
                } else {
                    assert_eq!(r.episode_step, p.episode_step + 1);
                }
                assert!(r.expert_action < 4);
            }
            assert_ne!(v.rgb(0), v.rgb(1));
            prev = v.records().to_vec();
        }
        assert!(ends > 5);
    }

    #[test]
    fn every_target_is_a_category_the_policy_knows() {
        // PPO embeds the target category: one out of range failed `up --synthetic` at program 37.
        let programs: Vec<u64> = (30..120).collect();
        let mut s = SyntheticStepper::new(0, 4, 16, 16, Some(programs), false);
        let mut buf = PayloadBuf::new(&s.layout());
        s.reset(buf.bytes_mut()).unwrap();
        let mut seen = std::collections::BTreeSet::new();
        for _ in 0..100_000 {
            if s.finished() {
                break;
            }
            s.step(&[2, 2, 2, 2], buf.bytes_mut()).unwrap();
            for r in ObsView::new(ObsShape::new(4, 16, 16), buf.bytes()).unwrap().records() {
                assert!((r.target_category as usize) < shm_schema::TARGET_CATEGORIES, "program {}", r.program);
                seen.insert(r.target_category);
            }
        }
        assert!(s.finished());
        assert_eq!(seen.len(), shm_schema::TARGET_CATEGORIES, "every category comes up");
    }

    #[test]
    fn a_program_sequence_runs_out() {
        let mut s = SyntheticStepper::new(0, 2, 16, 16, Some(vec![10, 11, 12]), false);
        let mut buf = PayloadBuf::new(&s.layout());
        s.reset(buf.bytes_mut()).unwrap();
        let mut seen = vec![];
        for _ in 0..100 {
            if s.finished() {
                break;
            }
            s.step(&[0, 0], buf.bytes_mut()).unwrap();
            let v = ObsView::new(ObsShape::new(2, 16, 16), buf.bytes()).unwrap();
            for r in v.records() {
                if r.terminated == 1 || r.truncated == 1 {
                    seen.push(r.program);
                }
            }
        }
        assert!(s.finished());
        seen.sort();
        assert_eq!(seen, vec![10, 11, 12]);
    }
}
