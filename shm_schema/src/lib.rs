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
/// Target categories the policy can be asked for (T3.3 lists 37 distinct ones); the value of
/// [`EnvRecord::target_category`] is below this.
pub const TARGET_CATEGORIES: usize = 37;

/// The robot's actions (§4.2), as the action message carries them.
pub mod action {
    pub const MOVE_AHEAD: u8 = 0;
    pub const ROTATE_LEFT: u8 = 1;
    pub const ROTATE_RIGHT: u8 = 2;
    pub const STOP: u8 = 3;
    /// How many there are: the policy's logits.
    pub const COUNT: usize = 4;
    /// [`super::EnvRecord::last_action`] and `expert_action` when there is none.
    pub const NONE: u8 = 255;
}

/// What [`EnvRecord::gesture_kind`] says the robot perceives.
pub mod gesture_kind {
    pub const NONE: u8 = 0;
    pub const REFERENCING: u8 = 1;
    pub const INTERVENTION: u8 = 2;
}

pub const OBS_MAGIC: u32 = 0x4753_4F42; // "GSOB"
pub const ACT_MAGIC: u32 = 0x4753_4143; // "GSAC"
pub const SCHEMA_VERSION: u32 = 2;

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
    /// Where this worker process's time went so far (for the training profile).
    pub timing: WorkerTiming,
}

/// Cumulative nanoseconds a worker process spent, since it started, on each part of its loop.
/// Observation `step` carries the sums up to the start of its own step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("gesthor::WorkerTiming")]
pub struct WorkerTiming {
    /// Stepping the envs (physics, task, gestures) and writing observations, rendering excluded.
    pub sim_ns: u64,
    /// Rendering the envs' views.
    pub render_ns: u64,
    /// Loaning, sending and notifying (the observation's way out).
    pub send_ns: u64,
    /// Waiting for the learner's actions.
    pub wait_ns: u64,
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
    /// l_i of SPL: a lower bound of any successful path's length from the start
    /// (`worker::shortest_path`).
    pub shortest_path: f32,
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
    /// [`gesture_kind`]: none, referencing or intervention.
    pub gesture_kind: u8,
    /// Which of the 20 intervention gestures, when `gesture_kind` is 2.
    pub gesture_index: u8,
    /// 1 when this env has no more programs to run (evaluation); the record is then stale.
    pub idle: u8,
    /// The shortest-path expert's action from here (255 when the run does not ask for it).
    pub expert_action: u8,
    pub _pad: [u8; 3],
    pub stops: u32,
    /// Target category index (order of `worker::scene::Category::targets()`), below [`TARGET_CATEGORIES`].
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
        ActionMsg {
            magic: ACT_MAGIC,
            worker_id: 0,
            generation: 0,
            command: command::STEP,
            step: 0,
            num_envs: 0,
            _pad: 0,
            actions: [0; MAX_ENVS],
        }
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
        ObsLayout {
            records_offset,
            rgb_offset,
            rgb_stride,
            depth_offset,
            depth_stride,
            gesture_offset,
            gesture_stride,
            total_len,
        }
    }
}

/// How a worker's frames lie in the GPU memory it exports to the learner (`env.frames =
/// "device"`): no bytes travel through shared memory, the learner imports the memory itself (a
/// Vulkan opaque file descriptor, passed over a Unix socket) and reads each env's slot in place.
/// Slot `s`'s colour layer starts at `s × layer_bytes` (RGBA8, rows of `row_bytes`), its
/// depth+id layer at `info_offset + s × layer_bytes` (u32 little-endian per pixel:
/// `depth16 << 16 | id`, depth 0..10 m → 0..65535); rows top first.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("gesthor::DeviceFrameLayout")]
pub struct DeviceFrameLayout {
    pub slots: u32,
    pub width: u32,
    pub height: u32,
    /// Bytes per row: `width × 4` rounded up to [`DeviceFrameLayout::ROW_ALIGNMENT`].
    pub row_bytes: u32,
    pub layer_bytes: u64,
    pub info_offset: u64,
    /// Bytes of the exported allocation: at least `2 × info_offset`, exactly what the exporter
    /// allocated (an importer must give this size).
    pub size: u64,
}

