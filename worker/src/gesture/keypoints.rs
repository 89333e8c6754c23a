//! A gesture as the robot's camera would see it (`model.gesture_input = "keypoints"`, beyond the
//! dissertation): ten body points per frame in the camera's frame, as a 3-D pose estimator on
//! the robot gives them. The muscles say where the arm points in the person's own frame, which a
//! policy can turn into a direction only by knowing the person's facing; these say it in the
//! robot's frame.
//!
//! The person performs the gesture all the while it is shown (§4.4.1: the referencing gesture
//! all episode); the robot sees its 100 frames from where it stands at each step, so the points
//! move with the robot as a tracked person would.

use nalgebra::Point3;

use super::{FRAMES, Motion};
use crate::camera::Camera;
use crate::humanoid::{Bone, Humanoid};

/// The body points, in the order they are written: head (eye height), hips, then per side
/// (left, right) the shoulder, elbow and wrist joints and the index fingertip.
pub const KEYPOINTS: usize = 10;

/// Values per frame: right, up and forward (metres) of each point.
pub const DIMS: usize = KEYPOINTS * 3;
const _: () = assert!(DIMS == shm_schema::GESTURE_KEYPOINT_DIMS);

/// Values per frame of the arms' rays (`model.gesture_input = "arm_rays"`).
pub const ARM_DIMS: usize = 8;
const _: () = assert!(ARM_DIMS == shm_schema::GESTURE_ARM_DIMS);

/// Index in [`points`] of each side's shoulder and wrist (left, right).
const ARMS: [(usize, usize); 2] = [(2, 4), (6, 8)];
const HIPS: usize = 1;

/// The body points of one pose, in the world.
fn points(pose: &crate::humanoid::SkeletonPose) -> [Point3<f32>; KEYPOINTS] {
    [
        pose.head_position(),
        pose.position(Bone::Hips),
        pose.position(Bone::LeftUpperArm),
        pose.position(Bone::LeftLowerArm),
        pose.position(Bone::LeftHand),
        pose.tip(Bone::LeftIndexDistal),
        pose.position(Bone::RightUpperArm),
        pose.position(Bone::RightLowerArm),
        pose.position(Bone::RightHand),
        pose.tip(Bone::RightIndexDistal),
    ]
}

/// Every frame's body points of `motion` performed by `h` standing at `root` facing `yaw_deg`.
pub fn world(h: &Humanoid, motion: &Motion, root: Point3<f32>, yaw_deg: f32) -> Vec<[Point3<f32>; KEYPOINTS]> {
    (0..FRAMES).map(|t| points(&h.pose(motion.frame(t), root, yaw_deg))).collect()
}

/// The points as `camera` sees them, frame-major into `out` (`FRAMES` rows of `row` values, the
/// first [`DIMS`] of each written, the rest zeroed).
pub fn write_seen(world: &[[Point3<f32>; KEYPOINTS]], camera: &Camera, row: usize, out: &mut [f32]) {
    write_rows(world, row, DIMS, out, |frame, dst| {
        for (p, xyz) in frame.iter().zip(dst.chunks_exact_mut(3)) {
            xyz.copy_from_slice(camera.to_eye(p).as_slice());
        }
    });
}

/// The arms' rays as `camera` sees them, frame-major into `out` (`FRAMES` rows of `row` values,
/// the first [`ARM_DIMS`] of each written, the rest zeroed): flat on the floor (right, forward),
/// the hips, then per arm (left, right) the unit direction from the shoulder to the wrist and
/// its length in metres (a zero direction where the two meet).
pub fn write_arm_rays(world: &[[Point3<f32>; KEYPOINTS]], camera: &Camera, row: usize, out: &mut [f32]) {
    let flat = |p: &Point3<f32>| {
        let e = camera.to_eye(p);
        nalgebra::Vector2::new(e.x, e.z)
    };
    write_rows(world, row, ARM_DIMS, out, |frame, dst| {
        let hips = flat(&frame[HIPS]);
        dst[..2].copy_from_slice(hips.as_slice());
        for ((shoulder, tip), ray) in ARMS.iter().zip(dst[2..].chunks_exact_mut(3)) {
            let arm = flat(&frame[*tip]) - flat(&frame[*shoulder]);
            let reach = arm.norm();
            let dir = if reach > 1e-6 { arm / reach } else { arm * 0.0 };
            ray.copy_from_slice(&[dir.x, dir.y, reach]);
        }
    });
}

