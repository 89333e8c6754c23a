//! `orchestrator robot`: a trained policy as a ROS 2 node. It reads the robot's camera (colour,
//! aligned depth, camera_info), its odometry and the person's gesture; at each step it asks the
//! policy for an action and drives it on `cmd_vel`, closed on odometry. On stale or bad input
//! it holds still (a zero twist), says why in one line, and decides afresh once input is good.
//!
//! An episode starts with a goal (`~/goal`, a target category such as `Television`) and ends at
//! the policy's first Stop or at the step limit.

use std::time::{Duration, Instant};

use anyhow::Context as _;

use shm_schema::action;
use worker::robot::Action;
use worker::scene::Category;

use super::args::NodeArgs;
use super::camera::PolicyView;
use super::dds::{self, seconds};
use super::drive::{Drive, Ended, Limits, Pose2, wrap};
use super::msgs::{Decision, Header};
use super::observation::{Facts, Observation, person_relative};
use super::person::Person;
use crate::commands::live::policy::{Answer, Checkpoint, Policy};

mod bodies;
mod heard;
mod topics;
use bodies::Bodies;
use heard::{Heard, Watch};
use topics::Io;

enum Phase {
    /// Waiting for a frame taken at or after this time (s).
    Deciding {
        after: f64,
    },
    Acting,
    /// Turning to look for the person (`--gesture camera`).
    Looking,
}

/// Turns of `turn_deg` the robot takes looking for the person before it goes on without them.
const LOOK_TURNS: u32 = 24;

struct Episode {
    number: u32,
    /// Turns taken looking for the person.
    turns: u32,
    /// The heading it began with (rad, odometry), turned back to before the first decision.
    heading: f64,
    target: u32,
    step: u32,
    last_action: u8,
    phase: Phase,
}

pub struct Robot {
    io: Io,
    args: NodeArgs,
    view: PolicyView,
    max_steps: u32,
    /// The policy reads the person (a gesture, their pose): wait for them on the gesture topic.
    needs_person: bool,
    schedule: farm::config::GestureSchedule,
    /// `--gesture camera` or `skeleton`: the person read from the colour frames, or from a
    /// tracker's bodies.
    person: Option<Person>,
    bodies: Option<Bodies>,
    policy: Policy,
    obs: Observation,
    heard: Heard,
    drive: Drive,
    episode: Option<Episode>,
    episodes: u32,
    holding: Option<String>,
    last_zero: Instant,
}

/// Runs the node until Ctrl-C (or SIGTERM): then it stops the base and leaves.
pub fn run(args: NodeArgs) -> anyhow::Result<()> {
    farm::process::install_termination_handler()?;
    let mut robot = Robot::start(args)?;
    robot.spin()
}

impl Robot {
    pub fn start(args: NodeArgs) -> anyhow::Result<Robot> {
        let ck = Checkpoint::open(&args.checkpoint)?;
        let cfg = &ck.cfg;
        anyhow::ensure!(
            cfg.env.width == cfg.env.height,
            "{}: frames of {}×{}; square ones expected",
            ck.name,
            cfg.env.width,
            cfg.env.height
        );
        let view = PolicyView { size: cfg.env.width, fov_deg: cfg.env.fov_deg };
        let limits = Limits {
            move_step: cfg.env.move_step as f64,
            turn_deg: cfg.env.turn_deg as f64,
            speed: args.max_speed,
            turn_rate: args.max_turn_rate,
            stall: args.stall_seconds,
        };
        let needs_person = cfg.run.method.schedule() != farm::config::GestureSchedule::None || cfg.model.person_pose;
        let policy = Policy::start_with(&ck, &ck.config, args.greedy)?;
        let person = match args.gesture.as_str() {
            "camera" | "skeleton" if needs_person => {
                Some(Person::start(args.capture_seconds, args.wave_rate, args.gesture == "camera")?)
            }
            _ => None,
        };
        let mut io = Io::open(&args)?;
        let bodies = match person.as_ref().is_some_and(|p| !p.reads_frames()) {
            true => Some(Bodies::open(&mut io.node, &io.names)?),
            false => None,
        };
        say!(
            "{} on ROS 2 domain {} as {}: colour {}, depth {}, odometry {}, commands {}, goals {}",
            ck.name,
            args.bus.domain,
            io.node.fully_qualified_name(),
            io.names.colour,
            io.names.depth,
            io.names.odom,
            io.names.cmd_vel,
            io.names.goal
        );
        Ok(Robot {
            io,
            view,
            max_steps: cfg.task.max_steps,
            needs_person,
            schedule: cfg.run.method.schedule(),
            person,
            bodies,
            policy,
            obs: Observation::new(view.size),
            heard: Heard::default(),
            drive: Drive::new(limits, Pose2::default()),
            episode: None,
            episodes: 0,
            holding: None,
            last_zero: Instant::now(),
            args,
        })
    }