impl DeviceFrameLayout {
    /// A texture-to-buffer copy's rows start at multiples of this (Vulkan via wgpu).
    pub const ROW_ALIGNMENT: u32 = 256;

    /// The layout of `slots` frames of `width × height`.
    pub fn new(slots: u32, width: u32, height: u32) -> DeviceFrameLayout {
        let row_bytes = (width * 4).next_multiple_of(Self::ROW_ALIGNMENT);
        let layer_bytes = row_bytes as u64 * height as u64;
        let info_offset = layer_bytes * slots as u64;
        DeviceFrameLayout { slots, width, height, row_bytes, layer_bytes, info_offset, size: 2 * info_offset }
    }
}

/// Service names; they carry the run id so that two runs on one host never meet.
pub mod service {
    /// Publish-subscribe, `[u8]` payload with user header [`super::ObsHeader`]: worker → learner.
    pub fn obs(run_id: &str, worker: u32) -> String {
        format!("gesthor/{run_id}/obs/{worker}")
    }
    /// Publish-subscribe, [`super::ActionMsg`]: learner → worker.
    pub fn act(run_id: &str, worker: u32) -> String {
        format!("gesthor/{run_id}/act/{worker}")
    }
    /// Event: every worker notifies it after sending an observation, so that the learner can
    /// sleep until one arrives instead of polling N subscribers.
    pub fn obs_ready(run_id: &str) -> String {
        format!("gesthor/{run_id}/obs_ready")
    }
    /// Event: the learner notifies worker `worker` after publishing its actions.
    pub fn act_ready(run_id: &str, worker: u32) -> String {
        format!("gesthor/{run_id}/act_ready/{worker}")
    }
    /// The iceoryx2 resource prefix of a run (iceoryx2's `global.prefix`): every file the run
    /// creates in `/dev/shm` and `/tmp/iceoryx2` starts with it, so the run's leftovers can be
    /// found, and cleaned, without touching anything else on the host. Characters that cannot
    /// appear in a file name are replaced by `_`.
    pub fn prefix(run_id: &str) -> String {
        let id: String =
            run_id.chars().take(48).map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        format!("gesthor_{id}_")
    }
}

/// Quality-of-service settings of the farm's services. Every process that creates or opens a
/// service uses these values (iceoryx2 refuses to open a service whose overflow setting differs,
/// and requires at least the buffer/history sizes asked for), including readers in other
/// languages (`shm_schema/README.md`).
pub mod qos {
    /// A full subscriber buffer drops its oldest sample instead of blocking the sender.
    pub const SAFE_OVERFLOW: bool = true;
    /// Payload alignment of the observation service, so that records, depth and gesture
    /// sections (64-byte aligned offsets) can be read in place as typed slices.
    pub const OBS_PAYLOAD_ALIGNMENT: usize = 64;
    /// The last observation is kept as history and handed to a subscriber that connects late
    /// (part of the start handshake; a reader attaching to a live run gets a frame at once).
    pub const OBS_HISTORY: usize = 1;
    pub const OBS_SUBSCRIBER_BUFFER: usize = 2;
    pub const OBS_SUBSCRIBER_MAX_BORROWED: usize = 2;
    /// The learner and up to two readers (e.g. `tests/python/read_frame.py`).
    pub const OBS_MAX_SUBSCRIBERS: usize = 3;
    /// The worker, and the ports of a killed one until its stale resources are removed.
    pub const OBS_MAX_PUBLISHERS: usize = 2;
    pub const OBS_MAX_NODES: usize = 8;
    /// Samples a worker may hold loaned at once (it writes one observation at a time).
    pub const OBS_MAX_LOANED: usize = 1;
    pub const ACT_HISTORY: usize = 0;
    pub const ACT_SUBSCRIBER_BUFFER: usize = 2;
    pub const ACT_SUBSCRIBER_MAX_BORROWED: usize = 2;
    pub const ACT_MAX_SUBSCRIBERS: usize = 4;
    pub const ACT_MAX_PUBLISHERS: usize = 2;
    pub const ACT_MAX_NODES: usize = 8;
    /// `act_ready/<k>`: the learner notifies, worker `k` listens (plus stale ports of killed ones).
    pub const ACT_READY_MAX_NOTIFIERS: usize = 2;
    pub const ACT_READY_MAX_LISTENERS: usize = 4;
    pub const ACT_READY_MAX_NODES: usize = 8;
    /// `obs_ready`: every worker notifies, the learner listens. Sized for `workers` live workers
    /// plus as many killed ones whose ports are not yet cleaned up, plus a few spare.
    pub fn obs_ready_max_notifiers(workers: usize) -> usize {
        2 * workers + 4
    }
    pub fn obs_ready_max_nodes(workers: usize) -> usize {
        2 * workers + 8
    }
    pub const OBS_READY_MAX_LISTENERS: usize = 4;
}

