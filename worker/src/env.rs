//! The environment: composes scene, physics, nav, task, humanoid and gesture into episodes,
//! and a pool of environments that renders all its views in one submit and writes
//! observations straight into a buffer it is given (shared memory in the worker process).
//!
//! Episode protocol (see `shm_schema`): when an episode ends, the next observation is its
//! final one (terminated/truncated set); the action answered to it is ignored and the env
//! starts a new episode, whose first observation carries `episode_start` and reward 0.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use anyhow::Context;
use half::f16;
use nalgebra::{Point3, Vector2};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use shm_schema::{EnvRecord, EpisodeSummary, GESTURE_DIMS, GESTURE_FRAMES, ObsLayout, SUMMARY_STOPS, StopSummary};

use crate::camera::{Camera, Intrinsics};
use crate::dataset::build::RoomContext;
use crate::dataset::{Dataset, Verify};
use crate::geometry::{Part, angle_diff_deg, yaw_of};
use crate::gesture::{self, Motion};
use crate::humanoid::Humanoid;
use crate::nav::{Goal, NavGrid, expert_action};
use crate::physics::Physics;
use crate::program::Program;
use crate::render::{RenderConfig, Renderer, SceneHandle, View, ViewOut, count_id};
use crate::robot::{self, Action, RobotPose};
use crate::scene::{SceneId, Split, object_id};
use crate::task::{StepFacts, StepResult, Task};
use crate::visibility;
use farm::config::{GestureSchedule, RunConfig};
use farm::seed;

/// Gesture kinds as written into observations.
pub use shm_schema::gesture_kind::{
    INTERVENTION as GESTURE_INTERVENTION, NONE as GESTURE_NONE, REFERENCING as GESTURE_REFERENCING,
};

/// Motion frames the person advances per environment step (the gesture loops).
const FRAMES_PER_STEP: usize = 3;
const SAMPLE_KEY: u64 = 0xE9_0001;
const INTERVENTION_KEY: u64 = 0xE9_0002;

/// What the robot perceives at a step, by schedule (§4.4.1): referencing all episode; an
/// intervention while the heading is more than `angle` degrees from the bearing to the
/// target (the true angle, not the original code's atan2(dz, dx) against Unity's yaw);
/// or both (intervention when facing away, referencing otherwise).
pub fn gesture_kind(schedule: GestureSchedule, pose: &RobotPose, target: Point3<f32>, angle: f32) -> u8 {
    let to = Vector2::new(target.x - pose.x, target.z - pose.z);
    let away = to.norm() > 1e-6 && angle_diff_deg(pose.yaw, yaw_of(to)).abs() > angle;
    match schedule {
        GestureSchedule::None => GESTURE_NONE,
        GestureSchedule::Referencing => GESTURE_REFERENCING,
        GestureSchedule::Intervention => {
            if away {
                GESTURE_INTERVENTION
            } else {
                GESTURE_NONE
            }
        }
        GestureSchedule::Both => {
            if away {
                GESTURE_INTERVENTION
            } else {
                GESTURE_REFERENCING
            }
        }
    }
}

/// Rooms shared by the envs of a pool: scene, reachable grid, targets' success regions.
pub struct Rooms {
    dataset: Arc<Dataset>,
    cache: HashMap<SceneId, Arc<RoomContext>>,
    cfg: RunConfig,
}

impl Rooms {
    pub fn new(dataset: Arc<Dataset>, cfg: &RunConfig) -> Rooms {
        Rooms { dataset, cache: HashMap::new(), cfg: cfg.clone() }
    }

    pub fn get(&mut self, id: SceneId) -> anyhow::Result<Arc<RoomContext>> {
        if let Some(r) = self.cache.get(&id) {
            return Ok(r.clone());
        }
        let scene = self.dataset.scene(id)?;
        let ctx = Arc::new(RoomContext::new(id, scene, &self.cfg.env, self.cfg.task.success_distance));
        self.cache.insert(id, ctx.clone());
        Ok(ctx)
    }
}

/// One running episode.
pub struct Env {
    cfg: RunConfig,
    k: Intrinsics,
    pub program: Program,
    pub program_index: u64,
    pub room: Arc<RoomContext>,
    physics: Physics,
    grid: NavGrid,
    goal: Goal,
    pub pose: RobotPose,
    pub task: Task,
    humanoid: Humanoid,
    referencing: Motion,
    intervention: (u8, Arc<Motion>),
    frame: usize,
    start_geodesic: f32,
    /// Pixels of the target in the frame last shown to the robot.
    visible_pixels: u32,
    intervention_steps: u32,
    last: StepResult,
    last_action: Option<Action>,
    collided: bool,
}

