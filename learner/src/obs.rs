//! What the learner reads from the environments at one step: the [`EnvBatch`], the agent's and
//! the trainer's input (the farm's round of worker messages, `crate::serve::batch::WorkerBatch`,
//! becomes one of these in `crate::serve::ppo_policy`).
//!
//! One message per step for N environments. Frames and gestures are read *in place* from the
//! buffers the caller hands over (shared memory, in the farm): a [`FrameView`] per group of
//! environments (one worker's sample), turned into tensors with `from_blob` and copied once,
//! straight into the rollout storage or onto the GPU (see `crate::inputs`). The small
//! per-environment fields come as a slice of [`EnvStep`] in environment order.
//!
//! ## The step protocol (Gymnasium's terminated vs truncated, next-step autoreset)
//! The message at step t carries, for each env, the *feedback* of the action sent at t−1
//! (`reward`, `terminated`, `truncated`) and the observation o_t on which the next action is taken.
//! When an episode ends, the worker sends its *final* observation (`episode_start` false, a flag
//! set) and ignores the action it gets for it; the next message starts the new episode
//! (`episode_start`, reward 0). Step t of a final observation is never learned from.
//! - `terminated`: the episode ended by itself (success, stop limit): no bootstrap.
//! - `truncated` (the 100-step limit): the learner bootstraps from V(o_t) (adds γ·V(o_t) to the
//!   reward of t−1). If both flags are set, `terminated` wins.
//! - An env may also reset at once on termination (o_t is then the new episode's first
//!   observation, `episode_start` and `terminated` both set); that is handled the same way.
//! - `lost`: the env's message was lost (its worker crashed or restarted). The feedback of t−1 is
//!   unknown: t−1 and t are kept out of the loss, and the env's memory is reset at the next step.

use half::f16;
use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES, TARGET_CATEGORIES, gesture_kind};

/// Which gesture the robot sees now ([`shm_schema::gesture_kind`]); `None` zeroes the gesture input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u8)]
pub enum GestureKind {
    #[default]
    None = gesture_kind::NONE,
    Referencing = gesture_kind::REFERENCING,
    Intervention = gesture_kind::INTERVENTION,
}

impl GestureKind {
    /// The kind an [`shm_schema::EnvRecord::gesture_kind`] names, if it names one.
    pub fn from_u8(v: u8) -> Option<GestureKind> {
        match v {
            gesture_kind::NONE => Some(GestureKind::None),
            gesture_kind::REFERENCING => Some(GestureKind::Referencing),
            gesture_kind::INTERVENTION => Some(GestureKind::Intervention),
            _ => None,
        }
    }
}

/// The small per-environment fields of one step message.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvStep {
    /// Reward of the previous action (§4.3.2).
    pub reward: f32,
    /// The previous action ended the episode by itself (no bootstrap).
    pub terminated: bool,
    /// The previous action hit the step limit; the observation is the episode's final one.
    pub truncated: bool,
    /// The observation is the first of a new episode (the recurrent state is reset).
    pub episode_start: bool,
    /// The message of this env was lost (worker crash/restart); its fields are not read.
    pub lost: bool,
    /// Gesture shown with this observation.
    pub gesture: GestureKind,
    /// Target category, index into `worker::scene::Category::targets()`.
    pub target: i64,
    /// The person relative to the robot: dx, dz (metres, robot frame), yaw/360.
    pub person_pose: [f32; 3],
    /// Outcome of an episode that ended with the previous action (read when it ended).
    pub success: bool,
    pub spl: f32,
}

impl EnvStep {
    /// The observation is the final one of an episode: the env ignores the action taken on it
    /// (then resets), so the step is not learned from.
    pub fn is_final_observation(&self) -> bool {
        (self.truncated || self.terminated) && !self.episode_start && !self.lost
    }

    /// The final observation of an episode cut by the step limit: its value bootstraps the
    /// return of the step that led to it.
    pub fn bootstraps(&self) -> bool {
        self.truncated && !self.terminated && !self.episode_start && !self.lost
    }
}

/// Gesture clips of a group of envs, `[E, 100, 95]`, as half or single floats.
#[derive(Clone, Copy, Debug)]
pub enum GestureView<'a> {
    F16(&'a [f16]),
    F32(&'a [f32]),
}

impl GestureView<'_> {
    fn len(&self) -> usize {
        match self {
            GestureView::F16(s) => s.len(),
            GestureView::F32(s) => s.len(),
        }
    }
}

/// Frames of a group of consecutive envs, read in place.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    /// Number of envs in this group.
    pub envs: usize,
    /// RGB, `[E, H, W, 3]` u8.
    pub rgb: &'a [u8],
    /// Linear depth, `[E, H, W]` u16 (0..10 m → 0..65535).
    pub depth: &'a [u16],
    pub gesture: GestureView<'a>,
    /// `env.frames = "device"`: the group's frames are in the memory its worker exported (slots
    /// `0..envs`), read from there instead of `rgb` / `depth` for the modalities it names.
    pub device: Option<DeviceFrames<'a>>,
}

/// Frames a worker keeps in GPU memory the learner imported, and which of them to read there
/// (an evaluation that blanks a modality reads that one's zeros from the host slices).
#[derive(Clone, Copy, Debug)]
pub struct DeviceFrames<'a> {
    pub frames: &'a crate::device_frames::ImportedFrames,
    pub rgb: bool,
    pub depth: bool,
}

/// One step of all N envs, in env order: what the agent acts on and the trainer learns from.
#[derive(Clone, Debug)]
pub struct EnvBatch<'a> {
    pub height: usize,
    pub width: usize,
    /// Frame groups in env order; their `envs` sum to N.
    pub frames: Vec<FrameView<'a>>,
    /// Per env, length N.
    pub envs: &'a [EnvStep],
}

