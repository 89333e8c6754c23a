//! Referencing gestures (§3.3): a person standing at a position and yaw points at a target.
//!
//! Like the recorded people, each gesture starts and ends in natural standing (breathing,
//! sway), and the rest is drawn from the seed: the arm (by the side the target is on; either
//! one for targets near straight ahead), the hand shape (index finger, open palm, two
//! fingers), a straight or bent elbow, the timing of lead-in idle / rise / hold / return /
//! trailing idle, a tremor while holding, an aiming error of a few degrees, a torso turn for
//! targets far to the side, and when the eyes (head) go to the target and come back.
//!
//! The pointing pose is solved, not guessed: the upper arm is aimed analytically, then a few
//! Levenberg–Marquardt steps over shoulder, arm and hand muscles put the pointing ray (index
//! finger's last segment, or the hand for an open palm) through the aimed point, and two more
//! put the face on the target.
//!
//! How cleanly people point is a stated quantity, [`Pointing`]: `clean` (the level of the
//! committed study) draws an aiming error of N(0, 2.5°) sideways and N(0, 2°) up, clamped to
//! ±6°/±5°, and puts the finger (or forearm) ray through that aimed point. `realistic` follows
//! what people do: 40% aim with the arm rather than the finger (the GOND recording holds
//! its wrist on the shoulder→target line with the elbow bent ≈80°); with a straight arm they put
//! the fingertip on the line from the eye to the target (Herbort & Kunde 2016, 2018), so the
//! arm–finger line an observer extrapolates passes above and beside the target; and the random
//! part is N(0, 3°) per axis (the order of the ≈3° biases of Bangerter & Oppenheimer 2006),
//! clamped to ±9°.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::synth::{
    ArmGoal, HandPose, INDEX_POINT, Idle, OPEN, STANDING, TWO_FINGER, Wobble, aim_bone, blend_hand, clamp_pose,
    envelope, solve_arm, solve_gaze, to_hips_frame,
};
use super::{FRAMES, Motion};
use crate::humanoid::muscles::idx;
use crate::humanoid::{Bone, Finger, Humanoid, MUSCLES, Side, Skeleton, muscle_value};

/// How the hand is shaped while pointing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum HandShape {
    IndexPoint,
    OpenPalm,
    TwoFinger,
}

impl HandShape {
    fn fingers(self) -> &'static HandPose {
        match self {
            HandShape::IndexPoint => &INDEX_POINT,
            HandShape::OpenPalm => &OPEN,
            HandShape::TwoFinger => &TWO_FINGER,
        }
    }

    /// The bone whose ray is put through the target.
    fn ray_bone(self, side: Side) -> Bone {
        match self {
            HandShape::OpenPalm => Bone::hand(side),
            _ => Bone::finger(side, Finger::Index, 2),
        }
    }
}

/// How cleanly the people of a dataset point (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Pointing {
    /// The finger or forearm ray through a point a few degrees off the target.
    #[default]
    Clean,
    /// Arm-aimed and eye–fingertip-aligned pointing, with a larger random error.
    Realistic,
}

impl Pointing {
    pub const ALL: [Pointing; 2] = [Pointing::Clean, Pointing::Realistic];

    pub fn name(self) -> &'static str {
        match self {
            Pointing::Clean => "clean",
            Pointing::Realistic => "realistic",
        }
    }

    pub fn from_name(s: &str) -> Option<Pointing> {
        Pointing::ALL.into_iter().find(|p| p.name() == s)
    }
}

/// What was drawn for one referencing gesture.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferencingStyle {
    pub side: Side,
    pub shape: HandShape,
    /// Whether the elbow stays bent (pointing with the forearm) rather than nearly straight.
    pub bent_elbow: bool,
    /// Forearm Stretch during the hold (1 straight, 0 bent 80°).
    pub forearm_stretch: f32,
    /// The wrist on the shoulder→aim line with the elbow bent (realistic level only).
    pub arm_aimed: bool,
    /// The fingertip on the eye→target line rather than the finger ray through the aim
    /// (realistic level, straight arm only).
    pub eye_aligned: bool,
    /// Frames of lead-in idle, rise, hold and return; the rest is trailing idle.
    pub lead: u32,
    pub rise: u32,
    pub hold: u32,
    pub ret: u32,
    /// First and last frame of looking at the target (`last` = 100: until the end).
    pub gaze: (u32, u32),
    /// Aiming error (sideways, up) in degrees.
    pub aim_error_deg: [f32; 2],
    /// Torso turn towards the target, degrees (+ right).
    pub torso_turn_deg: f32,
    /// Bearing of the target from the person (degrees, + right of straight ahead).
    pub bearing_deg: f32,
}