impl Env {
    /// Starts an episode of `program`. `motion` is its referencing gesture.
    pub fn new(
        cfg: &RunConfig,
        room: Arc<RoomContext>,
        program: Program,
        program_index: u64,
        motion: Motion,
        intervention: (u8, Arc<Motion>),
    ) -> anyhow::Result<Env> {
        let robot = room.physics.robot();
        let mut physics = Physics::new(&room.scene.parts(), robot);
        physics.set_human(Some(program.human_xz()));
        anyhow::ensure!(
            room.targets.contains_key(&program.target_object),
            "program {program_index}: target object {} of {} is not reachable",
            program.target_object,
            program.scene
        );
        let (grid, cells, field) = room.goal_field(&physics, program.target_object, program.human_xz());
        let t = &room.targets[&program.target_object];
        let goal =
            Goal { center: t.center, id: object_id(program.target_object), points: t.points.clone(), cells, field };
        let pose = program.robot_start();
        let start_geodesic = goal.geodesic(&grid, pose.xz());
        let mut task = Task::new(cfg.task.clone());
        task.reset(goal.distance_2d(pose.xz()));
        let k = Intrinsics::reference(cfg.env.fov_deg);
        Ok(Env {
            cfg: cfg.clone(),
            k,
            humanoid: Humanoid::seeded(program.seed),
            program,
            program_index,
            room,
            physics,
            grid,
            goal,
            pose,
            task,
            referencing: motion,
            intervention,
            frame: 0,
            start_geodesic,
            visible_pixels: 0,
            intervention_steps: 0,
            last: StepResult::default(),
            last_action: None,
            collided: false,
        })
    }

    pub fn camera(&self) -> Camera {
        self.pose.camera(&self.cfg.env)
    }

    pub fn target_id(&self) -> u16 {
        self.goal.id
    }

    pub fn goal(&self) -> &Goal {
        &self.goal
    }

    pub fn grid(&self) -> &NavGrid {
        &self.grid
    }

    pub fn physics(&self) -> &Physics {
        &self.physics
    }

    pub fn start_geodesic(&self) -> f32 {
        self.start_geodesic
    }

    pub fn is_done(&self) -> bool {
        self.task.is_done()
    }

    pub fn last_result(&self) -> StepResult {
        self.last
    }

    /// The gesture the robot perceives now.
    pub fn gesture_kind(&self) -> u8 {
        gesture_kind(self.cfg.run.method.schedule(), &self.pose, self.goal.center, self.cfg.task.intervention_angle_deg)
    }

    /// The 100 × 95 motion the robot perceives now, if any.
    pub fn perceived(&self) -> Option<&Motion> {
        match self.gesture_kind() {
            GESTURE_REFERENCING => Some(&self.referencing),
            GESTURE_INTERVENTION => Some(&self.intervention.1),
            _ => None,
        }
    }

    pub fn intervention_index(&self) -> u8 {
        self.intervention.0
    }

    /// The person's parts this frame: performing what the robot perceives, standing otherwise.
    pub fn person_parts(&self) -> Vec<Part> {
        let motion = match self.gesture_kind() {
            GESTURE_INTERVENTION => &*self.intervention.1,
            _ => &self.referencing,
        };
        let f = if self.gesture_kind() == GESTURE_NONE { 0 } else { self.frame % gesture::FRAMES };
        let p = &self.program;
        let pose = self.humanoid.pose(motion.frame(f), Point3::from(p.human_pos), p.human_yaw);
        self.humanoid.parts(&pose)
    }

    /// Sets how many target pixels the robot's current frame shows (from the renderer).
    pub fn set_visible_pixels(&mut self, n: u32) {
        self.visible_pixels = n;
    }

    /// Without a renderer: the target counts as seen (1 pixel) when a sample point of it is in
    /// the frame and unoccluded, which implies at least one rendered pixel.
    pub fn update_visibility_geometric(&mut self) {
        let seen = visibility::visible(&self.physics, &self.camera(), &self.k, &self.goal.points, self.goal.id);
        self.visible_pixels = seen as u32;
    }

