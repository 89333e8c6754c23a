//! Gesture accuracy, the original evaluator's measure: the fraction of the 100 frames in which a
//! ray from the head (along the face) or from a hand or distal finger bone (along the bone)
//! passes through a sphere around the target.
//!
//! The evaluator replayed the motion on the avatar and cast `Physics.Raycast` from the bones
//! `Head` (its forward axis), `LeftHand`/`RightHand` and the ten `*Distal` finger bones (their
//! right axis, along the bone) against a unit-scale primitive sphere at the target: radius
//! 0.5 m, which is our [`DEFAULT_RADIUS`]. A frame counts when any ray hits. (Its sphere also
//! carried a unit box collider; the sphere is the documented target.)
//!
//! [`line_errors`] measures how a person aims rather than whether a ray hits: the angle between
//! the target and the pointing arm's shoulder→wrist line, and its forearm's elbow→wrist line,
//! over the frames the arm is held out. People aim with the arm (the GOND recording holds the
//! wrist ≈2° off its shoulder→target line with the forearm ≈40° above it), so the two differ.

use nalgebra::Point3;

use super::{FRAMES, Motion};
use crate::humanoid::{Bone, Humanoid, Side, SkeletonPose};

/// Radius of the target sphere (m): the evaluator's unit-scale sphere.
pub const DEFAULT_RADIUS: f32 = 0.5;

/// The bones whose rays are cast, as in the original evaluator.
pub const POINTING_BONES: [Bone; 13] = [
    Bone::Head,
    Bone::LeftHand,
    Bone::RightHand,
    Bone::LeftThumbDistal,
    Bone::RightThumbDistal,
    Bone::LeftIndexDistal,
    Bone::RightIndexDistal,
    Bone::LeftMiddleDistal,
    Bone::RightMiddleDistal,
    Bone::LeftRingDistal,
    Bone::RightRingDistal,
    Bone::LeftLittleDistal,
    Bone::RightLittleDistal,
];

/// Whether the ray from `origin` along unit `dir` passes within `radius` of `center` (a ray,
/// not a line: points behind the origin do not count; an origin inside the sphere does).
pub fn ray_hits_sphere(origin: Point3<f32>, dir: nalgebra::Vector3<f32>, center: Point3<f32>, radius: f32) -> bool {
    let oc = center - origin;
    let t = oc.dot(&dir).max(0.0);
    (oc - dir * t).norm_squared() <= radius * radius
}

/// Whether a pose refers to the target: any pointing bone's ray hits the sphere.
pub fn pose_refers_to(pose: &SkeletonPose, target: Point3<f32>, radius: f32) -> bool {
    POINTING_BONES.iter().any(|&b| {
        let (o, d) = pose.ray(b);
        ray_hits_sphere(o, d, target, radius)
    })
}

/// Per frame, whether the pose refers to the target.
pub fn hits(
    h: &Humanoid,
    motion: &Motion,
    human_pos: Point3<f32>,
    human_yaw: f32,
    target: Point3<f32>,
    radius: f32,
) -> [bool; FRAMES] {
    std::array::from_fn(|t| pose_refers_to(&h.pose(motion.frame(t), human_pos, human_yaw), target, radius))
}

/// Gesture accuracy of `motion` performed by `h` standing at `human_pos` (floor point) facing
/// `human_yaw` (degrees) towards `target`.
pub fn accuracy_with(
    h: &Humanoid,
    motion: &Motion,
    human_pos: Point3<f32>,
    human_yaw: f32,
    target: Point3<f32>,
    radius: f32,
) -> f32 {
    hits(h, motion, human_pos, human_yaw, target, radius).iter().filter(|&&x| x).count() as f32 / FRAMES as f32
}

/// [`accuracy_with`] on the default 1.70 m person.
pub fn accuracy(motion: &Motion, human_pos: Point3<f32>, human_yaw: f32, target: Point3<f32>, radius: f32) -> f32 {
    accuracy_with(Humanoid::standard(), motion, human_pos, human_yaw, target, radius)
}

/// How far the pointing arm's lines pass from the target while it is held out (degrees,
/// medians over the hold).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineErrors {
    /// The arm that moved most.
    pub side: Side,
    /// Shoulder (upper-arm joint) → wrist.
    pub arm_deg: f32,
    /// Elbow → wrist.
    pub forearm_deg: f32,
    /// Frames counted as the hold: the wrist at least 80% of its largest distance from where
    /// it started.
    pub hold_frames: usize,
}