const KEY_REFERENCING: u64 = 0x5EFE_2E4C;

/// A referencing gesture of the default 1.70 m person at `human_pos` (floor point) facing
/// `human_yaw` (degrees) towards `target`, drawn from `seed`.
pub fn referencing(
    seed: u64,
    human_pos: Point3<f32>,
    human_yaw: f32,
    target: Point3<f32>,
) -> (Motion, ReferencingStyle) {
    referencing_with(Humanoid::standard(), Pointing::Clean, seed, human_pos, human_yaw, target)
}

/// [`referencing`] for a given body (its proportions decide the exact arm angles) and pointing
/// level: this person's stance, the style drawn, the pointing pose solved, where the eyes go,
/// the hold's tremor, then the 100 frames. The draws from the seed come in that order.
///
/// Panics if a position or the yaw is not finite (a caller's bug, not a data error).
pub fn referencing_with(
    h: &Humanoid,
    pointing: Pointing,
    seed: u64,
    human_pos: Point3<f32>,
    human_yaw: f32,
    target: Point3<f32>,
) -> (Motion, ReferencingStyle) {
    assert!(
        human_pos.iter().chain(target.iter()).all(|v| v.is_finite()) && human_yaw.is_finite(),
        "referencing gesture needs finite positions and yaw, got person {human_pos:?} yaw {human_yaw} target {target:?}"
    );
    let sk = h.skeleton();
    let mut r = farm::seed::rng(seed, &[KEY_REFERENCING]);
    let (base, idle) = stance(&mut r);
    let t_local = target_from_hips(h, sk, &base, target, human_pos, human_yaw);
    let mut style = draw_style(&mut r, pointing, t_local.x.atan2(t_local.z).to_degrees());
    let (pose, target_distance) = pointing_pose(sk, &base, &style, t_local, &mut r);
    let gaze = Gaze::draw(&mut r, sk, &base, &pose, t_local, target_distance, &style);
    style.gaze = (gaze.on, gaze.off);
    let hold = Hold::draw(&mut r);
    (animate(&base, &pose, &idle, &style, &gaze, &hold), style)
}

/// This person's way of standing, and their idle movement.
fn stance(r: &mut ChaCha8Rng) -> ([f32; MUSCLES], Idle) {
    let mut base = STANDING;
    let arm_down = r.random_range(-0.06..0.06f32);
    let elbow = r.random_range(-0.08..0.06f32);
    for side in Side::BOTH {
        let a = side.arm_muscles();
        base[a + idx::ARM_DOWN_UP] += arm_down + r.random_range(-0.02..0.02f32);
        base[a + idx::FOREARM_STRETCH] += elbow;
        base[side.leg_muscles() + idx::UPPER_LEG_IN_OUT] += r.random_range(-0.05..0.05f32);
    }
    base[idx::SPINE_FRONT_BACK] += r.random_range(-0.04..0.04f32);
    (base, Idle::new(r))
}

/// The target in the standing person's hips frame; one inside the body cannot be pointed at
/// and is taken half a metre further out.
fn target_from_hips(
    h: &Humanoid,
    sk: &Skeleton,
    base: &[f32; MUSCLES],
    target: Point3<f32>,
    human_pos: Point3<f32>,
    human_yaw: f32,
) -> Point3<f32> {
    let mut t_local = to_hips_frame(target, human_pos, human_yaw, sk.hips_height(base));
    let chest = Point3::new(0.0, 0.4 * h.height() / 1.7, 0.0);
    if (t_local - chest).norm() < 0.4 {
        let out = Vector3::new(t_local.x, 0.0, t_local.z);
        let out = if out.norm() > 1e-3 { out.normalize() } else { Vector3::z() };
        t_local += out * 0.5;
    }
    t_local
}

