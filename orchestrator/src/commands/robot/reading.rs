//! How well the robot's camera read the person (`robot sim` against a node on `--gesture
//! camera`): the node's reading, published on `~/person` with its first decision, set against
//! the simulator's truth and the waves it saw against those shown. Written to each episode's
//! `camera.json`, so what the camera loses can be told apart: a person not found, misplaced, a
//! gesture fitted wrong, a wave missed.

use nalgebra::{Point3, Vector2};
use serde::Serialize;
use shm_schema::gesture_kind;

use worker::geometry::{angle_diff_deg, yaw_of};
use worker::gesture::{DEFAULT_RADIUS, INTERVENTION_NAMES, Motion, accuracy_with, line_errors};
use worker::humanoid::Humanoid;
use worker::program::Program;

use super::msgs::Gesture;

/// The person as the camera read them, against the truth: metres and degrees.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Reading {
    /// The node published a reading, and it held a gesture.
    pub heard: bool,
    pub read: bool,
    /// Where the person was read, how far from where they stand; how far their facing is off.
    pub place_error: Option<f32>,
    pub facing_error: Option<f32>,
    /// The person from where the robot starts: how far, how far off the camera's axis, how far
    /// turned from facing the robot.
    pub distance: f32,
    pub bearing: f32,
    pub turned: f32,
    /// The pointing arm (the one that moves most): GOND's clip's, the read clip's.
    pub arm: String,
    pub arm_read: Option<String>,
    /// How far the arm's shoulder→wrist line passes from the target over the hold (median):
    /// GOND's clip where the person stands, the read clip where they were read.
    pub arm_error: f32,
    pub arm_error_read: Option<f32>,
    /// GOND's gesture accuracy (rays within 0.5 m of the target), likewise.
    pub accuracy: f32,
    pub accuracy_read: Option<f32>,
    /// The program's intervention (GOND's 20; the node reads a wave only), and the decisions
    /// taken while the person showed it (waved, or what the intervention is), those with the person
    /// in the camera's frame (any of their pixels), those the node read as a wave, and those it
    /// read a wave that was not shown.
    pub intervention: String,
    pub waves: u32,
    pub waves_in_view: u32,
    pub waves_read: u32,
    pub false_waves: u32,
}

impl Reading {
    /// The truth of program `p` (GOND's clip `motion`, performed by `person`, and intervention
    /// number `intervention`) and the node's reading of it, if it published one.
    pub fn new(p: &Program, motion: &Motion, person: &Humanoid, intervention: u8, heard: Option<&Gesture>) -> Reading {
        let (human, target) = (Point3::from(p.human_pos), Point3::from(p.target_pos));
        let robot = Point3::from(p.robot_pos);
        let to_person = Vector2::new(human.x - robot.x, human.z - robot.z);
        let to_robot = -to_person;
        let truth = line_errors(person, motion, human, p.human_yaw, target);
        let mut r = Reading {
            heard: heard.is_some(),
            distance: to_person.norm(),
            bearing: angle_diff_deg(p.robot_yaw, yaw_of(to_person)).abs(),
            turned: angle_diff_deg(p.human_yaw, yaw_of(to_robot)).abs(),
            arm: format!("{:?}", truth.side),
            arm_error: truth.arm_deg,
            accuracy: accuracy_with(person, motion, human, p.human_yaw, target, DEFAULT_RADIUS),
            intervention: INTERVENTION_NAMES.get(intervention as usize).map_or("", |n| n).to_string(),
            ..Default::default()
        };
        let Some(g) = heard else { return r };
        // the odometry frame (x ahead, y left, yaw counter-clockwise, rad) on the floor
        let (x, y, yaw) = g.person.to_planar();
        let (at, yaw_deg) = (Point3::new(-y as f32, human.y, x as f32), -(yaw.to_degrees() as f32));
        r.place_error = Some(Vector2::new(at.x - human.x, at.z - human.z).norm());
        r.facing_error = Some(angle_diff_deg(p.human_yaw, yaw_deg).abs());
        if let Some(m) = Motion::from_flat(&g.muscles).filter(|_| g.kind == gesture_kind::REFERENCING) {
            let read = line_errors(person, &m, at, yaw_deg, target);
            r.read = true;
            r.arm_read = Some(format!("{:?}", read.side));
            r.arm_error_read = Some(read.arm_deg);
            r.accuracy_read = Some(accuracy_with(person, &m, at, yaw_deg, target, DEFAULT_RADIUS));
        }
        r
    }

    /// One decision: the gesture the person showed, the one the node gave its policy, and
    /// whether the person was in the frame.
    pub fn decided(&mut self, shown: u8, given: u8, in_view: bool) {
        let (shown, given) = (shown == gesture_kind::INTERVENTION, given == gesture_kind::INTERVENTION);
        self.waves += shown as u32;
        self.waves_in_view += (shown && in_view) as u32;
        self.waves_read += (shown && given) as u32;
        self.false_waves += (!shown && given) as u32;
    }
}