/// [`LineErrors`] of `motion` performed by `h` at `human_pos` facing `human_yaw` towards `target`.
pub fn line_errors(
    h: &Humanoid,
    motion: &Motion,
    human_pos: Point3<f32>,
    human_yaw: f32,
    target: Point3<f32>,
) -> LineErrors {
    let poses: Vec<SkeletonPose> = (0..FRAMES).map(|t| h.pose(motion.frame(t), human_pos, human_yaw)).collect();
    let travel = |side: Side| -> Vec<f32> {
        let w0 = poses[0].position(Bone::hand(side));
        poses.iter().map(|p| (p.position(Bone::hand(side)) - w0).norm()).collect()
    };
    let (right, left) = (travel(Side::Right), travel(Side::Left));
    let top = |v: &[f32]| v.iter().cloned().fold(0.0f32, f32::max);
    let (side, moved) = if top(&right) >= top(&left) { (Side::Right, right) } else { (Side::Left, left) };
    let far = top(&moved);
    let angle = |from: Point3<f32>, to: Point3<f32>| {
        let (d, t) = ((to - from).normalize(), (target - from).normalize());
        d.dot(&t).clamp(-1.0, 1.0).acos().to_degrees()
    };
    let (mut arm, mut forearm) = (Vec::new(), Vec::new());
    for (p, &m) in poses.iter().zip(&moved) {
        if m >= 0.8 * far {
            let (shoulder, elbow, wrist) =
                (p.position(Bone::upper_arm(side)), p.position(Bone::lower_arm(side)), p.position(Bone::hand(side)));
            arm.push(angle(shoulder, wrist));
            forearm.push(angle(elbow, wrist));
        }
    }
    LineErrors { side, arm_deg: median(&mut arm), forearm_deg: median(&mut forearm), hold_frames: arm.len() }
}

fn median(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use nalgebra::{Point3, Vector3};

    use super::*;
    use crate::gesture::motion::{Metadata, read_csv};

    const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/gond-sample/2021-05-04_13-22-28_mocap");

    #[test]
    fn rays_are_rays() {
        let o = Point3::origin();
        let d = Vector3::z();
        assert!(ray_hits_sphere(o, d, Point3::new(0.4, 0.0, 5.0), 0.5));
        assert!(!ray_hits_sphere(o, d, Point3::new(0.6, 0.0, 5.0), 0.5));
        assert!(!ray_hits_sphere(o, d, Point3::new(0.0, 0.0, -5.0), 0.5), "behind the origin");
        assert!(ray_hits_sphere(o, d, Point3::new(0.0, 0.3, -0.1), 0.5), "origin inside");
    }

    /// The real recording refers to its own target far more than to the same target mirrored
    /// through the person (behind them), and its right arm rises towards the hold.
    #[test]
    fn gond_sample_points_at_its_target() {
        let motion = read_csv(Path::new(&format!("{FIXTURES}.csv"))).unwrap();
        let meta = Metadata::load(Path::new(&format!("{FIXTURES}.json"))).unwrap();
        let arm_up = motion.muscle(48);
        let start: f32 = arm_up[..10].iter().sum::<f32>() / 10.0;
        let peak = arm_up[25..50].iter().cloned().fold(f32::MIN, f32::max);
        assert!(peak > start + 0.5, "Right Arm Down-Up rises from {start} to {peak}");
        assert!(arm_up[..20].windows(2).all(|w| (w[1] - w[0]).abs() < 0.02), "idle lead-in");

        // As the evaluator replayed it: the person at humanPos×10, yaw humanRot×360, the target
        // at humanPos×10 + targetToHuman×10.
        let human = meta.human_position();
        let yaw = meta.human_yaw_deg();
        let target = human + meta.target_offset();
        let mirrored = human - meta.target_offset() + Vector3::new(0.0, 2.0 * meta.target_offset().y, 0.0);
        let own = accuracy(&motion, human, yaw, target, DEFAULT_RADIUS);
        let other = accuracy(&motion, human, yaw, mirrored, DEFAULT_RADIUS);
        eprintln!("GOND sample accuracy: own target {own:.2}, mirrored target {other:.2}");
        assert!(own >= 0.8 && other <= 0.1, "own {own}, mirrored {other}");
        // The person aims with the arm: the wrist on the shoulder→target line, the bent forearm
        // well above it.
        let e = line_errors(Humanoid::standard(), &motion, human, yaw, target);
        eprintln!("GOND sample lines: {e:?}");
        assert_eq!(e.side, Side::Right);
        assert!(e.arm_deg < 5.0, "shoulder→wrist line {:.1}° off the target", e.arm_deg);
        assert!((30.0..55.0).contains(&e.forearm_deg), "forearm line {:.1}° off the target", e.forearm_deg);
        // It replays: every frame poses to finite bones with the feet on the floor.
        let h = Humanoid::default();
        for t in 0..FRAMES {
            let p = h.pose(motion.frame(t), human, yaw);
            assert!(p.position(Bone::Head).coords.iter().all(|v| v.is_finite()));
            assert!(p.position(Bone::Head).y > 1.4 && p.position(Bone::Hips).y > 0.85);
        }
    }
}
