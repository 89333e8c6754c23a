//! Shared-memory message types and service names of the GesTHOR-RS rollout farm.
//!
//! Types only: `#[repr(C)]`, `ZeroCopySend`, written in place by one process and read in
//! place by another. The layout is documented in `shm_schema/README.md` for readers in other
//! languages (iceoryx2's Python binding reads these types through ctypes structures whose
//! `type_name()` equals the `#[type_name]` below).
//!
//! # The observation message (service `obs/<worker>`)
//! An iceoryx2 sample with user header [`ObsHeader`] and a `[u8]` payload holding, at the
//! offsets given by [`ObsLayout`]: `num_envs` × [`EnvRecord`], then per env the RGB frame
//! (`height × width × 3` u8, row-major, top row first), then per env the depth frame
//! (`height × width` u16, linear 0..10 m → 0..65535), then per env the gesture the robot
//! perceives (`100 × 95` IEEE f16 bit patterns, frame-major; zeros when none).
//!
//! # Episode boundaries
//! An observation carries the reward of the transition that led to it. When an episode ends,
//! the worker first sends the final observation (`terminated` or `truncated` set); the action
//! the learner answers to it is ignored, and the next observation starts the new episode
//! (`episode_start` set, reward 0). The learner thus sees the final state of a truncated
//! episode and can bootstrap from its value (terminated: no bootstrap).

use iceoryx2::prelude::ZeroCopySend;

/// Most environments one worker may step (size of the action array).
pub const MAX_ENVS: usize = 64;
/// Frames and muscle values of a gesture (§3.3.1).
pub const GESTURE_FRAMES: usize = 100;
pub const GESTURE_DIMS: usize = 95;
/// How many stops an episode summary keeps (metrics at 1, 2, 3 stops).
pub const SUMMARY_STOPS: usize = 3;

pub const OBS_MAGIC: u32 = 0x4753_4F42; // "GSOB"
pub const ACT_MAGIC: u32 = 0x4753_4143; // "GSAC"
pub const SCHEMA_VERSION: u32 = 1;

/// Byte offsets of the payload sections (from the start of the `[u8]` payload), each aligned
/// to 64 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("gesthor::ObsLayout")]
pub struct ObsLayout {
    pub records_offset: u64,
    pub rgb_offset: u64,
    /// Bytes from one env's RGB frame to the next.
    pub rgb_stride: u64,
    pub depth_offset: u64,
    pub depth_stride: u64,
    pub gesture_offset: u64,
    pub gesture_stride: u64,
    /// Payload length in bytes.
    pub total_len: u64,
}

/// User header of every observation sample.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("gesthor::ObsHeader")]
pub struct ObsHeader {
    /// [`OBS_MAGIC`].
    pub magic: u32,
    /// [`SCHEMA_VERSION`].
    pub version: u32,
    pub worker_id: u32,
    /// How many times this worker slot was (re)started: 0 for the first process.
    pub generation: u32,
    /// Messages sent by this worker process so far (0 for the first).
    pub step: u64,
    pub num_envs: u32,
    pub width: u32,
    pub height: u32,
    pub gesture_frames: u32,
    pub gesture_dims: u32,
    /// 1 once every env of this worker has run out of assigned programs (evaluation).
    pub finished: u32,
    pub layout: ObsLayout,
}

/// One stop of an episode (for SR/SPL/DTS at k stops).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("gesthor::StopSummary")]
pub struct StopSummary {
    /// 1-based step of the stop; 0 = no such stop.
    pub step: u32,
    pub success: u32,
    /// 2D distance to the target centre at the stop.
    pub distance: f32,
    /// Path length travelled up to the stop.
    pub path_length: f32,
}

/// Summary of an episode, filled in on its final observation.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("gesthor::EpisodeSummary")]
pub struct EpisodeSummary {
    pub steps: u32,
    pub success: u32,
    pub collisions: u32,
    pub num_stops: u32,
    pub path_length: f32,
    /// Geodesic distance from the start to the success region (l_i of SPL).
    pub start_geodesic: f32,
    /// 2D distance to the target centre at the end.
    pub final_distance: f32,
    pub total_reward: f32,
    /// Steps at which an intervention gesture was shown.
    pub intervention_steps: u32,
    pub _pad: u32,
    pub stops: [StopSummary; SUMMARY_STOPS],
}

