//! `orchestrator robot sim`: GesTHOR published as a ROS 2 robot. Each program of a list puts
//! the robot and the person in their room; the simulator publishes a 640×480 RGB-D camera (with
//! `camera_info`), odometry, `/clock` and the person's gesture, integrates `cmd_vel` at a fixed
//! rate with the simulator's collisions, judges each episode by the task's rules from the
//! node's decisions, and records it as the live page does.
//!
//! Time is simulated: each tick publishes odometry and waits for the node's command before it
//! moves on, so a run goes as fast as the node answers (`--realtime` paces it to the wall).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use ros2_client::dds::Publisher;

use farm::config::RunConfig;
use farm::files::write_atomic;
use farm::metrics::{EpisodeResult, Trajectory, TrajectoryStep, scores};
use farm::stepper::PayloadBuf;
use shm_schema::{ObsShape, ObsView, action};
use worker::camera::{Intrinsics, depth_mm};
use worker::dataset::{Dataset, Verify, write_subset};
use worker::env::{EnvPool, PoolSpec, ProgramSource};
use worker::gesture::Motion;
use worker::humanoid::Humanoid;
use worker::program::Program;
use worker::robot::Action;
use worker::scene::Split;

use super::args::SimArgs;
use super::camera::{PolicyView, Sampling, pinhole};
use super::dds::{self, drain};
use super::msgs::{Clock, Decision, Gesture, Header, IdsList, Image, Odometry, Pose, Skeleton2D, Text, Twist};
use super::reading::Reading;
use crate::commands::live::record::{EpisodeRecord, Recorder, episode_config};
use crate::commands::live::wire::{GestureSource, Interventions, Outcome, StepRecord};
use crate::commands::program::program_ref;
use crate::report::trajectory::write_program_gif;

mod episodes;
mod io;
mod tracker;
use episodes::{episode_dir, recorded, summary};
use io::Io;

/// Simulated seconds the node may go without deciding: its look around for the person (24
/// turns), two captures of 7 s and the turn back take well under a minute.
const UNDECIDED_S: f64 = 120.0;

/// The action under way, as the simulator judges it once the next decision comes.
struct Track {
    action: Action,
    /// Geodesic distance when it began, metres moved since.
    before: f32,
    travelled: f32,
    collided: bool,
}

/// The episode under way.
struct Episode {
    program: String,
    /// The node's number for it (from its first decision).
    node_episode: Option<u32>,
    rec: Recorder,
    /// When the node last answered a tick (wall clock), and last decided (simulated time).
    last_answer: Instant,
    last_decision: f64,
    /// Where the robot stood at each decision, for the episode's GIF.
    steps: Vec<TrajectoryStep>,
    /// The program and GOND's clip; the node's reading of the person, and at each decision the
    /// gesture shown and the one the node gave (`camera.json`, with `--gesture camera` or
    /// `skeleton`).
    truth: (Program, Motion),
    heard: Option<Gesture>,
    kinds: Vec<(u8, u8, bool)>,
    camera: bool,
}

pub struct Sim {
    args: SimArgs,
    io: Io,
    cfg: RunConfig,
    checkpoint: PathBuf,
    pool: EnvPool,
    buf: PayloadBuf,
    shape: ObsShape,
    /// The camera's pixels the policy reads (as the node samples them).
    view: Sampling,
    /// Simulated time (s), and when the next camera frame is due.
    t: f64,
    next_frame: f64,
    command: (f64, f64),
    track: Option<Track>,
    holding: String,
    /// When the episode under way began (s): the person performs from then on.
    began: f64,
}

pub fn run(a: SimArgs) -> anyhow::Result<()> {
    farm::process::install_termination_handler()?;
    let ds = Dataset::open(&a.dataset, Verify::Quick)?;
    let (split, list) = crate::commands::robot::args::programs(&a, &ds)?;
    let located = crate::commands::eval::locate(&a.checkpoint)?;
    let checkpoint = located.0.clone();
    let mut outcomes = recorded(&a.out, split, &list, &checkpoint)?;
    let (done, out) = (outcomes.len(), a.out.clone());
    if done > 0 {
        say!("{done} of {} episodes already recorded in {}: on from the next", list.len(), out.display());
    }
    if done < list.len() {
        let mut sim = Sim::new(a, located, split, list[done..].to_vec())?;
        for (n, &p) in list.iter().enumerate().skip(done) {
            if farm::process::stop_requested() {
                break;
            }
            let program = program_ref(split, p);
            let outcome = sim.episode(&ds, split, p, n + 1, n == done)?;
            say!(
                "{program}: {} after {} steps (SPL {:.2}) [{}/{}]",
                if outcome.success { "success" } else { "failure" },
                outcome.steps,
                outcome.spl,
                n + 1,
                list.len()
            );
            outcomes.push((program, outcome));
        }
    }
    summary(&out, &checkpoint, &outcomes)
}

