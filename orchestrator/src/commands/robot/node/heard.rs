//! What the node heard on its topics, and why it must hold still: the newest message of each
//! kind, colour and depth paired by stamp, and the one-line fault that stops the robot.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use super::topics::Io;
use crate::commands::robot::camera::PolicyView;
use crate::commands::robot::camera::Sampling;
use crate::commands::robot::dds::{self, drain, seconds};
use crate::commands::robot::drive::Pose2;
use crate::commands::robot::msgs::{CameraInfo, Gesture, Image, Text};
use crate::commands::robot::names::Resolved;
use crate::commands::robot::observation::Frame;
use crate::commands::robot::person::Person;
use farm::config::GestureSchedule;

/// Frames kept while waiting for their pair (colour and depth arrive apart), and depth images
/// kept after it for a tracker's skeletons, which come later (`--gesture skeleton`).
const KEEP: usize = 4;
const KEEP_DEPTH: usize = 16;

/// The newest of what the topics said, and when (wall clock) each was last heard.
#[derive(Default)]
pub(super) struct Heard {
    pub(super) info: Option<CameraInfo>,
    pub(super) sampling: Option<Result<Sampling, String>>,
    pub(super) colour: VecDeque<Image>,
    pub(super) depth: VecDeque<Image>,
    pub(super) paired_depth: VecDeque<Image>,
    pub(super) frame: Option<Frame>,
    /// The newest colour or depth image could not be read: why.
    pub(super) frame_problem: Option<String>,
    pub(super) odom: Option<(Pose2, f64, String)>,
    pub(super) gesture: Option<Gesture>,
    pub(super) clock: Option<f64>,
    pub(super) odom_at: Option<Instant>,
    pub(super) frame_at: Option<Instant>,
    /// A message of the wrong type on one of the topics, and when.
    pub(super) garbled: Option<(String, Instant)>,
}

/// What the topics' messages are judged against: the node's limits, and the time now.
pub(super) struct Watch {
    /// How long a topic may be silent (wall clock).
    pub(super) timeout: Duration,
    /// How old the newest frame may be (s, ROS time), and the time now.
    pub(super) max_age: f64,
    pub(super) now: f64,
    pub(super) episode: bool,
}

impl Heard {
    /// Reads every topic: whether odometry arrived (the control loop runs at its rate), and the
    /// goals. The gesture topic is read unless the node reads the person itself.
    pub(super) fn listen(&mut self, io: &Io, view: PolicyView, gesture_topic: bool) -> (bool, Vec<Text>) {
        let h = self;
        let mut garbled = Vec::new();
        let mut note = |what: &str, e: Option<String>| {
            if let Some(e) = e {
                garbled.push(dds::not_of_its_type(what, &e));
            }
        };
        if let Some(c) = &io.clock {
            let (m, e) = drain(c);
            note(&io.names.clock, e);
            if let Some(c) = m.last() {
                h.clock = Some(seconds(c.clock));
            }
        }
        let (infos, e) = drain(&io.info);
        note(&io.names.info, e);
        if let Some(info) = infos.last() {
            if h.sampling
                .as_ref()
                .is_none_or(|s| s.as_ref().map_or(true, |s| (s.width, s.height) != (info.width, info.height)))
            {
                h.sampling = Some(Sampling::new(info, view));
            }
            h.info = Some(info.clone());
        }
        let (odoms, e) = drain(&io.odom);
        note(&io.names.odom, e);
        let odom = !odoms.is_empty();
        if let Some(o) = odoms.last() {
            let (x, y, yaw) = o.pose.pose.to_planar();
            h.odom = Some((Pose2 { x, y, yaw }, seconds(o.header.stamp), o.header.frame_id.clone()));
            h.odom_at = Some(Instant::now());
        }
        let (goals, e) = drain(&io.goal);
        note(&io.names.goal, e);
        let (gestures, e) = drain(&io.gesture);
        note(&io.names.gesture, e);
        if let Some(g) = gestures.into_iter().last().filter(|_| gesture_topic) {
            h.gesture = Some(g);
        }
        let (colour, e) = drain(&io.colour);
        note(&io.names.colour, e);
        let (depth, e) = drain(&io.depth);
        note(&io.names.depth, e);
        h.colour.extend(colour);
        h.depth.extend(depth);
        if let Some(g) = garbled.into_iter().next() {
            h.garbled = Some((g, Instant::now()));
        }
        (odom, goals)
    }