/// Per-environment part of an observation.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("gesthor::EnvRecord")]
pub struct EnvRecord {
    /// Observations this env has produced in this worker process (counts every message).
    pub env_step: u64,
    /// Episodes this env has started in this worker process.
    pub episode: u64,
    /// Index of the program (within the split) the episode runs.
    pub program: u64,
    /// Steps taken in the current episode (0 on its first observation).
    pub episode_step: u32,
    /// The action that led here (255 on an episode's first observation).
    pub last_action: u32,
    /// Reward of the transition that led here.
    pub reward: f32,
    /// This is the final observation of an episode that succeeded or ran out of stops.
    pub terminated: u8,
    /// This is the final observation of an episode cut at the step limit.
    pub truncated: u8,
    /// This observation starts an episode (reset recurrent state).
    pub episode_start: u8,
    pub success: u8,
    /// The last action was a blocked move.
    pub collided: u8,
    /// 0 none, 1 referencing, 2 intervention.
    pub gesture_kind: u8,
    /// Which of the 20 intervention gestures, when `gesture_kind` is 2.
    pub gesture_index: u8,
    /// 1 when this env has no more programs to run (evaluation); the record is then stale.
    pub idle: u8,
    /// The shortest-path expert's action from here (255 when the run does not ask for it).
    pub expert_action: u8,
    pub _pad: [u8; 3],
    pub stops: u32,
    /// Target category index (order of `worker::scene::Category::targets()`).
    pub target_category: u32,
    /// Instances of the target category in the room.
    pub target_instances: u32,
    /// Pixels of the target instance in this frame.
    pub visible_pixels: u32,
    /// Robot x, z (metres) and yaw (degrees).
    pub robot: [f32; 3],
    /// The person relative to the robot: right (m), forward (m), yaw difference / 360.
    pub person_rel: [f32; 3],
    /// 2D distance from the robot to the target centre.
    pub distance: f32,
    /// Geodesic distance from the robot to the success region.
    pub geodesic: f32,
    /// Valid when `terminated` or `truncated` is set.
    pub summary: EpisodeSummary,
}

/// Commands a learner sends with the actions.
pub mod command {
    /// Apply the actions and send the next observation.
    pub const STEP: u32 = 0;
    /// Finish: the worker exits cleanly.
    pub const SHUTDOWN: u32 = 1;
}

/// Actions for one worker (service `act/<worker>`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("gesthor::ActionMsg")]
pub struct ActionMsg {
    /// [`ACT_MAGIC`].
    pub magic: u32,
    pub worker_id: u32,
    /// Must equal the generation of the observation answered; stale answers are ignored.
    pub generation: u32,
    /// [`command`].
    pub command: u32,
    /// The `step` of the observation this answers.
    pub step: u64,
    pub num_envs: u32,
    pub _pad: u32,
    /// Action index per env (0 MoveAhead, 1 RotateLeft, 2 RotateRight, 3 Stop).
    pub actions: [u8; MAX_ENVS],
}

impl Default for ActionMsg {
    fn default() -> Self {
        ActionMsg { magic: ACT_MAGIC, worker_id: 0, generation: 0, command: command::STEP, step: 0, num_envs: 0, _pad: 0, actions: [0; MAX_ENVS] }
    }
}

fn align64(x: u64) -> u64 {
    x.div_ceil(64) * 64
}

impl ObsLayout {
    /// The payload layout for `num_envs` frames of `width × height`.
    pub fn new(num_envs: u32, width: u32, height: u32) -> ObsLayout {
        let n = num_envs as u64;
        let px = width as u64 * height as u64;
        let records_offset = 0;
        let rgb_offset = align64(records_offset + n * std::mem::size_of::<EnvRecord>() as u64);
        let rgb_stride = px * 3;
        let depth_offset = align64(rgb_offset + n * rgb_stride);
        let depth_stride = px * 2;
        let gesture_offset = align64(depth_offset + n * depth_stride);
        let gesture_stride = (GESTURE_FRAMES * GESTURE_DIMS * 2) as u64;
        let total_len = align64(gesture_offset + n * gesture_stride);
        ObsLayout { records_offset, rgb_offset, rgb_stride, depth_offset, depth_stride, gesture_offset, gesture_stride, total_len }
    }
}

/// Service names; they carry the run id so that two runs on one host never meet.
pub mod service {
    pub fn obs(run_id: &str, worker: u32) -> String {
        format!("gesthor/{run_id}/obs/{worker}")
    }
    pub fn act(run_id: &str, worker: u32) -> String {
        format!("gesthor/{run_id}/act/{worker}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_sections_do_not_overlap_and_are_aligned() {
        let l = ObsLayout::new(8, 224, 224);
        assert_eq!(l.records_offset, 0);
        assert!(l.rgb_offset >= 8 * std::mem::size_of::<EnvRecord>() as u64);
        assert_eq!(l.depth_offset % 64, 0);
        assert!(l.depth_offset >= l.rgb_offset + 8 * 224 * 224 * 3);
        assert!(l.gesture_offset >= l.depth_offset + 8 * 224 * 224 * 2);
        assert!(l.total_len >= l.gesture_offset + 8 * 19_000);
    }

    #[test]
    fn record_sizes_are_stable() {
        // Readers in other languages hard-code these; change SCHEMA_VERSION when they change.
        assert_eq!(std::mem::size_of::<StopSummary>(), 16);
        assert_eq!(std::mem::size_of::<EpisodeSummary>(), 40 + 48);
        assert_eq!(std::mem::size_of::<EnvRecord>(), 184);
        assert_eq!(std::mem::size_of::<ObsHeader>(), 48 + 64);
        assert_eq!(std::mem::size_of::<ActionMsg>(), 32 + MAX_ENVS);
    }

    #[test]
    fn names_carry_the_run_id() {
        assert_ne!(service::obs("a", 0), service::obs("b", 0));
        assert_ne!(service::obs("a", 0), service::act("a", 0));
    }
}