/// The gesture's style for a target at `bearing` degrees: the arm, the hand, the elbow, the
/// torso's turn, the timing and the aiming error (the eyes' timing comes later: [`Gaze`]).
fn draw_style(r: &mut ChaCha8Rng, pointing: Pointing, bearing: f32) -> ReferencingStyle {
    // Arm by the target's side; near straight ahead, mostly the right.
    let side = if bearing > 12.0 {
        Side::Right
    } else if bearing < -12.0 {
        Side::Left
    } else if r.random_bool(0.65) {
        Side::Right
    } else {
        Side::Left
    };
    let shape = match r.random_range(0.0..1.0f32) {
        x if x < 0.55 => HandShape::IndexPoint,
        x if x < 0.8 => HandShape::OpenPalm,
        _ => HandShape::TwoFinger,
    };
    let mut bent = r.random_bool(if shape == HandShape::OpenPalm { 0.2 } else { 0.4 });
    let mut stretch = if bent { r.random_range(0.2..0.55f32) } else { r.random_range(0.82..0.98f32) };
    let torso_turn = bearing.signum() * ((bearing.abs() - 35.0).max(0.0) * r.random_range(0.35..0.6f32)).min(65.0);
    let [lead, rise, hold, ret] = draw_timing(r);
    let normal = |sd: f32| Normal::new(0.0f32, sd).expect("positive deviation");
    let mut aim_err = [normal(2.5).sample(r).clamp(-6.0, 6.0), normal(2.0).sample(r).clamp(-5.0, 5.0)];
    // The realistic level draws after everything the clean one draws, so a clean dataset's
    // gestures do not depend on it.
    let (mut arm_aimed, mut eye_aligned) = (false, false);
    if pointing == Pointing::Realistic {
        aim_err = [normal(3.0).sample(r).clamp(-9.0, 9.0), normal(3.0).sample(r).clamp(-9.0, 9.0)];
        arm_aimed = r.random_bool(0.4);
        let arm_bend = r.random_range(55.0..90.0f32);
        if arm_aimed {
            // Forearm Stretch 1 is straight, 0 bent 80°, linear in between and beyond.
            (bent, stretch) = (false, 1.0 - arm_bend / 80.0);
        }
        eye_aligned = !arm_aimed && !bent;
    }
    ReferencingStyle {
        side,
        shape,
        bent_elbow: bent,
        forearm_stretch: stretch,
        arm_aimed,
        eye_aligned,
        lead,
        rise,
        hold,
        ret,
        gaze: (0, 0),
        aim_error_deg: aim_err,
        torso_turn_deg: torso_turn,
        bearing_deg: bearing,
    }
}

/// Frames of lead-in idle, rise, hold and return, fitting 96 frames (the hold shortened first).
fn draw_timing(r: &mut ChaCha8Rng) -> [u32; 4] {
    let mut lead = r.random_range(3..=30u32);
    let rise = r.random_range(8..=20u32);
    let mut hold = r.random_range(12..=50u32);
    let ret = r.random_range(8..=22u32);
    while lead + rise + hold + ret > 96 {
        if hold > 12 {
            hold -= 1;
        } else {
            lead -= 1;
        }
    }
    [lead, rise, hold, ret]
}

/// The held pointing pose, its ray through the aimed point; and the target's distance from the
/// shoulder.
fn pointing_pose(
    sk: &Skeleton,
    base: &[f32; MUSCLES],
    s: &ReferencingStyle,
    t_local: Point3<f32>,
    r: &mut ChaCha8Rng,
) -> ([f32; MUSCLES], f32) {
    let mut pose = *base;
    set_torso_turn(&mut pose, s.torso_turn_deg);
    blend_hand(&mut pose, s.side, s.shape.fingers(), 1.0);
    let a = s.side.arm_muscles();
    pose[a + idx::FOREARM_STRETCH] = s.forearm_stretch;
    pose[a + idx::FOREARM_TWIST] = match s.shape {
        HandShape::OpenPalm => r.random_range(0.3..0.7f32),
        _ => r.random_range(-0.15..0.15f32),
    };
    let ua = Bone::upper_arm(s.side);
    let shoulder = sk.chain(&pose, ua).0;
    let distance = (t_local - shoulder).norm();
    // Where the pointing line should go before the aiming error: the target, or for an
    // eye-aligned point the direction from the shoulder through a fingertip on the eye→target
    // line.
    let aimed_at = if s.eye_aligned { eye_aligned_point(sk, &pose, s.side, t_local) } else { t_local };
    // The aiming error is an angle seen from the pointing hand (from the shoulder when the
    // arm aims).
    aim_bone(sk, &mut pose, ua, aimed_at - shoulder);
    let from = if s.arm_aimed { shoulder } else { sk.chain(&pose, s.shape.ray_bone(s.side)).0 };
    let along = aimed_at - from;
    let aim = from + perturb(along.normalize(), s.aim_error_deg) * along.norm();
    if s.arm_aimed {
        aim_with_arm(sk, &mut pose, s.side, aim, s.forearm_stretch);
    } else {
        point_hand(sk, &mut pose, s, shoulder, aim);
    }
    (pose, distance)
}