/// Why a payload cannot be viewed with a layout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ViewError {
    /// The payload is shorter than the layout's `total_len`.
    TooShort {
        len: usize,
        need: usize,
    },
    /// The payload does not start on an 8-byte boundary (records need it).
    Misaligned,
    /// The layout does not match `ObsLayout::new(num_envs, width, height)`.
    Layout,
    TooManyEnvs(usize),
}

impl std::fmt::Display for ViewError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ViewError::TooShort { len, need } => write!(f, "payload is {len} bytes, the layout needs {need}"),
            ViewError::Misaligned => write!(f, "payload is not 8-byte aligned"),
            ViewError::Layout => write!(f, "layout does not match the env count and frame size"),
            ViewError::TooManyEnvs(n) => write!(f, "{n} envs (at most {MAX_ENVS})"),
        }
    }
}

impl std::error::Error for ViewError {}

/// The shape of one observation payload: how many envs, frame size, and the section offsets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObsShape {
    pub num_envs: usize,
    pub width: usize,
    pub height: usize,
    pub layout: ObsLayout,
}

impl ObsShape {
    pub fn new(num_envs: usize, width: u32, height: u32) -> ObsShape {
        ObsShape {
            num_envs,
            width: width as usize,
            height: height as usize,
            layout: ObsLayout::new(num_envs as u32, width, height),
        }
    }

    /// The shape a received header announces, checked against the layout it carries.
    pub fn of_header(h: &ObsHeader) -> Result<ObsShape, ViewError> {
        if h.num_envs as usize > MAX_ENVS {
            return Err(ViewError::TooManyEnvs(h.num_envs as usize));
        }
        let s = ObsShape::new(h.num_envs as usize, h.width, h.height);
        if s.layout != h.layout
            || h.gesture_frames as usize != GESTURE_FRAMES
            || h.gesture_dims as usize != GESTURE_DIMS
        {
            return Err(ViewError::Layout);
        }
        Ok(s)
    }

    fn pixels(&self) -> usize {
        self.width * self.height
    }

    fn check(&self, ptr: *const u8, len: usize) -> Result<(), ViewError> {
        if self.num_envs > MAX_ENVS {
            return Err(ViewError::TooManyEnvs(self.num_envs));
        }
        let need = self.layout.total_len as usize;
        if len < need {
            return Err(ViewError::TooShort { len, need });
        }
        if (ptr as usize) % std::mem::align_of::<EnvRecord>() != 0 {
            return Err(ViewError::Misaligned);
        }
        Ok(())
    }
}

/// An observation payload read in place: typed slices over the bytes, no copy.
#[derive(Debug, Clone, Copy)]
pub struct ObsView<'a> {
    shape: ObsShape,
    payload: &'a [u8],
}

impl<'a> ObsView<'a> {
    pub fn new(shape: ObsShape, payload: &'a [u8]) -> Result<ObsView<'a>, ViewError> {
        shape.check(payload.as_ptr(), payload.len())?;
        Ok(ObsView { shape, payload })
    }

    pub fn shape(&self) -> &ObsShape {
        &self.shape
    }

    pub fn bytes(&self) -> &'a [u8] {
        self.payload
    }

