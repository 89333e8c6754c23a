//! Building blocks shared by the gesture synthesizers: the natural standing pose, hand shapes,
//! timing curves, smooth noise for idling and tremor, and a small least-squares solver that
//! finds muscle values for geometric goals (a wrist position, a palm direction, a ray through
//! a point).

use nalgebra::{DMatrix, DVector, Point3, Vector3};
use rand::Rng;

use super::FPS;
use crate::humanoid::muscles::idx;
use crate::humanoid::{Bone, MUSCLES, Side, Skeleton, muscle_value};

/// Natural standing, arms hanging at the sides: the recorded person's idle pose (GOND sample,
/// first frame), made symmetric.
pub const STANDING: [f32; MUSCLES] = {
    let mut m = [0.0f32; MUSCLES];
    m[idx::SPINE_FRONT_BACK] = -0.05;
    m[idx::NECK_NOD] = 0.02;
    m[idx::HEAD_NOD] = 0.03;
    m[idx::JAW_CLOSE] = 0.25;
    let leg = [0.6, 0.1, -0.1, 0.93, 0.04, 0.0, -0.15, 0.0];
    let arm = [0.0, 0.0, -0.68, 0.13, -0.25, 0.77, -0.06, 0.0, 0.0];
    let mut i = 0;
    while i < 8 {
        m[idx::LEFT_LEG + i] = leg[i];
        m[idx::RIGHT_LEG + i] = leg[i];
        i += 1;
    }
    let mut i = 0;
    while i < 9 {
        m[idx::LEFT_ARM + i] = arm[i];
        m[idx::RIGHT_ARM + i] = arm[i];
        i += 1;
    }
    let mut i = 0;
    while i < 20 {
        m[idx::LEFT_FINGERS + i] = RELAXED[i];
        m[idx::RIGHT_FINGERS + i] = RELAXED[i];
        i += 1;
    }
    m
};

/// Finger muscles of one hand (thumb, index, middle, ring, little × 1 Stretched, Spread,
/// 2 Stretched, 3 Stretched).
pub type HandPose = [f32; 20];

pub const RELAXED: HandPose =
    [-0.75, 0.31, 0.31, 0.64, 0.55, -0.3, 0.65, 0.7, 0.52, -0.4, 0.62, 0.7, 0.5, -0.05, 0.6, 0.7, 0.48, 0.2, 0.6, 0.7];
/// Index finger out, the others curled, thumb over them.
pub const INDEX_POINT: HandPose = [
    -0.9, -0.6, -0.4, 0.0, 0.95, 0.0, 0.95, 0.9, -0.9, 0.0, -0.95, -0.6, -0.95, 0.0, -0.95, -0.6, -0.95, 0.1, -0.95,
    -0.6,
];
/// Index and middle finger out in a slight V.
pub const TWO_FINGER: HandPose = [
    -0.9, -0.6, -0.4, 0.0, 0.95, 0.3, 0.95, 0.9, 0.95, -0.5, 0.95, 0.9, -0.95, 0.0, -0.95, -0.6, -0.95, 0.1, -0.95,
    -0.6,
];
/// Open hand, fingers loosely apart.
pub const OPEN: HandPose =
    [0.3, 0.5, 0.6, 0.7, 0.9, 0.1, 0.9, 0.85, 0.9, 0.0, 0.9, 0.85, 0.88, 0.0, 0.88, 0.85, 0.85, 0.3, 0.85, 0.8];
/// Flat hand, fingers together (a "stop" palm).
pub const FLAT: HandPose =
    [0.5, -0.3, 0.8, 0.8, 0.95, -0.3, 0.95, 0.9, 0.95, -0.3, 0.95, 0.9, 0.95, 0.3, 0.95, 0.9, 0.95, 0.2, 0.95, 0.9];
/// Closed fist.
pub const FIST: HandPose = [
    -0.8, -0.5, -0.5, -0.6, -1.0, 0.0, -1.0, -0.8, -1.0, 0.0, -1.0, -0.8, -1.0, 0.0, -1.0, -0.8, -1.0, 0.0, -1.0, -0.8,
];

/// Writes a hand shape into a pose, blended by `w` (0: keep, 1: the shape).
pub fn blend_hand(pose: &mut [f32; MUSCLES], side: Side, shape: &HandPose, w: f32) {
    let b = side.finger_muscles();
    for (i, s) in shape.iter().enumerate() {
        pose[b + i] += (s - pose[b + i]) * w;
    }
}