/// A straight or bent arm whose hand's ray goes through `aim`: the upper arm aimed (lower by
/// the elbow's angle when bent, then the twist that lifts the forearm onto the aim), then a few
/// solver steps over shoulder, arm and hand.
fn point_hand(sk: &Skeleton, pose: &mut [f32; MUSCLES], s: &ReferencingStyle, shoulder: Point3<f32>, aim: Point3<f32>) {
    let ua = Bone::upper_arm(s.side);
    if s.bent_elbow {
        let aim_dir = (aim - shoulder).normalize();
        let bend = (1.0 - s.forearm_stretch) * 80.0;
        let axis = Vector3::y().cross(&aim_dir);
        let axis = if axis.norm() > 1e-3 { axis.normalize() } else { Vector3::x() };
        let down = UnitQuaternion::from_scaled_axis(axis * bend.to_radians()) * aim_dir;
        aim_bone(sk, pose, ua, down + Vector3::new(0.25 * s.side.sign(), 0.0, 0.0));
        best_twist(sk, pose, s.side, aim);
    } else {
        aim_bone(sk, pose, ua, aim - shoulder);
    }
    let a = s.side.arm_muscles();
    let params = [
        a + idx::ARM_DOWN_UP,
        a + idx::ARM_FRONT_BACK,
        a + idx::ARM_TWIST,
        a + idx::HAND_DOWN_UP,
        a + idx::HAND_IN_OUT,
    ];
    let stay = [0.02, 0.02, 0.05, 0.12, 0.12];
    let goal = ArmGoal { ray: Some((s.shape.ray_bone(s.side), aim)), ..Default::default() };
    solve_arm(sk, pose, s.side, &goal, &params, &stay, 12);
}

/// Where the face goes: at the target, from the standing and from the pointing posture; and
/// when (frames: on, its ramp, off, its fall).
struct Gaze {
    look_base: [f32; MUSCLES],
    look_hold: [f32; MUSCLES],
    on: u32,
    ramp: f32,
    off: u32,
    fall: f32,
}

impl Gaze {
    fn draw(
        r: &mut ChaCha8Rng,
        sk: &Skeleton,
        base: &[f32; MUSCLES],
        pose: &[f32; MUSCLES],
        t_local: Point3<f32>,
        distance: f32,
        s: &ReferencingStyle,
    ) -> Gaze {
        let normal = |sd: f32| Normal::new(0.0f32, sd).expect("positive deviation");
        let err = Vector3::new(normal(0.04).sample(r), normal(0.03).sample(r), 0.0) * distance;
        let (mut look_base, mut look_hold) = (*base, *pose);
        solve_gaze(sk, &mut look_base, t_local + err, 6);
        solve_gaze(sk, &mut look_hold, t_local + err, 6);
        let on = if r.random_bool(0.3) { 0 } else { s.lead.saturating_sub(r.random_range(0..12)) };
        let ramp = r.random_range(5..11) as f32;
        let end = s.lead + s.rise + s.hold;
        let off =
            if r.random_bool(0.45) { FRAMES as u32 } else { (end + r.random_range(0..=s.ret + 10)).min(FRAMES as u32) };
        let fall = r.random_range(6..13) as f32;
        Gaze { look_base, look_hold, on, ramp, off, fall }
    }
}

/// Tremor while holding, a little overshoot-and-settle after the rise.
struct Hold {
    tremor: [Wobble; 4],
    settle: f32,
}