    pub fn records(&self) -> &'a [EnvRecord] {
        let l = &self.shape.layout;
        // SAFETY: `check` made sure the payload is long enough and 8-byte aligned, and every
        // section offset is a multiple of 64; EnvRecord is repr(C) plain data valid for any bytes
        // the schema defines (flags are u8, not bool).
        unsafe {
            std::slice::from_raw_parts(
                self.payload.as_ptr().add(l.records_offset as usize) as *const EnvRecord,
                self.shape.num_envs,
            )
        }
    }

    /// RGB of every env, `[E, H, W, 3]` u8, contiguous.
    pub fn rgb_all(&self) -> &'a [u8] {
        let l = &self.shape.layout;
        let start = l.rgb_offset as usize;
        &self.payload[start..start + self.shape.num_envs * self.shape.pixels() * 3]
    }

    pub fn rgb(&self, env: usize) -> &'a [u8] {
        let n = self.shape.pixels() * 3;
        &self.rgb_all()[env * n..(env + 1) * n]
    }

    /// Depth of every env, `[E, H, W]` u16 (0..10 m → 0..65535), contiguous.
    pub fn depth_all(&self) -> &'a [u16] {
        let l = &self.shape.layout;
        // SAFETY: in bounds (checked length), 2-byte aligned (aligned base + 64-byte offset).
        unsafe {
            std::slice::from_raw_parts(
                self.payload.as_ptr().add(l.depth_offset as usize) as *const u16,
                self.shape.num_envs * self.shape.pixels(),
            )
        }
    }

    pub fn depth(&self, env: usize) -> &'a [u16] {
        let n = self.shape.pixels();
        &self.depth_all()[env * n..(env + 1) * n]
    }

    /// Gestures of every env, `[E, 100, 95]` IEEE f16 bit patterns, contiguous.
    pub fn gesture_bits_all(&self) -> &'a [u16] {
        let l = &self.shape.layout;
        // SAFETY: as for depth.
        unsafe {
            std::slice::from_raw_parts(
                self.payload.as_ptr().add(l.gesture_offset as usize) as *const u16,
                self.shape.num_envs * GESTURE_FRAMES * GESTURE_DIMS,
            )
        }
    }

    pub fn gesture_bits(&self, env: usize) -> &'a [u16] {
        let n = GESTURE_FRAMES * GESTURE_DIMS;
        &self.gesture_bits_all()[env * n..(env + 1) * n]
    }
}

/// The sections of an observation payload, borrowed mutably and apart, so that a writer can
/// fill frames and records at the same time (what a worker does with a loaned sample).
#[derive(Debug)]
pub struct ObsSections<'a> {
    pub records: &'a mut [EnvRecord],
    /// `[E, H, W, 3]`.
    pub rgb: &'a mut [u8],
    /// `[E, H, W]`.
    pub depth: &'a mut [u16],
    /// `[E, 100, 95]` f16 bits.
    pub gesture: &'a mut [u16],
}