    pub fn visible_pixels(&self) -> u32 {
        self.visible_pixels
    }

    /// The shortest-path expert's action from here, trusting the rendered frame (when there
    /// is one) on whether the target is in view.
    pub fn expert(&self, rendered: bool) -> Action {
        let seen = rendered.then_some(self.visible_pixels >= self.cfg.task.min_visible_pixels);
        expert_action(
            &self.grid,
            &self.physics,
            &self.cfg.env,
            &self.k,
            self.cfg.task.success_distance,
            &self.goal,
            &self.pose,
            seen,
        )
    }

    /// Geodesic distance from the robot to the success region now.
    pub fn geodesic(&self) -> f32 {
        self.goal.geodesic(&self.grid, self.pose.xz())
    }

    /// Applies an action and scores it. The visibility used by Stop is that of the frame the
    /// robot saw when choosing the action (set before this call).
    pub fn step(&mut self, action: Action) -> StepResult {
        let before = self.geodesic();
        let m = robot::apply(&mut self.pose, action, &self.cfg.env, &self.physics);
        let after = self.geodesic();
        let facts = StepFacts {
            action,
            moved: m.moved,
            collided: m.collided,
            travelled: if m.moved { self.cfg.env.move_step } else { 0.0 },
            distance: self.goal.distance_2d(self.pose.xz()),
            visible_pixels: self.visible_pixels,
            progress: if before.is_finite() && after.is_finite() { before - after } else { 0.0 },
        };
        self.last = self.task.step(&facts);
        self.last_action = Some(action);
        self.collided = m.collided;
        self.frame += FRAMES_PER_STEP;
        if self.gesture_kind() == GESTURE_INTERVENTION {
            self.intervention_steps += 1;
        }
        self.last
    }

    /// The person relative to the robot: right (m), forward (m), yaw difference / 360.
    pub fn person_relative(&self) -> [f32; 3] {
        let d = self.program.human_xz() - self.pose.xz();
        let h = self.pose.heading();
        let right = Vector2::new(h.y, -h.x);
        [d.dot(&right), d.dot(&h), angle_diff_deg(self.pose.yaw, self.program.human_yaw) / 360.0]
    }

    /// Summary of the episode so far (complete once it is done).
    pub fn summary(&self) -> EpisodeSummary {
        let s = &self.task.stats;
        let mut stops = [StopSummary::default(); SUMMARY_STOPS];
        for (i, st) in s.stops.iter().take(SUMMARY_STOPS).enumerate() {
            stops[i] = StopSummary {
                step: st.step,
                success: st.success as u32,
                distance: st.distance,
                path_length: st.path_length,
            };
        }
        EpisodeSummary {
            steps: s.steps,
            success: s.success as u32,
            collisions: s.collisions,
            num_stops: s.stops.len() as u32,
            path_length: s.path_length,
            start_geodesic: self.start_geodesic,
            final_distance: s.final_distance,
            total_reward: s.total_reward,
            intervention_steps: self.intervention_steps,
            _pad: 0,
            stops,
        }
    }

    /// Fills the record of this env's current observation (counters are the pool's).
    fn fill_record(&self, r: &mut EnvRecord, expert: bool) {
        let done = self.task.is_done();
        r.program = self.program_index;
        r.episode_step = self.task.stats.steps;
        r.last_action = self.last_action.map_or(255, |a| a as u32);
        r.reward = if self.last_action.is_some() { self.last.reward } else { 0.0 };
        r.terminated = self.last.terminated as u8;
        r.truncated = self.last.truncated as u8;
        r.episode_start = self.last_action.is_none() as u8;
        r.success = self.last.success as u8;
        r.collided = self.collided as u8;
        r.gesture_kind = self.gesture_kind();
        r.gesture_index = self.intervention.0;
        r.idle = 0;
        r.expert_action = if expert && !done { self.expert(true) as u8 } else { 255 };
        r.stops = self.task.stats.stops.len() as u32;
        r.target_category = self.program.target.target_index().unwrap_or(0);
        r.target_instances = self.program.instances;
        r.visible_pixels = self.visible_pixels;
        r.robot = [self.pose.x, self.pose.z, self.pose.yaw];
        r.person_rel = self.person_relative();
        r.distance = self.goal.distance_2d(self.pose.xz());
        r.geodesic = self.geodesic();
        r.summary = if done { self.summary() } else { EpisodeSummary::default() };
    }
}