/// Keeps every muscle inside its range.
pub fn clamp_pose(m: &mut [f32; MUSCLES]) {
    for v in m.iter_mut() {
        *v = v.clamp(-1.0, 1.0);
    }
}

/// Minimum-jerk ease from 0 to 1 (the velocity profile of human reaching).
pub fn min_jerk(t: f32) -> f32 {
    let t = t.clamp(0.0, 1.0);
    t * t * t * (10.0 + t * (-15.0 + 6.0 * t))
}

/// Rises over `[a, a + rise]`, holds, falls over `[b, b + fall]` (frames; min-jerk edges; a
/// zero-length edge is a step).
pub fn envelope(frame: f32, a: f32, rise: f32, b: f32, fall: f32) -> f32 {
    let edge = |x: f32, len: f32| {
        if len > 0.0 {
            min_jerk(x / len)
        } else if x >= 0.0 {
            1.0
        } else {
            0.0
        }
    };
    if frame < b { edge(frame - a, rise) } else { 1.0 - edge(frame - b, fall) }
}

/// Smooth random motion: a sum of a few sinusoids with drawn frequencies and phases.
#[derive(Clone, Copy, Debug)]
pub struct Wobble {
    parts: [(f32, f32, f32); 3],
}

impl Wobble {
    /// Amplitude `amp` (about the peak), frequencies around `hz`.
    pub fn new(r: &mut impl Rng, amp: f32, hz: f32) -> Wobble {
        let mut parts = [(0.0, 0.0, 0.0); 3];
        for (k, p) in parts.iter_mut().enumerate() {
            let f = hz * r.random_range(0.6..1.5) * (1.0 + 0.7 * k as f32);
            let a = amp / (1.0 + k as f32) * r.random_range(0.5..1.0) * 0.6;
            *p = (a, std::f32::consts::TAU * f / FPS, r.random_range(0.0..std::f32::consts::TAU));
        }
        Wobble { parts }
    }

    pub fn at(&self, frame: f32) -> f32 {
        self.parts.iter().map(|(a, w, p)| a * (w * frame + p).sin()).sum()
    }
}

/// The small motions of someone standing still: breathing, sway, head and arm drift.
#[derive(Clone, Copy, Debug)]
pub struct Idle {
    breath: (f32, f32, f32),
    channels: [(usize, Wobble); 10],
}

impl Idle {
    pub fn new(r: &mut impl Rng) -> Idle {
        let breath = (
            r.random_range(0.008..0.02),
            std::f32::consts::TAU * r.random_range(0.2..0.33) / FPS,
            r.random_range(0.0..6.3),
        );
        let mut ch = |i: usize, amp: f32, hz: f32| (i, Wobble::new(r, amp, hz));
        Idle {
            breath,
            channels: [
                ch(idx::SPINE_LEFT_RIGHT, 0.02, 0.2),
                ch(idx::SPINE_FRONT_BACK, 0.015, 0.15),
                ch(idx::SPINE_TWIST, 0.02, 0.15),
                ch(idx::NECK_NOD, 0.03, 0.3),
                ch(idx::HEAD_TURN, 0.04, 0.25),
                ch(idx::HEAD_TILT, 0.02, 0.2),
                ch(idx::LEFT_ARM + idx::ARM_FRONT_BACK, 0.02, 0.3),
                ch(idx::RIGHT_ARM + idx::ARM_FRONT_BACK, 0.02, 0.3),
                ch(idx::LEFT_ARM + idx::FOREARM_STRETCH, 0.03, 0.25),
                ch(idx::RIGHT_ARM + idx::FOREARM_STRETCH, 0.03, 0.25),
            ],
        }
    }

    /// A fixed idle for motions without a seed.
    pub fn fixed() -> Idle {
        let mut r = farm::seed::rng(0, &[0x1D1E]);
        Idle::new(&mut r)
    }

    pub fn apply(&self, pose: &mut [f32; MUSCLES], frame: f32) {
        let (a, w, p) = self.breath;
        let b = a * (w * frame + p).sin();
        pose[idx::CHEST_FRONT_BACK] += b;
        pose[idx::UPPER_CHEST_FRONT_BACK] += 0.5 * b;
        pose[idx::LEFT_ARM + idx::SHOULDER_DOWN_UP] += 0.5 * b;
        pose[idx::RIGHT_ARM + idx::SHOULDER_DOWN_UP] += 0.5 * b;
        for (i, w) in &self.channels {
            pose[*i] += w.at(frame);
        }
    }
}