impl Sim {
    /// `(checkpoint, run)`: the checkpoint `--checkpoint` names, and its run's folder.
    fn new(args: SimArgs, (checkpoint, run): (PathBuf, PathBuf), split: Split, list: Vec<u64>) -> anyhow::Result<Sim> {
        let mut cfg = RunConfig::load(&run.join("config.toml"))
            .with_context(|| format!("--checkpoint {}: its run's config", args.checkpoint.display()))?;
        cfg = episode_config(&cfg, &args.dataset, split);
        // the node ends an episode at its first Stop: so does the judge
        cfg.task.max_stops = 1;
        let policy = PolicyView { size: cfg.env.width, fov_deg: cfg.env.fov_deg };
        let view = Sampling::new(&pinhole(args.width, args.height, cfg.env.fov_deg as f64, Header::default()), policy)
            .map_err(|e| anyhow::anyhow!("--width {} --height {}: {e}", args.width, args.height))?;
        cfg.env.width = args.width;
        cfg.env.height = args.height;
        cfg.env.frames = farm::config::FramePath::SharedMemory;
        let spec =
            PoolSpec { worker_id: 0, generation: 0, programs: ProgramSource::Sequence(list), expert_hints: false };
        let pool = EnvPool::new(&cfg, spec)?;
        let shape = ObsShape::new(1, args.width, args.height);
        let io = Io::open(&args.bus)?;
        say!(
            "GesTHOR as a ROS 2 robot on domain {}: camera {} ({}×{}, {}° vertical), odometry {}, commands {}",
            args.bus.domain,
            io.names.colour,
            args.width,
            args.height,
            cfg.env.fov_deg,
            io.names.odom,
            io.names.cmd_vel
        );
        Ok(Sim {
            buf: PayloadBuf::new(&pool.layout()),
            pool,
            shape,
            view,
            io,
            cfg,
            checkpoint,
            t: 0.0,
            next_frame: 0.0,
            command: (0.0, 0.0),
            track: None,
            holding: String::new(),
            began: 0.0,
            args,
        })
    }

    /// One program, from its start to the node's Stop (or the step limit).
    /// `first`: the first this process runs (the node may not have appeared yet).
    fn episode(
        &mut self,
        ds: &Dataset,
        split: Split,
        index: u64,
        number: usize,
        first: bool,
    ) -> anyhow::Result<Outcome> {
        let program = &program_ref(split, index);
        let started = match first {
            true => {
                self.pool.reset(self.buf.bytes_mut())?;
                true
            }
            false => self.pool.next_episode(0)?,
        };
        anyhow::ensure!(started, "{program}: the simulator has no program left");
        let env = self.pool.env(0).context("the episode's env")?;
        let dir = episode_dir(&self.args.out, number);
        let (p, motion) = crate::commands::program::dataset_program(ds, split, index as usize)?;
        write_subset(&dir.join("dataset"), ds, split, &[(p.clone(), motion.as_flat().to_vec())])
            .with_context(|| format!("writing {}", dir.display()))?;
        let mut cfg = episode_config(&self.cfg, &dir.join("dataset"), split);
        cfg.task.max_stops = 1;
        let target = env.program.target.name();
        let mut e = Episode {
            program: program.to_string(),
            node_episode: None,
            rec: Recorder::new(&dir, &cfg)?,
            last_answer: Instant::now(),
            last_decision: self.t,
            steps: Vec::new(),
            truth: (p, motion),
            heard: None,
            kinds: Vec::new(),
            camera: false,
        };
        self.command = (0.0, 0.0);
        self.track = None;
        self.began = self.t;
        self.tick(true)?;
        self.apply((0.0, 0.0))?;
        if first {
            self.await_node()?;
        }
        self.io
            .goal
            .publish(Text { data: target.to_string() })
            .map_err(|e| anyhow::anyhow!("{}: {e:?}", self.io.names.goal))?;
        loop {
            // the node decides before it drives: its decision is judged where the robot stood
            let command = self.tick(false)?;
            if command.is_some() {
                e.last_answer = Instant::now();
            }
            let ended = self.hear(&mut e)?;
            self.apply(command.unwrap_or((0.0, 0.0)))?;
            if let Some(outcome) = ended {
                if e.camera {
                    let (p, motion) = &e.truth;
                    let intervention = self.pool.env(0).context("the episode's env")?.intervention_index();
                    let mut r = Reading::new(p, motion, &Humanoid::seeded(p.seed), intervention, e.heard.as_ref());
                    e.kinds.iter().for_each(|&(shown, given, in_view)| r.decided(shown, given, in_view));
                    write_atomic(&dir.join("camera.json"), serde_json::to_string_pretty(&r)?.as_bytes())?;
                }
                if number <= self.args.gifs {
                    let t = Trajectory { success: outcome.success, steps: e.steps, ..Default::default() };
                    let title = format!("{program} → {target} over ROS 2");
                    write_program_gif(&cfg, &dir.join("dataset"), split, &t, &title, &dir.join("episode.gif"))?;
                }
                // episode.json last: it marks the episode done for a run that goes on
                e.rec.finish(&EpisodeRecord {
                    program: e.program.clone(),
                    checkpoint: self.checkpoint.clone(),
                    gesture: GestureSource::Program,
                    interventions: Interventions::Rule,
                    beside: None,
                    outcome: outcome.clone(),
                })?;
                return Ok(outcome);
            }
            self.still_running(&e)?;
        }
    }