/// Which programs a pool runs.
#[derive(Clone, Debug)]
pub enum ProgramSource {
    /// Draw programs of the run's split at random from a seeded stream (training).
    Sample,
    /// Run exactly these programs of the run's split, in order (evaluation).
    Sequence(Vec<u64>),
}

/// Identity and duties of a pool.
#[derive(Clone, Debug)]
pub struct PoolSpec {
    pub worker_id: u32,
    /// Restart count of the worker slot: a restarted worker draws from a fresh stream.
    pub generation: u32,
    pub programs: ProgramSource,
    /// Compute the expert's action for every observation (for the `expert` policy).
    pub expert_hints: bool,
}

/// Programs available to a run: the split, filtered by the config's rooms and size limit.
pub fn eligible_programs(ds: &Dataset, cfg: &RunConfig) -> anyhow::Result<Vec<u64>> {
    let split = cfg.run.split;
    let file = ds.require(split)?;
    let rooms: Vec<SceneId> = cfg.run.scenes.iter().filter_map(|s| SceneId::parse(s)).collect();
    let mut out = Vec::new();
    for i in 0..file.len() {
        let r = file.record(i);
        if rooms.is_empty() || rooms.iter().any(|id| id.floorplan() as u16 == r.floorplan) {
            out.push(i as u64);
        }
    }
    if let Some(m) = cfg.run.max_programs {
        out.truncate(m);
    }
    anyhow::ensure!(
        !out.is_empty(),
        "{}: no programs of split `{}` match run.scenes {:?}",
        ds.dir.display(),
        split.name(),
        cfg.run.scenes
    );
    Ok(out)
}

enum Slot {
    Running(Box<Env>),
    Idle,
}

/// E environments and one renderer: one worker's share of the farm.
pub struct EnvPool {
    cfg: RunConfig,
    spec: PoolSpec,
    dataset: Arc<Dataset>,
    rooms: Rooms,
    renderer: Renderer,
    handles: HashMap<SceneId, SceneHandle>,
    interventions: Vec<Arc<Motion>>,
    envs: Vec<Slot>,
    eligible: Vec<u64>,
    queue: VecDeque<u64>,
    rng: ChaCha8Rng,
    env_steps: Vec<u64>,
    episodes: Vec<u64>,
    ids: Vec<Vec<u16>>,
    layout: ObsLayout,
}

/// Payload sections of one observation, borrowed mutably and disjointly.
struct Sections<'a> {
    records: &'a mut [EnvRecord],
    rgb: Vec<&'a mut [u8]>,
    depth: Vec<&'a mut [u16]>,
    gesture: Vec<&'a mut [u16]>,
}

fn sections<'a>(payload: &'a mut [u8], l: &ObsLayout, n: usize) -> anyhow::Result<Sections<'a>> {
    anyhow::ensure!(
        payload.len() as u64 >= l.total_len,
        "observation buffer of {} bytes is smaller than the layout's {}",
        payload.len(),
        l.total_len
    );
    anyhow::ensure!(payload.as_ptr() as usize % 64 == 0, "observation buffer is not 64-byte aligned");
    let (head, rest) = payload.split_at_mut(l.rgb_offset as usize);
    let (rgb_all, rest) = rest.split_at_mut((l.depth_offset - l.rgb_offset) as usize);
    let (depth_all, rest) = rest.split_at_mut((l.gesture_offset - l.depth_offset) as usize);
    let gest_all = &mut rest[..(l.total_len - l.gesture_offset) as usize];
    // SAFETY: the buffer is 64-byte aligned (checked above), `records_offset` is 0, and
    // EnvRecord is #[repr(C)] plain data for which every bit pattern is valid.
    let records = unsafe { std::slice::from_raw_parts_mut(head.as_mut_ptr() as *mut EnvRecord, n) };
    let rgb = rgb_all.chunks_exact_mut(l.rgb_stride as usize).take(n).collect();
    let depth16: &mut [u16] = bytemuck::cast_slice_mut(depth_all);
    let depth = depth16.chunks_exact_mut((l.depth_stride / 2) as usize).take(n).collect();
    let gest16: &mut [u16] = bytemuck::cast_slice_mut(gest_all);
    let gesture = gest16.chunks_exact_mut((l.gesture_stride / 2) as usize).take(n).collect();
    Ok(Sections { records, rgb, depth, gesture })
}