impl<'a> ObsSections<'a> {
    /// Splits `payload` into its sections. The bytes between sections (alignment padding) are
    /// left as they are.
    pub fn new(shape: &ObsShape, payload: &'a mut [u8]) -> Result<ObsSections<'a>, ViewError> {
        shape.check(payload.as_ptr(), payload.len())?;
        let l = &shape.layout;
        let (e, px) = (shape.num_envs, shape.pixels());
        let base = payload.as_mut_ptr();
        // SAFETY: the four ranges are disjoint (ObsLayout::new places them one after another),
        // within the checked length, and aligned for their element types.
        unsafe {
            Ok(ObsSections {
                records: std::slice::from_raw_parts_mut(base.add(l.records_offset as usize) as *mut EnvRecord, e),
                rgb: std::slice::from_raw_parts_mut(base.add(l.rgb_offset as usize), e * px * 3),
                depth: std::slice::from_raw_parts_mut(base.add(l.depth_offset as usize) as *mut u16, e * px),
                gesture: std::slice::from_raw_parts_mut(
                    base.add(l.gesture_offset as usize) as *mut u16,
                    e * GESTURE_FRAMES * GESTURE_DIMS,
                ),
            })
        }
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
        assert_eq!(std::mem::size_of::<ObsHeader>(), 48 + 64 + 32);
        assert_eq!(std::mem::size_of::<WorkerTiming>(), 32);
        assert_eq!(std::mem::size_of::<ActionMsg>(), 32 + MAX_ENVS);
    }

    #[test]
    fn offsets_match_the_readme() {
        use std::mem::offset_of;
        assert_eq!(offset_of!(ObsHeader, step), 16);
        assert_eq!(offset_of!(ObsHeader, finished), 44);
        assert_eq!(offset_of!(ObsHeader, layout), 48);
        assert_eq!(offset_of!(ObsHeader, timing), 112);
        assert_eq!(offset_of!(ObsLayout, total_len), 56);
        assert_eq!(offset_of!(EnvRecord, reward), 32);
        assert_eq!(offset_of!(EnvRecord, terminated), 36);
        assert_eq!(offset_of!(EnvRecord, expert_action), 44);
        assert_eq!(offset_of!(EnvRecord, stops), 48);
        assert_eq!(offset_of!(EnvRecord, robot), 64);
        assert_eq!(offset_of!(EnvRecord, geodesic), 92);
        assert_eq!(offset_of!(EnvRecord, summary), 96);
        assert_eq!(offset_of!(EpisodeSummary, stops), 40);
        assert_eq!(offset_of!(ActionMsg, step), 16);
        assert_eq!(offset_of!(ActionMsg, actions), 32);
        // the README's examples
        let l = ObsLayout::new(4, 224, 224);
        assert_eq!((l.rgb_offset, l.depth_offset, l.gesture_offset, l.total_len), (768, 602880, 1004288, 1080320));
        let l = ObsLayout::new(2, 64, 64);
        assert_eq!((l.rgb_offset, l.depth_offset, l.gesture_offset, l.total_len), (384, 24960, 41344, 79360));
        // device frames: 224 × 4 = 896 bytes a row, padded to 1,024
        let d = DeviceFrameLayout::new(8, 224, 224);
        assert_eq!((d.row_bytes, d.layer_bytes, d.info_offset, d.size), (1024, 229_376, 1_835_008, 3_670_016));
        assert_eq!(DeviceFrameLayout::new(8, 64, 64).row_bytes, 256);
    }

    #[test]
    fn names_carry_the_run_id() {
        assert_ne!(service::obs("a", 0), service::obs("b", 0));
        assert_ne!(service::obs("a", 0), service::act("a", 0));
        assert_ne!(service::prefix("a"), service::prefix("b"));
        assert_eq!(service::prefix("run/1 x"), "gesthor_run_1_x_");
    }

    #[test]
    fn sections_and_view_see_the_same_bytes() {
        let shape = ObsShape::new(3, 20, 10);
        let mut buf = vec![0u64; shape.layout.total_len as usize / 8 + 1];
        // SAFETY: reinterpreting an owned u64 buffer as bytes.
        let bytes = unsafe { std::slice::from_raw_parts_mut(buf.as_mut_ptr() as *mut u8, buf.len() * 8) };
        {
            let s = ObsSections::new(&shape, bytes).unwrap();
            assert_eq!(s.rgb.len(), 3 * 200 * 3);
            s.records[2].env_step = 7;
            s.rgb[200 * 3 + 5] = 9;
            s.depth[2 * 200] = 65535;
            s.gesture[GESTURE_FRAMES * GESTURE_DIMS] = 0x3C00;
        }
        let v = ObsView::new(shape, bytes).unwrap();
        assert_eq!(v.records()[2].env_step, 7);
        assert_eq!(v.rgb(1)[5], 9);
        assert_eq!(v.depth(2)[0], 65535);
        assert_eq!(v.gesture_bits(1)[0], 0x3C00);
        assert!(matches!(ObsView::new(shape, &bytes[..100]), Err(ViewError::TooShort { .. })));
        assert_eq!(ObsView::new(shape, &bytes[1..]).unwrap_err(), ViewError::Misaligned);
    }

    #[test]
    fn header_shape_must_match_its_layout() {
        let mut h = ObsHeader {
            num_envs: 2,
            width: 64,
            height: 48,
            gesture_frames: 100,
            gesture_dims: 95,
            layout: ObsLayout::new(2, 64, 48),
            ..Default::default()
        };
        assert!(ObsShape::of_header(&h).is_ok());
        h.width = 65;
        assert_eq!(ObsShape::of_header(&h).unwrap_err(), ViewError::Layout);
    }
}