/// What one arm pose should achieve. Points and directions are in the hips frame: hips at the
/// origin, x the person's right, y up, z forward.
#[derive(Clone, Copy, Debug, Default)]
pub struct ArmGoal {
    /// Where the wrist should be.
    pub wrist: Option<Point3<f32>>,
    /// Direction of the hand (wrist towards the knuckles).
    pub hand_dir: Option<Vector3<f32>>,
    /// Outward normal of the palm.
    pub palm: Option<Vector3<f32>>,
    /// A bone whose ray should pass through a point.
    pub ray: Option<(Bone, Point3<f32>)>,
}

/// The arm muscles a solver may move: shoulder, upper arm, forearm, hand.
pub fn arm_params(side: Side) -> [usize; 9] {
    std::array::from_fn(|k| side.arm_muscles() + k)
}

/// Adjusts `params` of `pose` so that `side`'s arm meets `goal` as well as it can, staying near
/// the starting values (weights `stay` per parameter) where the goal leaves freedom.
pub fn solve_arm(
    sk: &Skeleton,
    pose: &mut [f32; MUSCLES],
    side: Side,
    goal: &ArmGoal,
    params: &[usize],
    stay: &[f32],
    iters: usize,
) {
    let hand = Bone::hand(side);
    let hand_tip = sk.bone_def(hand).tip.normalize();
    let start = *pose;
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        if goal.wrist.is_some() || goal.hand_dir.is_some() || goal.palm.is_some() {
            let (p, q) = sk.chain(m, hand);
            if let Some(w) = goal.wrist {
                out.extend_from_slice((4.0 * (p - w)).as_slice());
            }
            if let Some(d) = goal.hand_dir {
                out.extend_from_slice((q * hand_tip - d.normalize()).as_slice());
            }
            if let Some(n) = goal.palm {
                out.extend_from_slice((0.7 * (q * -Vector3::y() - n.normalize())).as_slice());
            }
        }
        if let Some((b, target)) = goal.ray {
            let (o, q) = sk.chain(m, b);
            let d = q * sk.bone_def(b).tip.normalize();
            out.extend_from_slice((2.0 * (d - (target - o).normalize())).as_slice());
        }
        for (k, &i) in params.iter().enumerate() {
            out.push(stay[k] * (m[i] - start[i]));
        }
    };
    least_squares(pose, params, residual, iters, 1e-6);
}

/// Turns neck and head (equal shares) so the face points at `target` (hips frame).
pub fn solve_gaze(sk: &Skeleton, pose: &mut [f32; MUSCLES], target: Point3<f32>, iters: usize) {
    let params = [idx::NECK_NOD, idx::NECK_TURN, idx::HEAD_NOD, idx::HEAD_TURN];
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        let (p, q) = sk.chain(m, Bone::Head);
        let eye = p + q * Vector3::new(0.0, 0.075 * sk.height() / 1.7, 0.0);
        out.extend_from_slice((q * Vector3::z() - (target - eye).normalize()).as_slice());
        // Share the turn and the nod between neck and head.
        out.push(0.05 * (m[idx::NECK_TURN] - m[idx::HEAD_TURN]));
        out.push(0.05 * (m[idx::NECK_NOD] - m[idx::HEAD_NOD]));
    };
    least_squares(pose, &params, residual, iters, 1e-7);
}