/// A 64-byte aligned buffer for observations outside shared memory (tests, benchmarks).
pub struct AlignedBuf {
    lines: Vec<Line>,
    len: usize,
}

#[repr(C, align(64))]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Line([u8; 64]);

impl AlignedBuf {
    pub fn new(len: usize) -> AlignedBuf {
        AlignedBuf { lines: vec![Line([0; 64]); len.div_ceil(64)], len }
    }
    pub fn as_slice(&self) -> &[u8] {
        &bytemuck::cast_slice(&self.lines)[..self.len]
    }
    pub fn as_mut_slice(&mut self) -> &mut [u8] {
        &mut bytemuck::cast_slice_mut(&mut self.lines)[..self.len]
    }
}

impl EnvPool {
    pub fn new(cfg: &RunConfig, spec: PoolSpec) -> anyhow::Result<EnvPool> {
        let ds = Arc::new(Dataset::open(&cfg.run.dataset, Verify::Quick)?);
        EnvPool::with_dataset(cfg, spec, ds)
    }

    pub fn with_dataset(cfg: &RunConfig, spec: PoolSpec, dataset: Arc<Dataset>) -> anyhow::Result<EnvPool> {
        let n = cfg.env.envs_per_worker;
        let rcfg = RenderConfig {
            width: cfg.env.width,
            height: cfg.env.height,
            fov_deg: cfg.env.fov_deg,
            max_views_per_submit: n.max(1),
        };
        let renderer = Renderer::new(&rcfg).context("starting the renderer")?;
        let eligible = eligible_programs(&dataset, cfg)?;
        let iv = dataset.interventions();
        let interventions = (0..iv.len())
            .map(|i| Motion::from_flat(&iv.motion(i)).map(Arc::new).context("intervention motion has the wrong size"))
            .collect::<anyhow::Result<Vec<_>>>()?;
        anyhow::ensure!(
            !interventions.is_empty(),
            "{}: the dataset holds no intervention gestures",
            dataset.dir.display()
        );
        let queue = match &spec.programs {
            ProgramSource::Sample => VecDeque::new(),
            ProgramSource::Sequence(v) => v.iter().copied().collect(),
        };
        let rng = seed::rng(cfg.run.seed, &[SAMPLE_KEY, spec.worker_id as u64, spec.generation as u64]);
        let layout = ObsLayout::new(n as u32, cfg.env.width, cfg.env.height);
        let px = (cfg.env.width * cfg.env.height) as usize;
        Ok(EnvPool {
            cfg: cfg.clone(),
            rooms: Rooms::new(dataset.clone(), cfg),
            dataset,
            spec,
            renderer,
            handles: HashMap::new(),
            interventions,
            envs: (0..n).map(|_| Slot::Idle).collect(),
            eligible,
            queue,
            rng,
            env_steps: vec![0; n],
            episodes: vec![0; n],
            ids: vec![vec![0; px]; n],
            layout,
        })
    }

    pub fn num_envs(&self) -> usize {
        self.envs.len()
    }

    pub fn layout(&self) -> ObsLayout {
        self.layout
    }

    pub fn renderer_info(&self) -> String {
        self.renderer.adapter_info()
    }

    /// Every env has run out of programs (only with a `Sequence`).
    pub fn finished(&self) -> bool {
        matches!(self.spec.programs, ProgramSource::Sequence(_)) && self.envs.iter().all(|s| matches!(s, Slot::Idle))
    }

    pub fn env(&self, i: usize) -> Option<&Env> {
        match &self.envs[i] {
            Slot::Running(e) => Some(e),
            Slot::Idle => None,
        }
    }

    fn next_program(&mut self) -> Option<u64> {
        match &self.spec.programs {
            ProgramSource::Sample => Some(self.eligible[self.rng.random_range(0..self.eligible.len())]),
            ProgramSource::Sequence(_) => self.queue.pop_front(),
        }
    }