impl Hold {
    fn draw(r: &mut ChaCha8Rng) -> Hold {
        let amp = r.random_range(0.003..0.01f32);
        let tremor = [
            Wobble::new(r, amp, 6.0),
            Wobble::new(r, amp, 6.0),
            Wobble::new(r, 2.0 * amp, 5.0),
            Wobble::new(r, 0.015, 0.6),
        ];
        Hold { tremor, settle: r.random_range(0.0..0.03f32) }
    }
}

const HEAD: [usize; 6] = [idx::NECK_NOD, idx::NECK_TURN, idx::HEAD_NOD, idx::HEAD_TURN, idx::NECK_TILT, idx::HEAD_TILT];
const TORSO: [usize; 3] = [idx::SPINE_TWIST, idx::CHEST_TWIST, idx::UPPER_CHEST_TWIST];

/// The 100 frames: from standing to the pointing pose and back on the style's timing, the face
/// on its own, tremor and idle movement on top.
fn animate(
    base: &[f32; MUSCLES],
    pose: &[f32; MUSCLES],
    idle: &Idle,
    s: &ReferencingStyle,
    g: &Gaze,
    hold: &Hold,
) -> Motion {
    let (a, f) = (s.side.arm_muscles(), s.side.finger_muscles());
    let (lead, rise, held, ret) = (s.lead as f32, s.rise as f32, s.hold as f32, s.ret as f32);
    let mut motion = Motion::constant(base);
    for t in 0..FRAMES {
        let x = t as f32;
        let e_arm = envelope(x, lead, rise, lead + rise + held, ret);
        let e_hand = envelope(x, lead + 0.25 * rise, 0.7 * rise, lead + rise + held - 2.0, 0.7 * ret);
        // Looking at the target from the start means looking at it in frame 0 already.
        let e_gaze = envelope(x, g.on as f32, if g.on == 0 { 0.0 } else { g.ramp }, g.off as f32, g.fall);
        let m = motion.frame_mut(t);
        let towards = |i: usize, e: f32| base[i] + (pose[i] - base[i]) * e;
        for i in (a..a + 9).chain(TORSO) {
            m[i] = towards(i, e_arm);
        }
        for i in f..f + 20 {
            m[i] = towards(i, e_hand);
        }
        for i in HEAD {
            let look = g.look_base[i] + (g.look_hold[i] - g.look_base[i]) * e_arm;
            m[i] = base[i] + (look - base[i]) * e_gaze;
        }
        hold_and_sway(m, x, s, hold, lead + rise, e_arm);
        // Idle drift of the head is damped while the eyes are on the target.
        let held_head = HEAD.map(|i| m[i]);
        idle.apply(m, x);
        for (k, &i) in HEAD.iter().enumerate() {
            m[i] = held_head[k] + (m[i] - held_head[k]) * (1.0 - 0.7 * e_gaze);
        }
        clamp_pose(m);
    }
    motion
}

/// Overshoot just after the rise (ending at frame `risen`), settling during the hold; tremor
/// while the arm is up; the other arm moving a little with the body.
fn hold_and_sway(m: &mut [f32; MUSCLES], x: f32, s: &ReferencingStyle, hold: &Hold, risen: f32, e_arm: f32) {
    let a = s.side.arm_muscles();
    let after_rise = x - risen;
    if after_rise > -3.0 {
        m[a + idx::ARM_DOWN_UP] += hold.settle * (-(after_rise + 3.0) / 6.0).exp() * e_arm;
    }
    let held = e_arm * e_arm;
    m[a + idx::ARM_DOWN_UP] += held * hold.tremor[0].at(x);
    m[a + idx::ARM_FRONT_BACK] += held * hold.tremor[1].at(x);
    m[a + idx::HAND_DOWN_UP] += held * hold.tremor[2].at(x);
    m[a + idx::ARM_TWIST] += held * hold.tremor[3].at(x);
    let o = s.side.other().arm_muscles();
    m[o + idx::ARM_FRONT_BACK] -= 0.03 * e_arm;
    m[o + idx::FOREARM_STRETCH] -= 0.05 * e_arm;
}

/// Turns spine, chest and upper chest together by `deg` (+ right).
fn set_torso_turn(pose: &mut [f32; MUSCLES], deg: f32) {
    for (i, share) in [(idx::SPINE_TWIST, 0.4), (idx::CHEST_TWIST, 0.35), (idx::UPPER_CHEST_TWIST, 0.25)] {
        pose[i] += muscle_value(i, deg * share);
        pose[i] = pose[i].clamp(-1.0, 1.0);
    }
}