#[derive(Debug, thiserror::Error)]
pub enum ObsError {
    #[error("observation batch: {0}")]
    Shape(String),
    #[error("observation batch: env {env}: target category {target} is not in 0..{count}")]
    Target { env: usize, target: i64, count: i64 },
}

impl EnvBatch<'_> {
    pub fn n(&self) -> usize {
        self.envs.len()
    }

    /// Checks every buffer against N, H and W, so that tensor views are never out of bounds.
    pub fn validate(&self, expect_envs: usize, expect_hw: (usize, usize)) -> Result<(), ObsError> {
        let n = self.n();
        if n != expect_envs {
            return Err(ObsError::Shape(format!("{n} envs, the policy was made for {expect_envs}")));
        }
        if (self.height, self.width) != expect_hw {
            return Err(ObsError::Shape(format!(
                "frames are {}x{}, the config says {}x{}",
                self.width, self.height, expect_hw.1, expect_hw.0
            )));
        }
        let total: usize = self.frames.iter().map(|f| f.envs).sum();
        if total != n {
            return Err(ObsError::Shape(format!("frame groups hold {total} envs, the batch has {n}")));
        }
        let px = self.height * self.width;
        for (i, f) in self.frames.iter().enumerate() {
            let checks = [
                ("rgb", f.rgb.len(), f.envs * px * 3),
                ("depth", f.depth.len(), f.envs * px),
                ("gesture", f.gesture.len(), f.envs * GESTURE_FRAMES * GESTURE_DIMS),
            ];
            for (what, got, want) in checks {
                if got != want {
                    return Err(ObsError::Shape(format!(
                        "frame group {i}: {what} has {got} values, {} envs need {want}",
                        f.envs
                    )));
                }
            }
        }
        let count = TARGET_CATEGORIES as i64;
        for (env, e) in self.envs.iter().enumerate() {
            if !e.lost && !(0..count).contains(&e.target) {
                return Err(ObsError::Target { env, target: e.target, count });
            }
        }
        Ok(())
    }
}

/// The buffers an [`EnvBatch`] borrows, owned: for tests, the synthetic smoke task and benches.
#[derive(Clone, Debug)]
pub struct OwnedObs {
    pub height: usize,
    pub width: usize,
    pub rgb: Vec<u8>,
    pub depth: Vec<u16>,
    pub gesture: Vec<f16>,
    pub envs: Vec<EnvStep>,
}

impl OwnedObs {
    /// All-zero frames and gestures for `n` envs, every env starting an episode.
    pub fn new(n: usize, height: usize, width: usize) -> OwnedObs {
        OwnedObs {
            height,
            width,
            rgb: vec![0; n * height * width * 3],
            depth: vec![0; n * height * width],
            gesture: vec![f16::ZERO; n * GESTURE_FRAMES * GESTURE_DIMS],
            envs: vec![EnvStep { episode_start: true, ..Default::default() }; n],
        }
    }

    pub fn n(&self) -> usize {
        self.envs.len()
    }

    /// The batch, as one frame group.
    pub fn batch(&self) -> EnvBatch<'_> {
        EnvBatch {
            height: self.height,
            width: self.width,
            frames: vec![FrameView {
                envs: self.n(),
                rgb: &self.rgb,
                depth: &self.depth,
                gesture: GestureView::F16(&self.gesture),
                device: None,
            }],
            envs: &self.envs,
        }
    }

    /// Envs `envs` alone, as one frame group (one group of an acting round).
    pub fn batch_of(&self, envs: std::ops::Range<usize>) -> EnvBatch<'_> {
        let (px, g) = (self.height * self.width, GESTURE_FRAMES * GESTURE_DIMS);
        EnvBatch {
            height: self.height,
            width: self.width,
            frames: vec![FrameView {
                envs: envs.len(),
                rgb: &self.rgb[envs.start * px * 3..envs.end * px * 3],
                depth: &self.depth[envs.start * px..envs.end * px],
                gesture: GestureView::F16(&self.gesture[envs.start * g..envs.end * g]),
                device: None,
            }],
            envs: &self.envs[envs],
        }
    }

    /// The batch split into groups of `per_group` envs, as workers would send it.
    pub fn batch_grouped(&self, per_group: usize) -> EnvBatch<'_> {
        let px = self.height * self.width;
        let g = GESTURE_FRAMES * GESTURE_DIMS;
        let mut frames = Vec::new();
        let mut start = 0;
        while start < self.n() {
            let e = per_group.min(self.n() - start);
            frames.push(FrameView {
                envs: e,
                rgb: &self.rgb[start * px * 3..(start + e) * px * 3],
                depth: &self.depth[start * px..(start + e) * px],
                gesture: GestureView::F16(&self.gesture[start * g..(start + e) * g]),
                device: None,
            });
            start += e;
        }
        EnvBatch { height: self.height, width: self.width, frames, envs: &self.envs }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_sizes_and_targets_are_named() {
        let mut o = OwnedObs::new(2, 4, 4);
        o.rgb.pop();
        let err = o.batch().validate(2, (4, 4)).unwrap_err().to_string();
        assert!(err.contains("rgb"), "{err}");
        let mut o = OwnedObs::new(2, 4, 4);
        o.envs[1].target = 99;
        let err = o.batch().validate(2, (4, 4)).unwrap_err().to_string();
        assert!(err.contains("env 1") && err.contains("99"), "{err}");
        let err = OwnedObs::new(3, 4, 4).batch().validate(2, (4, 4)).unwrap_err().to_string();
        assert!(err.contains("3 envs"), "{err}");
    }
}