    fn start_episode(&mut self, i: usize) -> anyhow::Result<()> {
        let Some(index) = self.next_program() else {
            self.envs[i] = Slot::Idle;
            return Ok(());
        };
        let split: Split = self.cfg.run.split;
        let file = self.dataset.require(split)?;
        let program = Program::from_record(index, &file.record(index as usize))
            .with_context(|| format!("{}: program {index} is invalid", self.dataset.dir.display()))?;
        let motion = Motion::from_flat(&file.motion(index as usize)).context("motion has the wrong size")?;
        let room = self.rooms.get(program.scene_id())?;
        // Evaluation pairs each program with a fixed intervention gesture; training varies it.
        let key = match self.spec.programs {
            ProgramSource::Sample => seed::mix(
                self.cfg.run.seed,
                &[
                    INTERVENTION_KEY,
                    program.seed,
                    self.episodes[i],
                    i as u64,
                    self.spec.worker_id as u64,
                    self.spec.generation as u64,
                ],
            ),
            ProgramSource::Sequence(_) => seed::mix(self.cfg.run.seed, &[INTERVENTION_KEY, program.seed]),
        };
        let iv = (key % self.interventions.len() as u64) as usize;
        let env = Env::new(&self.cfg, room, program, index, motion, (iv as u8, self.interventions[iv].clone()))?;
        self.envs[i] = Slot::Running(Box::new(env));
        self.episodes[i] += 1;
        Ok(())
    }

    /// Writes the first observation of every env.
    pub fn reset(&mut self, payload: &mut [u8]) -> anyhow::Result<()> {
        for i in 0..self.envs.len() {
            self.start_episode(i)?;
        }
        self.observe(payload)
    }

    /// Applies one action per env and writes the next observation.
    pub fn step(&mut self, actions: &[u8], payload: &mut [u8]) -> anyhow::Result<()> {
        anyhow::ensure!(actions.len() >= self.envs.len(), "{} actions for {} envs", actions.len(), self.envs.len());
        for i in 0..self.envs.len() {
            let restart = match &mut self.envs[i] {
                Slot::Idle => false,
                Slot::Running(env) if env.is_done() => true,
                Slot::Running(env) => {
                    let a = Action::from_index(actions[i])
                        .with_context(|| format!("env {i}: action {} is not one of 0..4", actions[i]))?;
                    env.step(a);
                    false
                }
            };
            if restart {
                self.start_episode(i)?;
            }
        }
        self.observe(payload)
    }

    fn scene_handle(&mut self, id: SceneId) -> anyhow::Result<SceneHandle> {
        if let Some(h) = self.handles.get(&id) {
            return Ok(*h);
        }
        let room = self.rooms.get(id)?;
        let h = self.renderer.upload_scene(&room.scene.parts());
        self.handles.insert(id, h);
        Ok(h)
    }

    /// Renders every running env's view in one call, straight into the payload, then fills
    /// records and gestures.
    fn observe(&mut self, payload: &mut [u8]) -> anyhow::Result<()> {
        let n = self.envs.len();
        let layout = self.layout;
        let mut handles = Vec::with_capacity(n);
        for i in 0..n {
            let h = match &self.envs[i] {
                Slot::Running(e) => Some(self.scene_handle(e.program.scene_id())?),
                Slot::Idle => None,
            };
            handles.push(h);
        }
        let sec = sections(payload, &layout, n)?;
        let Sections { records, rgb, depth, gesture } = sec;
        let person: Vec<Option<Vec<Part>>> = self
            .envs
            .iter()
            .map(|s| match s {
                Slot::Running(e) => Some(e.person_parts()),
                Slot::Idle => None,
            })
            .collect();
        let mut views = Vec::with_capacity(n);
        let mut outs = Vec::with_capacity(n);
        let mut running = Vec::with_capacity(n);
        for (((i, rgb), depth), ids) in rgb.into_iter().enumerate().zip(depth).zip(self.ids.iter_mut()) {
            match (&self.envs[i], handles[i], &person[i]) {
                (Slot::Running(e), Some(h), Some(parts)) => {
                    views.push(View { scene: h, camera: e.camera(), dynamic: parts });
                    outs.push(ViewOut { rgb, depth, ids: Some(ids.as_mut_slice()) });
                    running.push(i);
                }
                _ => {
                    rgb.fill(0);
                    depth.fill(u16::MAX);
                }
            }
        }
        self.renderer.render(&views, &mut outs)?;
        drop(outs);
        for &i in &running {
            if let Slot::Running(e) = &mut self.envs[i] {
                let px = count_id(&self.ids[i], e.target_id());
                e.set_visible_pixels(px);
            }
        }
        for (i, (r, g)) in records.iter_mut().zip(gesture).enumerate() {
            self.env_steps[i] += 1;
            let mut rec = EnvRecord { env_step: self.env_steps[i], episode: self.episodes[i], ..Default::default() };
            match &self.envs[i] {
                Slot::Running(e) => {
                    e.fill_record(&mut rec, self.spec.expert_hints);
                    match e.perceived() {
                        Some(m) => {
                            for (dst, src) in g.iter_mut().zip(m.as_flat()) {
                                *dst = f16::from_f32(*src).to_bits();
                            }
                        }
                        None => g.fill(0),
                    }
                }
                Slot::Idle => {
                    rec.idle = 1;
                    rec.expert_action = 255;
                    rec.last_action = 255;
                    g.fill(0);
                }
            }
            *r = rec;
        }
        debug_assert_eq!(GESTURE_FRAMES * GESTURE_DIMS, crate::dataset::MOTION_LEN);
        Ok(())
    }
}