    fn spin(&mut self) -> anyhow::Result<()> {
        if let Some(t) = self.args.target.clone() {
            self.begin(&t);
        }
        while !farm::process::stop_requested() {
            let odom = self.listen()?;
            match self.problem() {
                Some(p) => self.hold(p, odom),
                None => {
                    if let Some(was) = self.holding.take() {
                        say!("input good again (was: {was})");
                    }
                    self.advance(odom)?;
                }
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        self.hold("stopped by a signal".into(), true);
        for _ in 0..3 {
            self.publish_twist(0.0, 0.0);
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    }

    /// ROS time now: the simulator's clock with `--use-sim-time`, the system's otherwise.
    fn now(&self) -> f64 {
        match self.args.bus.use_sim_time {
            true => self.heard.clock.unwrap_or(0.0),
            false => seconds(ros2_client::builtin_interfaces::Time::now()),
        }
    }
}

impl Robot {
    /// Reads every topic; true when odometry arrived (the control loop runs at its rate).
    fn listen(&mut self) -> anyhow::Result<bool> {
        let (odom, goals) = self.heard.listen(&self.io, self.view, self.person.is_none());
        if let Some(b) = &mut self.bodies {
            if let Some(g) = b.listen(&mut self.io.node, &self.io.names)? {
                self.heard.garbled = Some((g, Instant::now()));
            }
            self.read_bodies();
        }
        let schedule = self.schedule;
        self.heard.pair_frames(self.view, self.person.as_mut().map(|p| (p, schedule)));
        for g in goals {
            self.begin(&g.data);
        }
        Ok(odom)
    }

    /// The person sees each image the tracker is done with, measured by its aligned depth.
    fn read_bodies(&mut self) {
        let (Some(b), Some(p), h) = (&mut self.bodies, &mut self.person, &self.heard) else { return };
        let Some(info) = &h.info else { return };
        let at = h.odom.as_ref().map_or(Pose2::default(), |o| o.0);
        for (stamp, body) in b.ready() {
            if let Some(depth) = h.depth_at(stamp) {
                p.see_skeleton(body.as_ref(), depth, info, at);
            }
        }
    }

    /// Why the robot must hold still now, if it must.
    fn problem(&self) -> Option<String> {
        let w = Watch {
            timeout: Duration::from_secs_f64(self.args.input_timeout),
            max_age: self.args.max_age,
            now: self.now(),
            episode: self.episode.is_some(),
        };
        let names = &self.io.names;
        self.heard.problem(names, &w).or_else(|| self.person_problem(&w))
    }

    /// The gesture's problem, when the policy reads the person and an episode runs.
    fn person_problem(&self, w: &Watch) -> Option<String> {
        if !self.needs_person || self.episode.is_none() {
            return None;
        }
        let read = |p: &Person| p.watched() && self.heard.gesture.is_none();
        if self.person.as_ref().is_some_and(|p| p.capturing() || p.look.is_some() || read(p)) {
            // watching for the person's gesture is waiting, not a fault; nor is a gesture read
            // (or given up on) that the next frame publishes
            return None;
        }
        self.heard.gesture_problem(&self.io.names, w)
    }
}

impl Robot {
    /// A goal: an episode starts (one under way ends, unfinished).
    fn begin(&mut self, goal: &str) {
        let name = goal.trim();
        let Some(target) = Category::from_name(name).and_then(|c| c.target_index()) else {
            let all: Vec<&str> = Category::targets().map(|c| c.name()).collect();
            say!("goal `{name}`: not a target category ({})", all.join(", "));
            return;
        };
        if let Some(e) = &self.episode {
            say!("episode {} ends unfinished: a new goal came", e.number);
        }
        self.episodes += 1;
        let at = self.heard.odom.as_ref().map_or(Pose2::default(), |o| o.0);
        self.drive.restart(at);
        let now = self.now();
        if let Some(p) = &mut self.person {
            p.begin(now);
            self.heard.gesture = None;
        }
        // a frame taken after the goal: none seen before it
        let after = self.heard.frame.as_ref().map_or(self.now(), |f| self.now().max(f.stamp + 1e-6));
        self.episode = Some(Episode {
            number: self.episodes,
            turns: 0,
            heading: at.yaw,
            target,
            step: 0,
            last_action: action::NONE,
            phase: Phase::Deciding { after },
        });
        say!("episode {}: to the {name}", self.episodes);
    }

    /// Holds still: a zero twist at every odometry message (or 10 times a second without
    /// any); the action under way ends, to be decided afresh from good input.
    fn hold(&mut self, why: String, odom: bool) {
        if self.holding.as_ref() != Some(&why) {
            say!("holding still: {why}");
            self.publish_decision(None, false, &why);
            self.holding = Some(why);
        }
        if let Some(e) = self.episode.as_mut().filter(|e| matches!(e.phase, Phase::Acting)) {
            let at = self.heard.odom.as_ref().map_or(Pose2::default(), |o| o.0);
            self.drive.restart(at);
            e.phase = Phase::Deciding { after: f64::NEG_INFINITY };
        }
        if odom || self.last_zero.elapsed() > Duration::from_millis(100) {
            self.publish_twist(0.0, 0.0);
        }
    }

    /// One turn of the loop with good input: the action under way moves on odometry; a frame
    /// taken after it ended gets the policy's next decision.
    fn advance(&mut self, odom: bool) -> anyhow::Result<()> {
        let Some(e) = &mut self.episode else {
            // between episodes the base is held still, as it is while holding
            if odom {
                self.publish_twist(0.0, 0.0);
            }
            return Ok(());
        };
        let (pose, t, _) = self.heard.odom.clone().context("checked: odometry was heard")?;
        match e.phase {
            Phase::Acting if odom => match self.drive.command(pose, t) {
                Ok((v, w)) => self.publish_twist(v, w),
                Err(end) => {
                    if end == Ended::Blocked {
                        say!("episode {} step {}: the move was blocked", e.number, e.step);
                    }
                    e.phase = Phase::Deciding { after: t };
                    self.publish_twist(0.0, 0.0);
                }
            },
            Phase::Looking if odom => match self.drive.command(pose, t) {
                Ok((v, w)) => self.publish_twist(v, w),
                Err(_) => {
                    self.person.as_mut().expect("looking is for the camera's person").watch(t);
                    e.phase = Phase::Deciding { after: t };
                    self.publish_twist(0.0, 0.0);
                }
            },
            Phase::Acting | Phase::Looking => {}
            Phase::Deciding { after } => {
                if odom {
                    self.publish_twist(0.0, 0.0);
                }
                if let Some((p, turn)) = self.person.as_mut().and_then(|p| p.look.map(|turn| (p, turn))) {
                    let e = self.episode.as_mut().expect("under way");
                    if e.turns < LOOK_TURNS {
                        e.turns += 1;
                        e.phase = Phase::Looking;
                        self.drive.start(turn, pose, t);
                        return Ok(());
                    }
                    say!("episode {}: nobody in view all around: on without the person's gesture", e.number);
                    p.give_up(pose);
                }
                if self.turn_back(pose, t) {
                    return Ok(());
                }
                let fresh = self.heard.frame.as_ref().is_some_and(|f| f.stamp >= after);
                let seen =
                    !self.needs_person || self.heard.gesture.as_ref().is_some_and(|g| seconds(g.header.stamp) >= after);
                if fresh && seen {
                    self.decide(pose)?;
                }
            }
        }
        Ok(())
    }

    /// Before its first decision the robot turns back, 15° at a time, to the heading it began
    /// the episode with: it turned to find and face the person, and the policy starts where it
    /// would have without them. True while it turns.
    fn turn_back(&mut self, pose: Pose2, t: f64) -> bool {
        let Some(e) = self.episode.as_mut().filter(|e| e.step == 0) else { return false };
        if self.person.as_ref().is_none_or(|p| !p.watched()) {
            return false;
        }
        let off = wrap(e.heading - pose.yaw);
        if off.abs() < (self.drive.limits().turn_deg / 2.0).to_radians() {
            return false;
        }
        e.phase = Phase::Acting;
        self.drive.start(if off > 0.0 { action::ROTATE_LEFT } else { action::ROTATE_RIGHT }, pose, t);
        true
    }

    /// The policy's decision on the newest frame, published and started.
    fn decide(&mut self, pose: Pose2) -> anyhow::Result<()> {
        let e = self.episode.as_mut().expect("an episode is under way");
        let frame = self.heard.frame.as_ref().expect("a fresh frame");
        let gesture = self.heard.gesture.as_ref().filter(|_| self.needs_person);
        let person = gesture.map_or([0.0; 3], |g| {
            let (x, y, yaw) = g.person.to_planar();
            person_relative(pose, Pose2 { x, y, yaw })
        });
        let facts = Facts { start: e.step == 0, step: e.step, last_action: e.last_action, target: e.target };
        if let Err(why) = self.obs.write(facts, frame, gesture, person) {
            self.heard.gesture = None;
            self.hold(why, false);
            return Ok(());
        }
        let a = self.policy.act(self.obs.payload())?;
        e.step += 1;
        e.last_action = a.action;
        let done = a.action == action::STOP || e.step >= self.max_steps;
        let first = e.step == 1;
        let t = self.now();
        self.publish_decision(Some(&a), done, "");
        if first {
            self.publish_reading();
        }
        let e = self.episode.as_mut().expect("an episode is under way");
        if done {
            say!(
                "episode {} ended after {} steps ({})",
                e.number,
                e.step,
                Action::from_index(a.action).map_or("?", |a| a.name())
            );
            self.episode = None;
            self.publish_twist(0.0, 0.0);
        } else {
            self.drive.start(a.action, pose, t);
            e.phase = Phase::Acting;
        }
        Ok(())
    }

    /// What the camera read of the person this episode, on `~/person` (with the first decision:
    /// the capture is over by then).
    fn publish_reading(&self) {
        let odom = self.heard.odom.as_ref().map_or("", |o| o.2.as_str());
        if let Some(g) = self.person.as_ref().and_then(|p| p.reading(self.now(), odom)) {
            if let Err(e) = self.io.person.publish(g) {
                say!("{}: {e:?}", self.io.names.person);
            }
        }
    }

    fn publish_twist(&mut self, v: f64, w: f64) {
        if let Err(e) = self.io.cmd.publish(v, w, self.now()) {
            say!("{}: {e}", self.io.names.cmd_vel);
        }
        if v == 0.0 && w == 0.0 {
            self.last_zero = Instant::now();
        }
    }

    /// What was decided (or why the robot holds still) on `~/decision`.
    fn publish_decision(&mut self, a: Option<&Answer>, done: bool, holding: &str) {
        let e = self.episode.as_ref();
        let g = self.heard.gesture.as_ref().filter(|_| self.needs_person);
        let action = a.map_or(action::NONE, |a| a.action);
        let d = Decision {
            header: Header::new(dds::time(self.now()), "base_link"),
            episode: e.map_or(0, |e| e.number),
            step: e.map_or(0, |e| e.step),
            action,
            action_name: Action::from_index(action).map_or("", |a| a.name()).into(),
            probs: a.map_or(Vec::new(), |a| a.probs.clone()),
            value: a.map_or(0.0, |a| a.value),
            gesture_kind: g.map_or(0, |g| g.kind),
            gesture_source: if g.is_some() { self.args.gesture.clone() } else { String::new() },
            done,
            holding: holding.into(),
        };
        if let Err(e) = self.io.decision.publish(d) {
            say!("{}: {e:?}", self.io.names.decision);
        }
    }
}