    /// The node still answers and decides, and no signal came.
    fn still_running(&self, e: &Episode) -> anyhow::Result<()> {
        // a silent node by the wall clock; a node that answers but never decides by simulated
        // time, so that a loaded machine does not end an episode a fast one would finish
        anyhow::ensure!(
            e.last_answer.elapsed().as_secs_f64() < self.args.wait,
            "{}: the robot node answered nothing for {:.0} s (is `orchestrator robot` running on domain {}?)",
            e.program,
            self.args.wait,
            self.args.bus.domain
        );
        anyhow::ensure!(
            self.t - e.last_decision < UNDECIDED_S,
            "{}: the robot node decided nothing for {UNDECIDED_S} s of simulated time",
            e.program
        );
        anyhow::ensure!(!farm::process::stop_requested(), "stopped by a signal");
        Ok(())
    }

    /// Waits for the node's goal subscription (samples sent before it would be lost), the
    /// sensors ticking meanwhile.
    fn await_node(&mut self) -> anyhow::Result<()> {
        let start = Instant::now();
        while self.io.node.subscription_count(&self.io.names.goal) == 0
            || self.io.node.publisher_count(&self.io.names.cmd_vel) == 0
        {
            anyhow::ensure!(
                start.elapsed().as_secs_f64() < self.args.wait,
                "no robot node subscribed to {} within {:.0} s (start `orchestrator robot --domain {}`)",
                self.io.names.goal,
                self.args.wait,
                self.args.bus.domain
            );
            anyhow::ensure!(!farm::process::stop_requested(), "stopped by a signal");
            std::thread::sleep(Duration::from_secs_f64(1.0 / self.args.rate));
            self.tick(true)?;
        }
        // the node's other subscriptions match about now: let the camera reach it once more
        std::thread::sleep(Duration::from_millis(300));
        self.tick(true).map(|_| ())
    }
}

impl Sim {
    /// One tick of simulated time: the clock and odometry, a camera frame when one is due (or
    /// `frame`); the node's command for the tick, if it answered.
    fn tick(&mut self, frame: bool) -> anyhow::Result<Option<(f64, f64)>> {
        let dt = 1.0 / self.args.rate;
        self.t += dt;
        let stamp = dds::time(self.t);
        publish(&self.io.clock, Clock { clock: stamp }, &self.io.names.clock)?;
        publish(&self.io.odom, self.odometry(), &self.io.names.odom)?;
        if frame || self.t >= self.next_frame - 1e-9 {
            self.publish_frame()?;
            self.next_frame = self.t + 1.0 / self.args.camera_rate;
        }
        let wall = Instant::now();
        let command = self.answer();
        if self.args.realtime {
            std::thread::sleep(Duration::from_secs_f64(dt).saturating_sub(wall.elapsed()));
        }
        Ok(command)
    }

    /// Moves the robot by a tick of `command` (m/s, rad/s), the collisions stopping it.
    fn apply(&mut self, (v, w): (f64, f64)) -> anyhow::Result<()> {
        let dt = 1.0 / self.args.rate;
        self.command = (v, w);
        let env = self.pool.env_mut(0).context("the episode's env")?;
        let from = env.pose.xz();
        let blocked = env.drive((v * dt) as f32, -(w * dt).to_degrees() as f32);
        if let Some(track) = &mut self.track {
            track.travelled += (env.pose.xz() - from).norm();
            track.collided |= blocked;
        }
        Ok(())
    }