/// Rotates a unit direction by `err` degrees sideways (about up) and upwards.
fn perturb(dir: Vector3<f32>, err: [f32; 2]) -> Vector3<f32> {
    let side_axis = Vector3::y().cross(&dir);
    let yaw = UnitQuaternion::from_scaled_axis(Vector3::y() * err[0].to_radians());
    let pitch = if side_axis.norm() > 1e-3 {
        UnitQuaternion::from_scaled_axis(side_axis.normalize() * -err[1].to_radians())
    } else {
        UnitQuaternion::identity()
    };
    (yaw * pitch * dir).normalize()
}

/// For a straight arm whose fingertip sits on the line from the eye to `target` (hips frame):
/// the point at the target's distance along the shoulder→fingertip line.
fn eye_aligned_point(sk: &Skeleton, pose: &[f32; MUSCLES], side: Side, target: Point3<f32>) -> Point3<f32> {
    let (head, q) = sk.chain(pose, Bone::Head);
    let eye = head + q * Vector3::new(0.0, 0.075 * sk.height() / 1.7, 0.08 * sk.height() / 1.7);
    let shoulder = sk.chain(pose, Bone::upper_arm(side)).0;
    let reach = [Bone::upper_arm(side), Bone::lower_arm(side), Bone::hand(side)]
        .iter()
        .map(|&b| sk.bone_def(b).tip.norm())
        .sum::<f32>()
        + sk.bone_def(Bone::finger(side, Finger::Index, 0)).tip.norm() * 2.0;
    // The fingertip where the eye ray leaves the sphere of the arm's reach about the shoulder.
    let u = (target - eye).normalize();
    let e = eye - shoulder;
    let b = e.dot(&u);
    let disc = b * b - (e.norm_squared() - reach * reach);
    let tip = if disc > 0.0 { eye + u * (-b + disc.sqrt()) } else { shoulder + u * reach };
    shoulder + (tip - shoulder).normalize() * (target - shoulder).norm()
}

/// Bends the elbow to `stretch` and puts the wrist on the line from the shoulder to `aim`, the
/// elbow below it and the forearm rising to it, as the GOND recording's person points.
fn aim_with_arm(sk: &Skeleton, pose: &mut [f32; MUSCLES], side: Side, aim: Point3<f32>, stretch: f32) {
    let a = side.arm_muscles();
    pose[a + idx::FOREARM_STRETCH] = stretch.clamp(-1.0, 1.0);
    let ua = Bone::upper_arm(side);
    let shoulder = sk.chain(pose, ua).0;
    let (l1, l2) = (sk.bone_def(ua).tip.norm(), sk.bone_def(Bone::lower_arm(side)).tip.norm());
    let bend = ((1.0 - stretch) * 80.0).to_radians();
    let chord = (l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * bend.cos()).sqrt();
    // The upper arm leaves the shoulder→wrist line by this much, below it.
    let below = (l2 * bend.sin() / chord).clamp(-1.0, 1.0).asin();
    let dir = (aim - shoulder).normalize();
    let axis = Vector3::y().cross(&dir);
    let axis = if axis.norm() > 1e-3 { axis.normalize() } else { Vector3::x() };
    aim_bone(sk, pose, ua, UnitQuaternion::from_scaled_axis(axis * below) * dir);
    best_twist(sk, pose, side, aim);
    let params = [a + idx::ARM_DOWN_UP, a + idx::ARM_FRONT_BACK, a + idx::ARM_TWIST];
    let goal = ArmGoal { wrist: Some(shoulder + dir * chord), ..Default::default() };
    solve_arm(sk, pose, side, &goal, &params, &[0.01, 0.01, 0.02], 12);
}

