//! The gesture schedule: what the robot perceives at a step, as a `shm_schema::gesture_kind`.

use nalgebra::{Point3, Vector2};

use shm_schema::gesture_kind::{INTERVENTION, NONE, REFERENCING};

use crate::geometry::{angle_diff_deg, yaw_of};
use crate::robot::RobotPose;
use farm::config::GestureSchedule;

/// What the robot perceives at a step, by schedule (§4.4.1): referencing all episode; an
/// intervention while the heading is more than `angle` degrees from the bearing to the
/// target (the true angle, not the original code's atan2(dz, dx) against Unity's yaw);
/// or both (intervention when facing away, referencing otherwise).
pub fn gesture_kind(schedule: GestureSchedule, pose: &RobotPose, target: Point3<f32>, angle: f32) -> u8 {
    shown(schedule, facing_away(pose, target, angle))
}

/// The angle rule: the heading more than `angle` degrees from the bearing to the target.
pub fn facing_away(pose: &RobotPose, target: Point3<f32>, angle: f32) -> bool {
    let to = Vector2::new(target.x - pose.x, target.z - pose.z);
    to.norm() > 1e-6 && angle_diff_deg(pose.yaw, yaw_of(to)).abs() > angle
}

/// What the schedule shows when the intervention is called for (`away`) or not: by the angle
/// rule in training, by a person watching in `orchestrator live`.
pub fn shown(schedule: GestureSchedule, away: bool) -> u8 {
    match schedule {
        GestureSchedule::None => NONE,
        GestureSchedule::Referencing => REFERENCING,
        GestureSchedule::Intervention => {
            if away {
                INTERVENTION
            } else {
                NONE
            }
        }
        GestureSchedule::Both => {
            if away {
                INTERVENTION
            } else {
                REFERENCING
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intervention_shows_only_when_facing_away() {
        let target = Point3::new(0.0, 0.5, 3.0); // straight ahead of yaw 0
        let at = |yaw: f32| RobotPose { x: 0.0, z: 0.0, yaw };
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(0.0), target, 90.0), NONE);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(90.0), target, 90.0), NONE);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(105.0), target, 90.0), INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Intervention, &at(255.0), target, 90.0), INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Both, &at(180.0), target, 90.0), INTERVENTION);
        assert_eq!(gesture_kind(GestureSchedule::Both, &at(30.0), target, 90.0), REFERENCING);
        assert_eq!(gesture_kind(GestureSchedule::Referencing, &at(180.0), target, 90.0), REFERENCING);
        assert_eq!(gesture_kind(GestureSchedule::None, &at(180.0), target, 90.0), NONE);
    }
}