    /// Samples the newest colour image that has its depth (same stamp) to the policy's view.
    /// The person, when the node reads them, sees each new frame.
    pub(super) fn pair_frames(&mut self, view: PolicyView, person: Option<(&mut Person, GestureSchedule)>) {
        let h = self;
        while h.colour.len() > KEEP {
            h.colour.pop_front();
        }
        while h.depth.len() > KEEP {
            h.depth.pop_front();
        }
        let Some(Ok(sampling)) = &h.sampling else { return };
        let pair = h
            .colour
            .iter()
            .rev()
            .find_map(|c| h.depth.iter().find(|d| d.header.stamp == c.header.stamp).map(|d| (c, d)));
        let Some((c, d)) = pair else { return };
        let stamp = seconds(c.header.stamp);
        if h.frame.as_ref().is_some_and(|f| f.stamp >= stamp) {
            return;
        }
        h.frame_at = Some(Instant::now());
        match Frame::sample(sampling, c, d, view.size) {
            Ok(f) => {
                h.frame = Some(f);
                h.frame_problem = None;
                if let Some((p, schedule)) = person {
                    let (info, odom) = (h.info.as_ref().expect("camera_info came"), h.odom.as_ref());
                    let (at, frame_id) = odom.map_or((Pose2::default(), ""), |o| (o.0, o.2.as_str()));
                    // a tracker's skeletons are seen as they come (`read_bodies`), not with the frame
                    let seen = if p.reads_frames() { p.see(c, d, info, at) } else { Ok(()) };
                    match seen {
                        Ok(()) => h.gesture = p.gesture(schedule, stamp, frame_id),
                        Err(e) => h.frame_problem = Some(format!("the landmark model: {e:#}")),
                    }
                }
            }
            Err(e) => h.frame_problem = Some(e),
        }
        h.colour.retain(|x| seconds(x.header.stamp) > stamp);
        while h.depth.front().is_some_and(|x| seconds(x.header.stamp) <= stamp) {
            h.paired_depth.extend(h.depth.pop_front());
        }
        while h.paired_depth.len() > KEEP_DEPTH {
            h.paired_depth.pop_front();
        }
    }

    /// The depth image stamped `stamp`, if it came and is still kept.
    pub(super) fn depth_at(&self, stamp: f64) -> Option<&Image> {
        self.paired_depth.iter().chain(&self.depth).find(|d| seconds(d.header.stamp) == stamp)
    }

    /// Why the robot must hold still now, if its inputs say so (the gesture aside).
    pub(super) fn problem(&self, n: &Resolved, w: &Watch) -> Option<String> {
        let (h, limit) = (self, w.timeout);
        let silent = |at: Option<Instant>| at.is_none_or(|t| t.elapsed() > limit);
        if let Some((g, _)) = h.garbled.as_ref().filter(|(_, at)| !silent(Some(*at))) {
            return Some(g.clone());
        }
        if silent(h.odom_at) {
            return Some(format!("no odometry on {} for {:.1} s", n.odom, limit.as_secs_f64()));
        }
        match &h.sampling {
            None => return Some(format!("no camera_info on {}", n.info)),
            Some(Err(e)) => return Some(format!("{}: {e}", n.info)),
            Some(Ok(_)) => {}
        }
        if silent(h.frame_at) {
            return Some(format!(
                "no colour image with its depth on {} and {} for {:.1} s",
                n.colour,
                n.depth,
                limit.as_secs_f64()
            ));
        }
        if let Some(p) = &h.frame_problem {
            return Some(p.clone());
        }
        let age = w.now - h.frame.as_ref().map_or(f64::NEG_INFINITY, |f| f.stamp);
        if w.episode && age > w.max_age {
            return Some(format!("the newest camera frame is {age:.2} s old (limit {} s)", w.max_age));
        }
        None
    }

    /// The gesture's problem, when the policy reads the person and nothing explains a silence.
    pub(super) fn gesture_problem(&self, n: &Resolved, w: &Watch) -> Option<String> {
        let h = self;
        let odom_frame = h.odom.as_ref().map(|o| o.2.as_str()).unwrap_or("");
        match &h.gesture {
            None => Some(format!("no gesture on {}", n.gesture)),
            Some(g) if w.now - seconds(g.header.stamp) > w.max_age.max(1.0) => {
                Some(format!("the newest gesture on {} is {:.2} s old", n.gesture, w.now - seconds(g.header.stamp)))
            }
            Some(g) if g.header.frame_id != odom_frame => Some(format!(
                "gesture: the person's pose is in frame `{}`; odometry's frame `{odom_frame}` expected",
                g.header.frame_id
            )),
            Some(_) => None,
        }
    }
}