/// Levenberg–Marquardt over a few muscles with a forward-difference Jacobian; values stay in
/// [−1, 1].
pub fn least_squares<F>(pose: &mut [f32; MUSCLES], params: &[usize], mut residual: F, iters: usize, tol: f32)
where
    F: FnMut(&[f32; MUSCLES], &mut Vec<f32>),
{
    let n = params.len();
    let mut r = Vec::with_capacity(24);
    let mut rp = Vec::with_capacity(24);
    residual(pose, &mut r);
    let mut cost: f32 = r.iter().map(|v| v * v).sum();
    let mut mu = 1e-3f32;
    const H: f32 = 2e-3;
    for _ in 0..iters {
        if cost < tol {
            break;
        }
        let m = r.len();
        let mut j = DMatrix::<f32>::zeros(m, n);
        let mut probe = *pose;
        for (k, &i) in params.iter().enumerate() {
            let h = if probe[i] + H > 1.0 { -H } else { H };
            probe[i] += h;
            residual(&probe, &mut rp);
            probe[i] = pose[i];
            for row in 0..m {
                j[(row, k)] = (rp[row] - r[row]) / h;
            }
        }
        let rv = DVector::from_column_slice(&r);
        let jt = j.transpose();
        let g = &jt * &rv;
        let jtj = &jt * &j;
        loop {
            let mut a = jtj.clone();
            for k in 0..n {
                a[(k, k)] += mu * (1.0 + jtj[(k, k)]);
            }
            let Some(ch) = a.cholesky() else {
                mu *= 10.0;
                if mu > 1e6 {
                    return;
                }
                continue;
            };
            let step = ch.solve(&(-&g));
            let mut trial = *pose;
            for (k, &i) in params.iter().enumerate() {
                trial[i] = (trial[i] + step[k]).clamp(-1.0, 1.0);
            }
            residual(&trial, &mut rp);
            let c: f32 = rp.iter().map(|v| v * v).sum();
            if c < cost {
                *pose = trial;
                std::mem::swap(&mut r, &mut rp);
                cost = c;
                mu = (mu * 0.3).max(1e-6);
                break;
            }
            mu *= 8.0;
            if mu > 1e6 {
                return;
            }
        }
    }
}

/// Sets a bone's two swing muscles so that the bone points along `dir` (hips frame), keeping
/// its twist: the exact inverse of the swing for a direction goal.
pub fn aim_bone(sk: &Skeleton, pose: &mut [f32; MUSCLES], bone: Bone, dir: Vector3<f32>) {
    let d = sk.bone_def(bone);
    let parent = d.parent.expect("the hips cannot be aimed");
    let (_, pq) = sk.chain(pose, parent);
    let w = (pq * d.zero).inverse() * dir.normalize();
    let b = d.tip.normalize();
    let axis = b.cross(&w);
    let s = axis.norm();
    let angle = s.atan2(b.dot(&w));
    // Tan-half angles along the swing axes, as BoneDef::local_rotation composes them.
    let tan_half = if s > 1e-6 { axis / s * (0.5 * angle).tan() } else { Vector3::zeros() };
    for m in d.swing.iter().flatten() {
        let a = 2.0 * tan_half.dot(&m.axis).atan();
        pose[m.muscle] = muscle_value(m.muscle, a.to_degrees()).clamp(-1.0, 1.0);
    }
}

/// A world point in the hips frame of a person standing at `root` facing `yaw_deg`, whose hips
/// are `hips_height` above the floor.
pub fn to_hips_frame(world: Point3<f32>, root: Point3<f32>, yaw_deg: f32, hips_height: f32) -> Point3<f32> {
    let rel = world - Point3::new(root.x, root.y + hips_height, root.z);
    Point3::from(crate::geometry::yaw_rotation(yaw_deg).inverse() * rel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::humanoid::Humanoid;

    #[test]
    fn standing_pose_stands() {
        let h = Humanoid::default();
        let p = h.pose(&STANDING, Point3::origin(), 0.0);
        for side in Side::BOTH {
            let d = p.direction(Bone::upper_arm(side));
            assert!(d.y < -0.95, "{side:?} arm hangs: {d:?}");
            assert!(p.hand_position(side).y < 0.95 && p.hand_position(side).y > 0.7);
        }
        assert!((p.position(Bone::Hips).y - 0.95).abs() < 0.03);
        assert!(p.direction(Bone::Spine).y > 0.99 && p.head_forward().z > 0.98);
    }

    #[test]
    fn solver_reaches_a_wrist_goal_and_aim_bone_is_exact() {
        let h = Humanoid::default();
        let sk = h.skeleton();
        let mut m = STANDING;
        let goal = Point3::new(0.3, 0.5, 0.35);
        solve_arm(
            sk,
            &mut m,
            Side::Right,
            &ArmGoal { wrist: Some(goal), ..Default::default() },
            &arm_params(Side::Right),
            &[0.01; 9],
            30,
        );
        let (p, _) = sk.chain(&m, Bone::RightHand);
        assert!((p - goal).norm() < 0.01, "wrist at {p:?}");

        let mut m = STANDING;
        let dir = Vector3::new(-0.5, 0.1, 0.85).normalize();
        aim_bone(sk, &mut m, Bone::LeftUpperArm, dir);
        let (_, q) = sk.chain(&m, Bone::LeftUpperArm);
        let got = q * sk.bone_def(Bone::LeftUpperArm).tip.normalize();
        assert!((got - dir).norm() < 1e-3, "{got:?}");
    }
}