/// Zeroes `out` (`FRAMES` rows of `row` values) and lets `fill` write the first `width` values
/// of each row from its frame's points.
fn write_rows(
    world: &[[Point3<f32>; KEYPOINTS]],
    row: usize,
    width: usize,
    out: &mut [f32],
    mut fill: impl FnMut(&[Point3<f32>; KEYPOINTS], &mut [f32]),
) {
    assert!(row >= width && out.len() == FRAMES * row && world.len() == FRAMES);
    out.fill(0.0);
    for (frame, dst) in world.iter().zip(out.chunks_exact_mut(row)) {
        fill(frame, &mut dst[..width]);
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use nalgebra::{Point3, Vector3};
    use proptest::prelude::*;

    use super::*;
    use crate::gesture::motion::{Metadata, read_csv};

    const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/gond-sample/2021-05-04_13-22-28_mocap");

    fn seen(world: &[[Point3<f32>; KEYPOINTS]], camera: &Camera) -> Vec<f32> {
        let mut out = vec![f32::NAN; FRAMES * DIMS];
        write_seen(world, camera, DIMS, &mut out);
        out
    }

    fn point(v: &[f32], frame: usize, k: usize) -> Vector3<f32> {
        let i = frame * DIMS + k * 3;
        Vector3::new(v[i], v[i + 1], v[i + 2])
    }

    /// The real recording's person, target, body points, and the frame where the right arm is
    /// raised highest (the peak of the pointing).
    struct Recording {
        human: Point3<f32>,
        target: Point3<f32>,
        world: Vec<[Point3<f32>; KEYPOINTS]>,
        peak: usize,
    }

    fn recording() -> Recording {
        let motion = read_csv(Path::new(&format!("{FIXTURES}.csv"))).unwrap();
        let meta = Metadata::load(Path::new(&format!("{FIXTURES}.json"))).unwrap();
        let (human, yaw) = (meta.human_position(), meta.human_yaw_deg());
        let arm_up = motion.muscle(48);
        let peak = (25..60).max_by(|&a, &b| arm_up[a].total_cmp(&arm_up[b])).unwrap();
        let world = world(Humanoid::standard(), &motion, human, yaw);
        Recording { human, target: human + meta.target_offset(), world, peak }
    }

    /// The real recording, seen by a robot standing anywhere: at the peak of the pointing, the
    /// right shoulder → wrist line, in the camera's frame, passes the target as the camera sees
    /// it within the recording's own aiming error (the evaluator's 5° line, plus the fingertip).
    #[test]
    fn the_recorded_pointing_aims_at_its_target_in_the_robots_frame() {
        let Recording { human, target, world: w, peak } = recording();
        proptest!(|(x in -4.0f32..4.0, z in -4.0f32..4.0, robot_yaw in -180.0f32..180.0)| {
            let camera = Camera::new(Point3::new(human.x + x, 0.6, human.z + z), robot_yaw);
            let v = seen(&w, &camera);
            let (shoulder, wrist) = (point(&v, peak, 6), point(&v, peak, 8));
            let to_target = camera.to_eye(&target) - shoulder;
            let angle = (wrist - shoulder).angle(&to_target).to_degrees();
            prop_assert!(angle < 6.0, "shoulder→wrist {angle:.1}° off the target");
            let tip = point(&v, peak, 9);
            prop_assert!((tip - wrist).norm() < 0.25 && (tip - shoulder).norm() > (wrist - shoulder).norm());
        });
    }

    /// The arms' rays of the real recording, seen from anywhere: the hips where the body points
    /// put them, and at the peak of the pointing the right arm's ray, flat on the floor, heads
    /// for the target from the shoulder (within the recording's aim) with the arm outstretched.
    #[test]
    fn the_right_arm_s_ray_heads_for_the_target() {
        let Recording { human, target, world: w, peak } = recording();
        proptest!(|(x in -4.0f32..4.0, z in -4.0f32..4.0, robot_yaw in -180.0f32..180.0)| {
            let camera = Camera::new(Point3::new(human.x + x, 0.6, human.z + z), robot_yaw);
            let mut v = vec![f32::NAN; FRAMES * 12];
            write_arm_rays(&w, &camera, 12, &mut v);
            let hips = camera.to_eye(&w[peak][HIPS]);
            let row = &v[peak * 12..(peak + 1) * 12];
            prop_assert!((row[0] - hips.x).abs() < 1e-5 && (row[1] - hips.z).abs() < 1e-5);
            prop_assert!(row[ARM_DIMS..].iter().all(|x| *x == 0.0), "the rest of the row is zero");
            let shoulder = camera.to_eye(&w[peak][6]);
            let to_target = camera.to_eye(&target) - shoulder;
            let to_target = nalgebra::Vector2::new(to_target.x, to_target.z);
            let ray = nalgebra::Vector2::new(row[5], row[6]);
            prop_assert!((ray.norm() - 1.0).abs() < 1e-4);
            let angle = ray.angle(&to_target).to_degrees();
            prop_assert!(angle < 5.0, "right arm's ray {angle:.1}° off the target");
            prop_assert!(row[7] > 0.3, "outstretched: {}", row[7]);
        });
    }

    /// A person standing 2 m straight ahead of the camera, facing it: head up, hips down,
    /// their right shoulder on the camera's left; points outside the 30 values are zero.
    #[test]
    fn a_person_ahead_is_ahead() {
        let h = Humanoid::standard();
        let w = world(h, &Motion::constant(&crate::gesture::STANDING), Point3::new(0.0, 0.0, 2.0), 180.0);
        let camera = Camera::new(Point3::new(0.0, 0.6, 0.0), 0.0);
        let mut out = vec![f32::NAN; FRAMES * 95];
        write_seen(&w, &camera, 95, &mut out);
        let row = |k: usize| Vector3::new(out[k * 3], out[k * 3 + 1], out[k * 3 + 2]);
        let (head, hips, right_shoulder) = (row(0), row(1), row(6));
        assert!((head.z - 2.0).abs() < 0.3 && head.y > 0.8 && head.x.abs() < 0.1, "head {head:?}");
        assert!(hips.y > 0.1 && hips.y < head.y, "hips {hips:?}");
        assert!(right_shoulder.x < -0.1, "facing the camera, the right shoulder is on its left: {right_shoulder:?}");
        assert!(out.chunks(95).all(|r| r[DIMS..].iter().all(|v| *v == 0.0)));
    }
}
