//! One episode: a program run in its room. Composes the physics, the navigation grid and
//! goal, the task's scoring, the person (humanoid and gestures) and what the robot sees.

use std::sync::Arc;

use nalgebra::Point3;

use shm_schema::{EnvRecord, EpisodeSummary, SUMMARY_STOPS, StopSummary, action, gesture_kind};

use super::schedule;
use crate::camera::{Camera, Intrinsics};
use crate::dataset::build::RoomContext;
use crate::geometry::{Part, xz};
use crate::gesture::{self, Motion};
use crate::humanoid::{Humanoid, SkeletonPose};
use crate::nav::{Goal, NavGrid, expert_action};
use crate::physics::Physics;
use crate::program::Program;
use crate::robot::{self, Action, RobotPose};
use crate::scene::object_id;
use crate::task::{StepFacts, StepResult, Task};
use crate::visibility;
use farm::config::RunConfig;

/// Motion frames the person advances per environment step (the gesture loops).
const FRAMES_PER_STEP: usize = 3;

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
    shortest_path: f32,
    /// Pixels of the target in the frame last shown to the robot.
    visible_pixels: u32,
    intervention_steps: u32,
    last: StepResult,
    last_action: Option<Action>,
    collided: bool,
    /// A person's call on the intervention gesture (live), in place of the angle rule.
    person_calls: Option<bool>,
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
        let shortest_path =
            crate::shortest_path::lower_bound(&grid, pose.xz(), xz(&t.center).into(), cfg.task.success_distance);
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
            shortest_path,
            visible_pixels: 0,
            intervention_steps: 0,
            last: StepResult::default(),
            last_action: None,
            collided: false,
            person_calls: None,
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

    pub fn shortest_path(&self) -> f32 {
        self.shortest_path
    }

    pub fn is_done(&self) -> bool {
        self.task.is_done()
    }

    pub fn last_result(&self) -> StepResult {
        self.last
    }

    /// The gesture the robot perceives now.
    pub fn gesture_kind(&self) -> u8 {
        let away = self.person_calls.unwrap_or_else(|| self.facing_away());
        schedule::shown(self.cfg.run.method.schedule(), away)
    }

    /// What the angle rule would show now, whoever decides (§4.4.1).
    pub fn rule_kind(&self) -> u8 {
        schedule::shown(self.cfg.run.method.schedule(), self.facing_away())
    }

    fn facing_away(&self) -> bool {
        schedule::facing_away(&self.pose, self.goal.center, self.cfg.task.intervention_angle_deg)
    }

    /// Lets a person decide when the intervention gesture is shown (`Some(true)`: now), in place
    /// of the angle rule (`None`), for the methods whose schedule shows it.
    pub fn set_person_calls(&mut self, calls: Option<bool>) {
        self.person_calls = calls;
    }

    /// The 100 × 95 motion the robot perceives now, if any.
    pub fn perceived(&self) -> Option<&Motion> {
        match self.gesture_kind() {
            gesture_kind::REFERENCING => Some(&self.referencing),
            gesture_kind::INTERVENTION => Some(&self.intervention.1),
            _ => None,
        }
    }

    /// Writes the muscles of the gesture the robot perceives now (`FRAMES × GESTURE_DIMS` half
    /// floats, zero where none is shown).
    pub fn write_gesture(&self, out: &mut [u16]) {
        let Some(m) = self.perceived() else { return out.fill(0) };
        for (dst, src) in out.iter_mut().zip(m.as_flat()) {
            *dst = half::f16::from_f32(*src).to_bits();
        }
    }

    pub fn intervention_index(&self) -> u8 {
        self.intervention.0
    }

    /// The person's parts this frame: performing what the robot perceives, standing otherwise.
    pub fn person_parts(&self) -> Vec<Part> {
        self.humanoid.parts(&self.person_pose())
    }

    /// The person's skeleton this frame, in the world.
    pub fn person_pose(&self) -> SkeletonPose {
        let motion = match self.gesture_kind() {
            gesture_kind::INTERVENTION => &*self.intervention.1,
            _ => &self.referencing,
        };
        let f = if self.gesture_kind() == gesture_kind::NONE { 0 } else { self.frame % gesture::FRAMES };
        let p = &self.program;
        self.humanoid.pose(motion.frame(f), Point3::from(p.human_pos), p.human_yaw)
    }

    /// Poses the person at frame `f` of the gesture they perform (`robot sim` animates them in
    /// its own time; the farm advances them a few frames a step).
    pub fn set_person_frame(&mut self, f: usize) {
        self.frame = f;
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
        let travelled = if m.moved { self.cfg.env.move_step } else { 0.0 };
        self.settle(action, before, travelled, m.collided)
    }

    /// Drives the robot continuously (`orchestrator robot sim`): `forward` metres along the
    /// heading, then `turn_deg` clockwise. A move the body cannot make is not made; true when it
    /// was blocked. Scoring waits for [`Env::settle`].
    pub fn drive(&mut self, forward: f32, turn_deg: f32) -> bool {
        let delta = self.pose.heading() * forward;
        let blocked = forward != 0.0 && !self.physics.move_is_free(self.pose.xz(), delta);
        if !blocked {
            self.pose.x += delta.x;
            self.pose.z += delta.y;
        }
        self.pose.yaw = crate::geometry::wrap_deg(self.pose.yaw + turn_deg);
        blocked
    }

    /// Scores an action that has ended where the robot is now: `before` is the geodesic distance
    /// when it began, `travelled` the metres it moved. [`Env::step`] for the discrete moves; the
    /// ROS 2 robot for moves driven by velocity commands.
    pub fn settle(&mut self, action: Action, before: f32, travelled: f32, collided: bool) -> StepResult {
        let after = self.geodesic();
        let facts = StepFacts {
            action,
            moved: travelled > 0.0,
            collided,
            travelled,
            distance: self.goal.distance_2d(self.pose.xz()),
            visible_pixels: self.visible_pixels,
            progress: if before.is_finite() && after.is_finite() { before - after } else { 0.0 },
        };
        self.last = self.task.step(&facts);
        self.last_action = Some(action);
        self.collided = collided;
        self.frame += FRAMES_PER_STEP;
        if self.gesture_kind() == gesture_kind::INTERVENTION {
            self.intervention_steps += 1;
        }
        self.last
    }

    /// The person relative to the robot: right (m), forward (m), yaw difference / 360.
    pub fn person_relative(&self) -> [f32; 3] {
        self.program.person_relative(&self.pose)
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
            shortest_path: self.shortest_path,
            final_distance: s.final_distance,
            total_reward: s.total_reward,
            intervention_steps: self.intervention_steps,
            _pad: 0,
            stops,
        }
    }

    /// Fills the record of this env's current observation (counters are the pool's).
    pub(super) fn fill_record(&self, r: &mut EnvRecord, expert: bool) {
        let done = self.task.is_done();
        r.program = self.program_index;
        r.episode_step = self.task.stats.steps;
        r.last_action = self.last_action.map_or(action::NONE, |a| a as u8) as u32;
        r.reward = if self.last_action.is_some() { self.last.reward } else { 0.0 };
        r.terminated = self.last.terminated as u8;
        r.truncated = self.last.truncated as u8;
        r.episode_start = self.last_action.is_none() as u8;
        r.success = self.last.success as u8;
        r.collided = self.collided as u8;
        r.gesture_kind = self.gesture_kind();
        r.gesture_index = self.intervention.0;
        r.idle = 0;
        r.expert_action = if expert && !done { self.expert(true) as u8 } else { action::NONE };
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