/// Picks the arm twist that best lays the forearm along the line from the elbow to `aim`.
fn best_twist(sk: &Skeleton, pose: &mut [f32; MUSCLES], side: Side, aim: Point3<f32>) {
    let i = side.arm_muscles() + idx::ARM_TWIST;
    let la = Bone::lower_arm(side);
    let tip = sk.bone_def(la).tip.normalize();
    let mut best = (f32::MIN, pose[i]);
    for k in 0..=12 {
        let v = -1.0 + k as f32 / 6.0;
        pose[i] = v;
        let (o, q) = sk.chain(pose, la);
        let score = (q * tip).dot(&(aim - o).normalize());
        if score > best.0 {
            best = (score, v);
        }
    }
    pose[i] = best.1;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::heading;
    use crate::gesture::accuracy::{DEFAULT_RADIUS, accuracy_with};
    use crate::gesture::intervention::{INTERVENTIONS, intervention};

    /// A random target around a person: 1–5 m away, within ±100° of their heading, 0–2 m high.
    fn scenario(seed: u64) -> (Point3<f32>, f32, Point3<f32>) {
        let mut r = farm::seed::rng(seed, &[77]);
        let pos = Point3::new(r.random_range(-3.0..3.0f32), 0.0, r.random_range(-3.0..3.0f32));
        let yaw = r.random_range(0.0..360.0f32);
        let bearing = r.random_range(-100.0..100.0f32);
        let dist = r.random_range(1.0..5.0f32);
        let h = heading(yaw + bearing) * dist;
        (pos, yaw, Point3::new(pos.x + h.x, r.random_range(0.0..2.0f32), pos.z + h.y))
    }

    #[test]
    fn same_seed_same_motion_different_seed_different() {
        let (p, y, t) = scenario(1);
        let (a, sa) = referencing(5, p, y, t);
        let (b, sb) = referencing(5, p, y, t);
        assert_eq!(a, b);
        assert_eq!(sa, sb);
        let (c, _) = referencing(6, p, y, t);
        assert_ne!(a, c);
    }

    #[test]
    fn the_arm_on_the_targets_side_rises_and_returns() {
        let pos = Point3::origin();
        for (bearing, side) in [(60.0f32, Side::Right), (-60.0, Side::Left)] {
            let h = heading(bearing) * 3.0;
            let (m, s) = referencing(3, pos, 0.0, Point3::new(h.x, 1.2, h.y));
            assert_eq!(s.side, side);
            let du = m.muscle(side.arm_muscles() + idx::ARM_DOWN_UP);
            let mid = (s.lead + s.rise + s.hold / 2) as usize;
            assert!(du[mid] > du[0] + 0.4, "{side:?}: {} → {}", du[0], du[mid]);
            assert!((du[99] - du[0]).abs() < 0.1, "returns to rest");
            assert!(m.as_flat().iter().all(|v| v.is_finite() && v.abs() <= 1.0));
        }
    }

    /// During the hold the pointing ray passes close to the (deliberately missed) target.
    #[test]
    fn the_hold_pose_points_where_it_aims() {
        let h = Humanoid::default();
        let mut worst: f32 = 0.0;
        for seed in 0..60 {
            let (p, y, t) = scenario(seed);
            let (m, s) = referencing(seed, p, y, t);
            let frame = (s.lead + s.rise + s.hold / 2) as usize;
            let pose = h.pose(m.frame(frame), p, y);
            let (o, d) = pose.ray(s.shape.ray_bone(s.side));
            let off = (t - o).normalize().dot(&d).clamp(-1.0, 1.0).acos().to_degrees();
            let allowed = s.aim_error_deg[0].hypot(s.aim_error_deg[1]) + 5.0;
            worst = worst.max(off - allowed + 5.0);
            assert!(
                off < allowed,
                "seed {seed}: ray {off:.1}° off the target (aim error {:?}, style {s:?})",
                s.aim_error_deg
            );
        }
        eprintln!("largest pointing error beyond the drawn aiming error: {worst:.1}°");
    }

    /// Synthesized referencing gestures score high gesture accuracy towards their targets;
    /// intervention gestures score low towards the same targets.
    #[test]
    fn referencing_scores_high_and_intervention_low() {
        let h = Humanoid::default();
        let n = 200;
        let (mut refs, mut ints) = (0.0, 0.0);
        for seed in 0..n {
            let (p, y, t) = scenario(seed);
            let (m, _) = referencing(seed, p, y, t);
            refs += accuracy_with(&h, &m, p, y, t, DEFAULT_RADIUS);
            let i = intervention(seed as usize % INTERVENTIONS);
            ints += accuracy_with(&h, &i, p, y, t, DEFAULT_RADIUS);
        }
        let (refs, ints) = (refs / n as f32, ints / n as f32);
        eprintln!("mean gesture accuracy over {n} random targets: referencing {refs:.3}, intervention {ints:.3}");
        assert!(refs > 0.7, "referencing {refs}");
        assert!(ints < 0.2, "intervention {ints}");
    }

    #[test]
    fn odd_targets_still_give_valid_motions() {
        let pos = Point3::new(1.0, 0.0, 1.0);
        for t in [
            pos,
            Point3::new(1.0, 1.2, 1.0),
            Point3::new(1.0, 5.0, 1.0),
            Point3::new(101.0, 1.0, 1.0),
            Point3::new(1.0, 0.0, 0.2),
        ] {
            for seed in 0..5 {
                let (m, _) = referencing(seed, pos, 10.0, t);
                assert!(m.as_flat().iter().all(|v| v.is_finite() && v.abs() <= 1.0), "target {t:?}");
            }
        }
    }

    /// At the realistic level, arm-aimed gestures hold the wrist on the shoulder→target line
    /// with the forearm well above it, as the GOND recording does; straight-arm ones put the
    /// fingertip on the eye→target line, which clean pointing does not.
    #[test]
    fn realistic_pointing_aims_with_the_arm_and_the_eye() {
        let h = Humanoid::default();
        let (mut arm, mut eye_clean, mut eye_real) = (0, Vec::new(), Vec::new());
        for seed in 0..80 {
            let (p, y, t) = scenario(seed);
            let (m, s) = referencing_with(&h, Pointing::Realistic, seed, p, y, t);
            assert!(m.as_flat().iter().all(|v| v.is_finite() && v.abs() <= 1.0));
            if s.arm_aimed {
                arm += 1;
                let e = crate::gesture::line_errors(&h, &m, p, y, t);
                let allowed = s.aim_error_deg[0].hypot(s.aim_error_deg[1]) + 4.0;
                assert!(e.arm_deg < allowed, "seed {seed}: shoulder→wrist {e:?}, aim error {:?}", s.aim_error_deg);
                assert!(e.forearm_deg > 15.0, "seed {seed}: the forearm is the aiming line: {e:?}");
            }
            // Fingertip to the eye→target line at mid-hold (the drawn error moves it a little).
            let gap = |m: &Motion, s: &ReferencingStyle| {
                let pose = h.pose(m.frame((s.lead + s.rise + s.hold / 2) as usize), p, y);
                let (head, q) = (pose.position(Bone::Head), pose.rotation(Bone::Head));
                let eye = head + q * Vector3::new(0.0, 0.075, 0.08);
                let tip = pose.tip(Bone::finger(s.side, Finger::Index, 2));
                let u = (t - eye).normalize();
                ((tip - eye) - u * (tip - eye).dot(&u)).norm()
            };
            if s.eye_aligned && s.shape != HandShape::OpenPalm {
                eye_real.push(gap(&m, &s));
                let (mc, sc) = referencing(seed, p, y, t);
                if !sc.bent_elbow && sc.shape != HandShape::OpenPalm {
                    eye_clean.push(gap(&mc, &sc));
                }
            }
        }
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
        let (real, clean) = (mean(&eye_real), mean(&eye_clean));
        eprintln!("arm-aimed {arm}/80; fingertip to the eye→target line: realistic {real:.3} m, clean {clean:.3} m");
        assert!((20..50).contains(&arm), "arm-aimed {arm} of 80");
        assert!(eye_real.len() >= 10 && real < 0.06 && clean > 2.0 * real, "realistic {real}, clean {clean}");
    }

    #[test]
    fn styles_are_diverse() {
        let mut shapes = std::collections::HashSet::new();
        let (mut bent, mut left, mut turned) = (0, 0, 0);
        for seed in 0..100 {
            let (p, y, t) = scenario(seed);
            let (_, s) = referencing(seed, p, y, t);
            shapes.insert(s.shape);
            bent += s.bent_elbow as u32;
            left += (s.side == Side::Left) as u32;
            turned += (s.torso_turn_deg.abs() > 5.0) as u32;
        }
        assert_eq!(shapes.len(), 3);
        assert!(
            (15..60).contains(&bent) && (25..75).contains(&left) && turned > 5,
            "bent {bent} left {left} turned {turned}"
        );
    }
}
