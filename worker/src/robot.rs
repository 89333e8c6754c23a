//! The robot: its pose, its four actions (§4.2) and where its camera is (§3.2.2).

use nalgebra::{Point2, Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::geometry::{heading, wrap_deg};
use crate::physics::Physics;
use farm::config::EnvConfig;
use shm_schema::action;

/// The four actions. The discriminant is the action index the policy outputs and the action
/// message carries (`shm_schema::action`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum Action {
    MoveAhead = action::MOVE_AHEAD,
    RotateLeft = action::ROTATE_LEFT,
    RotateRight = action::ROTATE_RIGHT,
    Stop = action::STOP,
}

impl Action {
    pub const COUNT: usize = action::COUNT;
    /// Every action, in the order of its index.
    pub const ALL: [Action; Action::COUNT] = [Action::MoveAhead, Action::RotateLeft, Action::RotateRight, Action::Stop];

    pub fn from_index(i: u8) -> Option<Action> {
        Action::ALL.get(i as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            Action::MoveAhead => "MoveAhead",
            Action::RotateLeft => "RotateLeft",
            Action::RotateRight => "RotateRight",
            Action::Stop => "Stop",
        }
    }
}

/// Position on the floor and yaw (degrees, clockwise from above).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotPose {
    pub x: f32,
    pub z: f32,
    pub yaw: f32,
}

impl RobotPose {
    pub fn xz(&self) -> Point2<f32> {
        Point2::new(self.x, self.z)
    }

    pub fn heading(&self) -> Vector2<f32> {
        heading(self.yaw)
    }

    pub fn camera(&self, cfg: &EnvConfig) -> Camera {
        Camera { position: Point3::new(self.x, cfg.camera_height, self.z), yaw_deg: self.yaw, pitch_deg: 0.0 }
    }
}

/// What an action did to the robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Motion {
    /// The robot changed position.
    pub moved: bool,
    /// A MoveAhead was blocked: the robot stayed where it was.
    pub collided: bool,
}

/// Applies one action. Rotations always succeed (the robot turns in place); MoveAhead moves
/// `move_step` metres along the heading unless the sweep hits something, in which case the
/// robot does not move at all and a collision is reported; Stop changes nothing.
pub fn apply(pose: &mut RobotPose, action: Action, cfg: &EnvConfig, physics: &Physics) -> Motion {
    match action {
        Action::RotateLeft => {
            pose.yaw = snap(wrap_deg(pose.yaw - cfg.turn_deg));
            Motion { moved: false, collided: false }
        }
        Action::RotateRight => {
            pose.yaw = snap(wrap_deg(pose.yaw + cfg.turn_deg));
            Motion { moved: false, collided: false }
        }
        Action::MoveAhead => {
            let delta = pose.heading() * cfg.move_step;
            if physics.move_is_free(pose.xz(), delta) {
                pose.x += delta.x;
                pose.z += delta.y;
                Motion { moved: true, collided: false }
            } else {
                Motion { moved: false, collided: true }
            }
        }
        Action::Stop => Motion { moved: false, collided: false },
    }
}

/// Rounds a yaw to 1e-3° so that many turns never drift (24 turns of 15° give exactly 0 again).
fn snap(yaw: f32) -> f32 {
    let s = (yaw * 1000.0).round() / 1000.0;
    if s >= 360.0 { s - 360.0 } else { s }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Part, Shape, angle_diff_deg};
    use crate::physics::RobotBody;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    fn room() -> Physics {
        let wall = Part::new(Shape::Box, Point3::new(0.0, 1.0, 3.0), Vector3::new(5.0, 1.0, 0.05), [0.5; 3]).with_id(9);
        Physics::new(&[wall], RobotBody::default())
    }

    proptest! {
        #[test]
        fn a_turn_is_exactly_the_turn_angle(yaw in 0.0f32..360.0, right in any::<bool>()) {
            let cfg = EnvConfig::default();
            let phys = room();
            let mut p = RobotPose { x: 0.0, z: 0.0, yaw: snap(yaw) };
            let before = p;
            let a = if right { Action::RotateRight } else { Action::RotateLeft };
            let m = apply(&mut p, a, &cfg, &phys);
            prop_assert!(!m.moved && !m.collided);
            let d = angle_diff_deg(before.yaw, p.yaw);
            prop_assert!((d.abs() - 15.0).abs() < 2e-3, "turned {}", d);
            prop_assert_eq!(d > 0.0, right);
            prop_assert_eq!((p.x, p.z), (before.x, before.z));
        }

        #[test]
        fn a_free_move_is_a_quarter_metre_along_the_heading(k in 0u32..24) {
            let cfg = EnvConfig::default();
            let phys = room();
            let mut p = RobotPose { x: 0.0, z: 0.0, yaw: k as f32 * 15.0 };
            let m = apply(&mut p, Action::MoveAhead, &cfg, &phys);
            prop_assert!(m.moved && !m.collided);
            let h = heading(k as f32 * 15.0);
            prop_assert!((p.x - 0.25 * h.x).abs() < 1e-5 && (p.z - 0.25 * h.y).abs() < 1e-5);
        }

        #[test]
        fn a_blocked_move_does_not_move(x in -2.0f32..2.0, yaw in -40.0f32..40.0) {
            let cfg = EnvConfig::default();
            let phys = room();
            // the capsule's front is 0.05 m from the wall: any forward-ish step hits it
            let mut p = RobotPose { x, z: 3.0 - 0.05 - 0.3 - 0.05, yaw: wrap_deg(yaw) };
            let before = p;
            let m = apply(&mut p, Action::MoveAhead, &cfg, &phys);
            prop_assert!(!m.moved && m.collided);
            prop_assert_eq!(p, before);
        }
    }

    #[test]
    fn indices_are_the_wire_indices() {
        for (i, a) in Action::ALL.into_iter().enumerate() {
            assert_eq!(a as usize, i, "{a:?} is not at its index in Action::ALL");
            assert_eq!(Action::from_index(a as u8), Some(a));
        }
        assert_eq!(Action::from_index(action::COUNT as u8), None);
        assert_eq!(Action::from_index(action::NONE), None);
    }

    #[test]
    fn twenty_four_turns_come_back() {
        let cfg = EnvConfig::default();
        let phys = room();
        for a in [Action::RotateLeft, Action::RotateRight] {
            let mut p = RobotPose { x: 0.5, z: -0.25, yaw: 30.0 };
            for _ in 0..24 {
                apply(&mut p, a, &cfg, &phys);
            }
            assert_eq!(p, RobotPose { x: 0.5, z: -0.25, yaw: 30.0 });
        }
    }

    #[test]
    fn stop_changes_nothing() {
        let cfg = EnvConfig::default();
        let phys = room();
        let mut p = RobotPose { x: 0.5, z: -0.25, yaw: 30.0 };
        let m = apply(&mut p, Action::Stop, &cfg, &phys);
        assert_eq!(m, Motion { moved: false, collided: false });
        assert_eq!(p, RobotPose { x: 0.5, z: -0.25, yaw: 30.0 });
    }
}
