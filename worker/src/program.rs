//! A program (§3.3.2, T3.1): (scene, target type, target instance and position, person
//! position and yaw, robot position and yaw, referencing motion). Episodes run programs.

use bytemuck::{Pod, Zeroable};
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

use crate::robot::RobotPose;
use crate::scene::{Category, SceneId, SceneType};

/// Which hand a referencing gesture uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Hand {
    Left,
    Right,
}

/// A program as stored in the dataset index (`<split>.json`) and in binary records.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Program {
    /// Index within its split.
    pub id: u64,
    /// "FloorPlan201"...
    pub scene: String,
    pub scene_type: SceneType,
    pub target: Category,
    /// Index of the target instance among the scene's objects.
    pub target_object: usize,
    /// Target centre (metres).
    pub target_pos: [f32; 3],
    /// Instances of the target category in the room.
    pub instances: u32,
    /// Where the person stands (feet, metres) and faces (degrees).
    pub human_pos: [f32; 3],
    pub human_yaw: f32,
    /// Robot start.
    pub robot_pos: [f32; 3],
    pub robot_yaw: f32,
    /// Geodesic distance from the robot start to the success region (metres).
    pub geodesic: f32,
    /// Geodesic distance from the robot start to the target's centre: to a cell of the success
    /// region, then straight (metres; Fig. 3.12a, `dataset::starts::target_field`).
    pub target_geodesic: f32,
    /// Whether a Stop at the start already succeeds (within reach, target in view).
    pub starts_successful: bool,
    /// Euclidean distance between robot start and person (Fig. 3.12b).
    pub robot_human_distance: f32,
    /// Gesture accuracy of the referencing motion toward the target.
    pub gesture_accuracy: f32,
    pub hand: Hand,
    /// Referencing style index (index finger, open palm, two fingers...).
    pub style: u8,
    /// Seed of everything random about this program (motion, the person's looks).
    pub seed: u64,
}

impl Program {
    pub fn scene_id(&self) -> SceneId {
        SceneId::parse(&self.scene).expect("programs name valid rooms")
    }

    pub fn robot_start(&self) -> RobotPose {
        RobotPose { x: self.robot_pos[0], z: self.robot_pos[2], yaw: self.robot_yaw }
    }

    pub fn human_xz(&self) -> Point2<f32> {
        Point2::new(self.human_pos[0], self.human_pos[2])
    }

    pub fn target_center(&self) -> Point3<f32> {
        Point3::from(self.target_pos)
    }

    /// The person relative to a robot at `pose`: right (m), forward (m), their yaw less the
    /// robot's / 360 (`model.person_pose`).
    pub fn person_relative(&self, pose: &RobotPose) -> [f32; 3] {
        let [right, forward] = robot_frame(pose, self.human_xz() - pose.xz());
        [right, forward, crate::geometry::angle_diff_deg(pose.yaw, self.human_yaw) / 360.0]
    }

    /// Fixed-size binary form (see `dataset`).
    pub fn to_record(&self) -> ProgramRecord {
        ProgramRecord {
            seed: self.seed,
            floorplan: self.scene_id().floorplan() as u16,
            target_object: self.target_object as u16,
            target: self.target.target_index().expect("targets have an index") as u16,
            instances: self.instances as u16,
            target_pos: self.target_pos,
            human_pos: self.human_pos,
            human_yaw: self.human_yaw,
            robot_pos: self.robot_pos,
            robot_yaw: self.robot_yaw,
            geodesic: self.geodesic,
            robot_human_distance: self.robot_human_distance,
            gesture_accuracy: self.gesture_accuracy,
            hand: matches!(self.hand, Hand::Right) as u8,
            style: self.style,
            starts_successful: self.starts_successful as u8,
            _pad: 0,
            target_geodesic: self.target_geodesic,
        }
    }

    /// Inverse of `to_record`; None if the record names no valid room or category.
    pub fn from_record(id: u64, r: &ProgramRecord) -> Option<Program> {
        let sid = SceneId::parse(&r.floorplan.to_string())?;
        let target = Category::from_target_index(r.target as u32)?;
        Some(Program {
            id,
            scene: sid.name(),
            scene_type: sid.scene_type,
            target,
            target_object: r.target_object as usize,
            target_pos: r.target_pos,
            instances: r.instances as u32,
            human_pos: r.human_pos,
            human_yaw: r.human_yaw,
            robot_pos: r.robot_pos,
            robot_yaw: r.robot_yaw,
            geodesic: r.geodesic,
            target_geodesic: r.target_geodesic,
            starts_successful: r.starts_successful == 1,
            robot_human_distance: r.robot_human_distance,
            gesture_accuracy: r.gesture_accuracy,
            hand: if r.hand == 1 { Hand::Right } else { Hand::Left },
            style: r.style,
            seed: r.seed,
        })
    }
}

/// A program's binary record: little-endian, 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ProgramRecord {
    pub seed: u64,
    pub floorplan: u16,
    pub target_object: u16,
    /// Target category index (`Category::target_index`).
    pub target: u16,
    pub instances: u16,
    pub target_pos: [f32; 3],
    pub human_pos: [f32; 3],
    pub human_yaw: f32,
    pub robot_pos: [f32; 3],
    pub robot_yaw: f32,
    pub geodesic: f32,
    pub robot_human_distance: f32,
    pub gesture_accuracy: f32,
    /// 0 left, 1 right.
    pub hand: u8,
    pub style: u8,
    /// 1 when a Stop at the start already succeeds.
    pub starts_successful: u8,
    pub _pad: u8,
    pub target_geodesic: f32,
}

const _: () = assert!(std::mem::size_of::<ProgramRecord>() == 80);

/// A world offset `d` (x, z) as a robot at `pose` sees it: right, forward (metres).
fn robot_frame(pose: &RobotPose, d: nalgebra::Vector2<f32>) -> [f32; 2] {
    let h = pose.heading();
    [d.dot(&nalgebra::Vector2::new(h.y, -h.x)), d.dot(&h)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Program {
        Program {
            id: 7,
            scene: "FloorPlan305".into(),
            scene_type: SceneType::Bedroom,
            target: Category::Laptop,
            target_object: 12,
            target_pos: [1.0, 0.8, -0.5],
            instances: 2,
            human_pos: [0.0, 0.0, 1.0],
            human_yaw: 200.0,
            robot_pos: [-1.25, 0.0, 0.5],
            robot_yaw: 45.0,
            geodesic: 2.5,
            target_geodesic: 3.1,
            starts_successful: true,
            robot_human_distance: 1.7,
            gesture_accuracy: 0.6,
            hand: Hand::Left,
            style: 2,
            seed: 99,
        }
    }

    #[test]
    fn record_round_trip() {
        let p = sample();
        assert_eq!(std::mem::size_of::<ProgramRecord>(), 80);
        assert_eq!(Program::from_record(7, &p.to_record()).unwrap(), p);
    }
}