/// The simulator's pool of environments is the farm's real stepper.
impl farm::stepper::Stepper for EnvPool {
    fn num_envs(&self) -> usize {
        EnvPool::num_envs(self)
    }
    fn layout(&self) -> ObsLayout {
        EnvPool::layout(self)
    }
    fn reset(&mut self, payload: &mut [u8]) -> anyhow::Result<()> {
        EnvPool::reset(self, payload)
    }
    fn step(&mut self, actions: &[u8], payload: &mut [u8]) -> anyhow::Result<()> {
        EnvPool::step(self, actions, payload)
    }
    fn finished(&self) -> bool {
        EnvPool::finished(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intervention_shows_only_when_facing_away() {
        let target = Point3::new(0.0, 0.5, 3.0); // straight ahead of yaw 0
        let at = |yaw: f32| RobotPose { x: 0.0, z: 0.0, yaw };
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(0.0), target, 90.0), GESTURE_NONE);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(90.0), target, 90.0), GESTURE_NONE);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(105.0), target, 90.0), GESTURE_INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(255.0), target, 90.0), GESTURE_INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Both, &at(180.0), target, 90.0), GESTURE_INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Both, &at(30.0), target, 90.0), GESTURE_REFERENCING);
        assert_eq!(gesture_kind(GestureSchedule::Referencing, &at(180.0), target, 90.0), GESTURE_REFERENCING);
        assert_eq!(gesture_kind(GestureSchedule::None, &at(180.0), target, 90.0), GESTURE_NONE);
    }
}

#[cfg(test)]
mod pool_tests {
    use super::*;
    use crate::dataset::build::{BuildOptions, build, default_interventions, default_synth};
    use farm::config::Method;
    use std::path::Path;
    use std::sync::OnceLock;