    /// The node's command for this tick: the first to arrive within a moment (it answers every
    /// odometry message while an episode runs); none, and the base stops.
    fn answer(&mut self) -> Option<(f64, f64)> {
        let until = Instant::now() + Duration::from_millis(250);
        loop {
            let (twists, _) = drain(&self.io.cmd_vel);
            if let Some(t) = twists.last() {
                return Some((t.linear.x, t.angular.z));
            }
            if Instant::now() > until {
                return None;
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }

    fn odometry(&self) -> Odometry {
        let p = self.pool.env(0).map(|e| e.pose).unwrap_or(worker::robot::RobotPose { x: 0.0, z: 0.0, yaw: 0.0 });
        let mut o = Odometry {
            header: Header::new(dds::time(self.t), "odom"),
            child_frame_id: "base_link".into(),
            pose: Default::default(),
            twist: Default::default(),
        };
        o.pose.pose = floor_pose(p.x, p.z, p.yaw);
        o.twist.twist = Twist::planar(self.command.0, self.command.1);
        o
    }
}

/// The simulator's floor (x right, z forward, yaw clockwise in degrees) as the odometry frame
/// (x forward, y left, yaw counter-clockwise in radians).
pub fn floor_pose(x: f32, z: f32, yaw_deg: f32) -> Pose {
    Pose::planar(z as f64, -x as f64, -(yaw_deg as f64).to_radians())
}

fn publish<M: serde::Serialize + ros2_client::Message>(p: &Publisher<M>, m: M, topic: &str) -> anyhow::Result<()> {
    p.publish(m).map_err(|e| anyhow::anyhow!("{topic}: {e}"))
}

impl Sim {
    /// The camera: colour (rgb8), depth (16UC1, mm) and camera_info, and the person's gesture,
    /// all stamped now.
    fn publish_frame(&mut self) -> anyhow::Result<()> {
        if self.args.animate == "time" {
            let frame = ((self.t - self.began) * worker::gesture::FPS as f64) as usize;
            self.pool.env_mut(0).context("the episode's env")?.set_person_frame(frame);
        }
        self.pool.observe(self.buf.bytes_mut())?;
        let view = self.observed();
        let (w, h) = (self.args.width, self.args.height);
        let header = Header::new(dds::time(self.t), "camera_color_optical_frame");
        let colour = Image {
            header: header.clone(),
            height: h,
            width: w,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: w * 3,
            data: view.rgb(0).to_vec(),
        };
        let mm = |v: &u16| depth_mm(*v).to_le_bytes();
        let depth = Image {
            header: header.clone(),
            height: h,
            width: w,
            encoding: "16UC1".into(),
            is_bigendian: 0,
            step: w * 2,
            data: view.depth(0).iter().flat_map(mm).collect(),
        };
        let info = pinhole(w, h, self.cfg.env.fov_deg as f64, header.clone());
        let gesture = self.gesture()?;
        let body = self.body(&view, header.clone())?;
        let n = &self.io.names;
        publish(&self.io.info, info, &n.info)?;
        publish(&self.io.depth, depth, &n.depth)?;
        publish(&self.io.gesture, gesture, &n.gesture)?;
        publish(&self.io.colour, colour, &n.colour)?;
        // the tracker's: after the image it read
        if let Some(b) = &body {
            publish(&self.io.skeleton, b.clone(), &n.skeleton(tracker::BODY))?;
        }
        let ids = body.map(|_| tracker::BODY.to_string()).into_iter().collect();
        publish(&self.io.tracked, IdsList { header, ids }, &n.tracked)
    }

    /// The person's keypoints as a body tracker would find them in the frame, if it would.
    fn body(&self, view: &ObsView<'_>, header: Header) -> anyhow::Result<Option<Skeleton2D>> {
        let env = self.pool.env(0).context("the episode's env")?;
        let k = Intrinsics { width: self.args.width, height: self.args.height, fov_deg: self.cfg.env.fov_deg };
        let found = tracker::body(&env.person_pose(), &env.camera(), &k, view.depth(0));
        Ok(found.map(|skeleton| Skeleton2D { header, skeleton }))
    }

    /// The gesture the person shows now (the program's, or the intervention by the angle rule),
    /// and where they stand, in the odometry frame.
    fn gesture(&self) -> anyhow::Result<Gesture> {
        let env = self.pool.env(0).context("the episode's env")?;
        let p = &env.program;
        let muscles = env.perceived().map_or_else(Vec::new, |m| m.as_flat().to_vec());
        Ok(Gesture {
            header: Header::new(dds::time(self.t), "odom"),
            kind: env.gesture_kind(),
            person: floor_pose(p.human_pos[0], p.human_pos[2], p.human_yaw),
            frames: if muscles.is_empty() { 0 } else { shm_schema::GESTURE_FRAMES as u16 },
            dims: if muscles.is_empty() { 0 } else { shm_schema::GESTURE_DIMS as u16 },
            muscles,
        })
    }

    /// The node's decisions since the last tick, judged; the outcome once the episode ended.
    fn hear(&mut self, e: &mut Episode) -> anyhow::Result<Option<Outcome>> {
        let (decisions, _) = drain(&self.io.decision);
        let (readings, _) = drain(&self.io.person);
        e.heard = readings.into_iter().rfind(|g| dds::seconds(g.header.stamp) >= self.began).or(e.heard.take());
        for d in decisions {
            if d.action == action::NONE {
                if d.holding != self.holding && !d.holding.is_empty() {
                    say!("{}: the node holds still: {}", e.program, d.holding);
                }
                self.holding = d.holding;
                continue;
            }
            match e.node_episode {
                None if d.step == 1 => e.node_episode = Some(d.episode),
                Some(n) if n == d.episode => {}
                _ => continue,
            }
            e.last_decision = self.t;
            if let Some(outcome) = self.judge(e, &d)? {
                return Ok(Some(outcome));
            }
        }
        Ok(None)
    }

    /// One decision: the action before it is scored where it ended; a Stop (or the step limit)
    /// is scored at once and ends the episode.
    fn judge(&mut self, e: &mut Episode, d: &Decision) -> anyhow::Result<Option<Outcome>> {
        let a = Action::from_index(d.action).with_context(|| format!("decision {}: action {}", d.step, d.action))?;
        // a Stop is judged on the frame the node saw, taken where it stands: the target's pixels in it
        let seen = if a == Action::Stop || d.done { Some(self.target_pixels_seen()?) } else { None };
        let in_view = self.pool.ids(0).contains(&worker::geometry::ID_HUMAN);
        let env = self.pool.env_mut(0).context("the episode's env")?;
        if let Some(t) = self.track.take() {
            env.settle(t.action, t.before, t.travelled, t.collided);
        }
        let record = StepRecord {
            step: d.step - 1,
            robot: [env.pose.x, env.pose.z, env.pose.yaw],
            shown: env.gesture_kind(),
            rule: env.rule_kind(),
            action: d.action,
            probs: d.probs.clone(),
            value: d.value,
        };
        e.rec.step(&record)?;
        e.kinds.push((record.shown, d.gesture_kind, in_view));
        e.camera |= d.gesture_source == "camera" || d.gesture_source == "skeleton";
        let ([x, z, yaw], intervention) = (record.robot, env.intervention_index());
        e.steps.push(TrajectoryStep { x, z, yaw, action: d.action, gesture: record.shown, intervention });
        if let Some(seen) = seen {
            env.set_visible_pixels(seen);
            env.settle(a, env.geodesic(), 0.0, false);
        } else {
            self.track = Some(Track { action: a, before: env.geodesic(), travelled: 0.0, collided: false });
        }
        if !env.is_done() && !d.done {
            return Ok(None);
        }
        self.outcome().map(Some)
    }

    /// The observation the pool last wrote.
    fn observed(&self) -> ObsView<'_> {
        ObsView::new(self.shape, &self.buf.bytes()[..self.shape.layout.total_len as usize])
            .expect("the pool's own layout")
    }

    /// The target's pixels among those the policy read of the last frame, as eval counts them
    /// in its own smaller render.
    fn target_pixels_seen(&self) -> anyhow::Result<u32> {
        let target = self.pool.env(0).context("the episode's env")?.target_id();
        Ok(self.view.pick(self.pool.ids(0)).filter(|&id| id == target).count() as u32)
    }

    fn outcome(&mut self) -> anyhow::Result<Outcome> {
        self.pool.observe(self.buf.bytes_mut())?;
        let view = self.observed();
        let mut r = view.records()[0];
        if r.terminated == 0 && r.truncated == 0 {
            // the node ended before the judge did (a step limit of its own): as truncated here
            r.summary = self.pool.env(0).context("the episode's env")?.summary();
        }
        let result = EpisodeResult::from_record(&r, 0, 0, 0);
        let first = scores([&result], Some(1), self.cfg.task.dts_threshold as f64);
        Ok(Outcome {
            steps: result.steps,
            success: first.sr > 0.0,
            spl: first.spl / 100.0,
            dts: first.dts,
            success_any_stop: result.success,
        })
    }
}