    /// One small dataset shared by the tests of this module (val: 2 programs per room).
    fn dataset() -> &'static Path {
        static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
        DIR.get_or_init(|| {
            let d = tempfile::tempdir().unwrap();
            let opts = BuildOptions { seed: 5, val_per_room: 2, splits: vec![Split::Val], ..Default::default() };
            build(d.path(), &opts, false, &default_synth, &default_interventions(), &|_, _, _| {}).unwrap();
            d
        })
        .path()
    }

    fn config(method: Method, envs: usize) -> RunConfig {
        let mut cfg = RunConfig::from_toml(
            &format!(
                "[run]\nmethod = \"{}\"\nsplit = \"val\"\n",
                serde_json::to_value(method).unwrap().as_str().unwrap()
            ),
            "test",
        )
        .unwrap();
        cfg.run.dataset = dataset().to_path_buf();
        cfg.env.envs_per_worker = envs;
        cfg.env.width = 64;
        cfg.env.height = 64;
        cfg
    }

    fn pool(cfg: &RunConfig, programs: ProgramSource) -> Option<EnvPool> {
        let spec = PoolSpec { worker_id: 0, generation: 0, programs, expert_hints: true };
        match EnvPool::new(cfg, spec) {
            Ok(p) => Some(p),
            Err(e) if format!("{e:#}").contains("adapter") => {
                eprintln!("skipped: no wgpu adapter ({e:#})");
                None
            }
            Err(e) => panic!("{e:#}"),
        }
    }

    fn records(buf: &AlignedBuf, n: usize) -> Vec<EnvRecord> {
        let b = buf.as_slice();
        (0..n)
            .map(|i| {
                let o = i * std::mem::size_of::<EnvRecord>();
                // SAFETY: the buffer is aligned and holds n records at offset 0.
                unsafe { std::ptr::read(b[o..].as_ptr() as *const EnvRecord) }
            })
            .collect()
    }

    #[test]
    fn expert_succeeds_with_rendered_visibility_and_records_are_consistent() {
        let cfg = config(Method::Both, 3);
        let programs: Vec<u64> = (0..12).collect();
        let Some(mut pool) = pool(&cfg, ProgramSource::Sequence(programs.clone())) else { return };
        let mut buf = AlignedBuf::new(pool.layout().total_len as usize);
        pool.reset(buf.as_mut_slice()).unwrap();
        let mut finished = Vec::new();
        let mut last_step = vec![0u64; 3];
        for _ in 0..3000 {
            let recs = records(&buf, 3);
            for (i, r) in recs.iter().enumerate() {
                assert_eq!(r.env_step, last_step[i] + 1, "env {i} skipped or repeated an observation");
                last_step[i] = r.env_step;
                if r.idle == 1 {
                    continue;
                }
                if r.episode_start == 1 {
                    assert_eq!((r.episode_step, r.reward, r.last_action), (0, 0.0, 255));
                }
                if r.terminated == 1 || r.truncated == 1 {
                    finished.push((r.program, r.success, r.summary));
                }
                assert!(r.target_instances >= 1 && (r.gesture_kind as u8) <= GESTURE_INTERVENTION);
            }
            if pool.finished() {
                break;
            }
            let actions: Vec<u8> =
                recs.iter().map(|r| if r.expert_action == 255 { 0 } else { r.expert_action }).collect();
            pool.step(&actions, buf.as_mut_slice()).unwrap();
        }
        assert!(pool.finished(), "the sequence never ran out");
        let mut ran: Vec<u64> = finished.iter().map(|f| f.0).collect();
        ran.sort();
        assert_eq!(ran, programs, "every program exactly once");
        for (p, success, s) in &finished {
            assert!(*success == 1, "expert failed program {p}: {s:?}");
            assert_eq!(s.num_stops, 1, "program {p}: the expert stops once");
            assert!(
                s.path_length <= 1.3 * s.start_geodesic + 0.5,
                "program {p}: expert path {} for geodesic {}",
                s.path_length,
                s.start_geodesic
            );
        }
    }

    #[test]
    fn intervention_gesture_is_written_when_facing_away() {
        let cfg = config(Method::Intervention, 2);
        let Some(mut pool) = pool(&cfg, ProgramSource::Sample) else { return };
        let mut buf = AlignedBuf::new(pool.layout().total_len as usize);
        pool.reset(buf.as_mut_slice()).unwrap();
        let l = pool.layout();
        let mut saw = [false; 3];
        for _ in 0..48 {
            let recs = records(&buf, 2);
            for (i, r) in recs.iter().enumerate() {
                let env = pool.env(i).unwrap();
                let expect = gesture_kind(GestureSchedule::Intervention, &env.pose, env.goal().center, 90.0);
                assert_eq!(r.gesture_kind, expect);
                saw[r.gesture_kind as usize] = true;
                let o = (l.gesture_offset + i as u64 * l.gesture_stride) as usize;
                let g = &buf.as_slice()[o..o + l.gesture_stride as usize];
                assert_eq!(g.iter().any(|b| *b != 0), r.gesture_kind != GESTURE_NONE, "gesture bytes follow the kind");
            }
            pool.step(&[1, 2], buf.as_mut_slice()).unwrap(); // keep turning: faces every way
        }
        assert!(saw[GESTURE_NONE as usize] && saw[GESTURE_INTERVENTION as usize] && !saw[GESTURE_REFERENCING as usize]);
    }

    #[test]
    fn same_seed_same_episode() {
        let cfg = config(Method::Both, 2);
        let run = || {
            let mut pool = pool(&cfg, ProgramSource::Sample)?;
            let mut buf = AlignedBuf::new(pool.layout().total_len as usize);
            pool.reset(buf.as_mut_slice()).unwrap();
            for t in 0..30u8 {
                pool.step(&[t % 4, (t / 2) % 4], buf.as_mut_slice()).unwrap();
            }
            Some(buf.as_slice().to_vec())
        };
        let (Some(a), Some(b)) = (run(), run()) else { return };
        assert!(a == b, "same seed and actions gave different observations");
    }
}
