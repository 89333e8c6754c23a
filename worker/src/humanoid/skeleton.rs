//! The skeleton: Unity's humanoid bones, adult proportions, and forward kinematics from the
//! 95 muscle values.
//!
//! Every bone has a frame that, in the T-pose, is aligned with the character's axes (x right,
//! y up, z forward; palms down, thumbs forward). A bone's rotation relative to its parent is
//!
//! ```text
//! local = zero · Swing(a₁·θ₁ + a₂·θ₂) · Twist(t·θ₀)
//! ```
//!
//! as Unity's muscle space does it (`preQ · SwingTwist(angles)`): `zero` is the bone's
//! muscle-zero orientation, `t` its twist axis along the bone, `a₁`, `a₂` the two swing axes
//! perpendicular to it, θ the muscle angles (see [`super::muscles`]). Left bones are the mirror
//! images of right bones, so one muscle value means the same anatomical motion on both sides.
//!
//! **Muscle-zero pose** (Unity's centre of every range, not the T-pose): torso and head upright,
//! upper arms 40° below horizontal and swung 30° forward, elbows bent 80°, fingers half curled
//! (proximal 40°, middle 45°, distal 40°; thumb joints 30°), thighs 30° forward, knees bent 80°:
//! a crouch with the hands forward. In this pose the T-pose is muscles
//! Arm Down-Up 0.4, Arm Front-Back 0.3, Forearm Stretch 1, Upper Leg Front-Back 0.6,
//! Lower Leg Stretch 1, fingers Stretched ≈ 0.9, and natural standing is
//! [`crate::gesture::STANDING`] (arms at the sides at Arm Down-Up ≈ −0.65).

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3};

use super::muscles::{MUSCLES, idx, muscle_degrees};
use crate::geometry::yaw_rotation;

/// Number of humanoid bones (Unity's `HumanBodyBones`, without `LastBone`).
pub const BONES: usize = 55;

/// Declares `Bone` and its names from one list.
macro_rules! bones {
    ($($name:ident),* $(,)?) => {
        /// Unity's `HumanBodyBones`, same order and numbering.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        #[repr(u8)]
        pub enum Bone {
            $($name),*
        }

        const BONE_NAMES: [&str; BONES] = [$(stringify!($name)),*];
    };
}

bones!(
    Hips,
    LeftUpperLeg,
    RightUpperLeg,
    LeftLowerLeg,
    RightLowerLeg,
    LeftFoot,
    RightFoot,
    Spine,
    Chest,
    Neck,
    Head,
    LeftShoulder,
    RightShoulder,
    LeftUpperArm,
    RightUpperArm,
    LeftLowerArm,
    RightLowerArm,
    LeftHand,
    RightHand,
    LeftToes,
    RightToes,
    LeftEye,
    RightEye,
    Jaw,
    LeftThumbProximal,
    LeftThumbIntermediate,
    LeftThumbDistal,
    LeftIndexProximal,
    LeftIndexIntermediate,
    LeftIndexDistal,
    LeftMiddleProximal,
    LeftMiddleIntermediate,
    LeftMiddleDistal,
    LeftRingProximal,
    LeftRingIntermediate,
    LeftRingDistal,
    LeftLittleProximal,
    LeftLittleIntermediate,
    LeftLittleDistal,
    RightThumbProximal,
    RightThumbIntermediate,
    RightThumbDistal,
    RightIndexProximal,
    RightIndexIntermediate,
    RightIndexDistal,
    RightMiddleProximal,
    RightMiddleIntermediate,
    RightMiddleDistal,
    RightRingProximal,
    RightRingIntermediate,
    RightRingDistal,
    RightLittleProximal,
    RightLittleIntermediate,
    RightLittleDistal,
    UpperChest,
);

/// Body side, the person's own.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    pub const BOTH: [Side; 2] = [Side::Left, Side::Right];

    pub fn other(self) -> Side {
        match self {
            Side::Left => Side::Right,
            Side::Right => Side::Left,
        }
    }

    /// +1 for the right side, −1 for the left (the sign of x in the character frame).
    pub fn sign(self) -> f32 {
        match self {
            Side::Left => -1.0,
            Side::Right => 1.0,
        }
    }

    /// First muscle of this side's arm block (Shoulder Down-Up).
    pub fn arm_muscles(self) -> usize {
        match self {
            Side::Left => super::muscles::idx::LEFT_ARM,
            Side::Right => super::muscles::idx::RIGHT_ARM,
        }
    }

    /// First muscle of this side's finger block (Thumb 1 Stretched).
    pub fn finger_muscles(self) -> usize {
        match self {
            Side::Left => super::muscles::idx::LEFT_FINGERS,
            Side::Right => super::muscles::idx::RIGHT_FINGERS,
        }
    }

    /// First muscle of this side's leg block (Upper Leg Front-Back).
    pub fn leg_muscles(self) -> usize {
        match self {
            Side::Left => super::muscles::idx::LEFT_LEG,
            Side::Right => super::muscles::idx::RIGHT_LEG,
        }
    }
}

/// The five digits, in Unity's order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Finger {
    Thumb,
    Index,
    Middle,
    Ring,
    Little,
}

impl Finger {
    pub const ALL: [Finger; 5] = [Finger::Thumb, Finger::Index, Finger::Middle, Finger::Ring, Finger::Little];
}

impl Bone {
    /// Every bone, in `HumanBodyBones` order.
    pub const ALL: [Bone; BONES] = {
        let mut out = [Bone::Hips; BONES];
        let mut i = 0;
        while i < BONES {
            out[i] = Bone::from_index_const(i);
            i += 1;
        }
        out
    };

    const fn from_index_const(i: usize) -> Bone {
        assert!(i < BONES);
        // SAFETY: `Bone` is `repr(u8)` with the contiguous discriminants 0..BONES.
        unsafe { std::mem::transmute::<u8, Bone>(i as u8) }
    }

    pub fn from_index(i: usize) -> Option<Bone> {
        (i < BONES).then(|| Bone::from_index_const(i))
    }

    pub const fn index(self) -> usize {
        self as usize
    }

    /// Unity's name of the bone (`HumanBodyBones` member name).
    pub fn name(self) -> &'static str {
        BONE_NAMES[self.index()]
    }

    /// The finger bone of a side, digit and phalanx (0 proximal, 1 intermediate, 2 distal).
    pub fn finger(side: Side, finger: Finger, phalanx: usize) -> Bone {
        assert!(phalanx < 3);
        let base = match side {
            Side::Left => Bone::LeftThumbProximal.index(),
            Side::Right => Bone::RightThumbProximal.index(),
        };
        Bone::from_index_const(base + 3 * finger as usize + phalanx)
    }

    pub fn hand(side: Side) -> Bone {
        match side {
            Side::Left => Bone::LeftHand,
            Side::Right => Bone::RightHand,
        }
    }

    pub fn lower_arm(side: Side) -> Bone {
        match side {
            Side::Left => Bone::LeftLowerArm,
            Side::Right => Bone::RightLowerArm,
        }
    }

    pub fn upper_arm(side: Side) -> Bone {
        match side {
            Side::Left => Bone::LeftUpperArm,
            Side::Right => Bone::RightUpperArm,
        }
    }

    /// The bone's parent in the humanoid hierarchy (`None` for the hips).
    pub fn parent(self) -> Option<Bone> {
        use Bone::*;
        Some(match self {
            Hips => return None,
            Spine | LeftUpperLeg | RightUpperLeg => Hips,
            Chest => Spine,
            UpperChest => Chest,
            Neck | LeftShoulder | RightShoulder => UpperChest,
            Head => Neck,
            LeftEye | RightEye | Jaw => Head,
            LeftUpperArm => LeftShoulder,
            RightUpperArm => RightShoulder,
            LeftLowerArm => LeftUpperArm,
            RightLowerArm => RightUpperArm,
            LeftHand => LeftLowerArm,
            RightHand => RightLowerArm,
            LeftLowerLeg => LeftUpperLeg,
            RightLowerLeg => RightUpperLeg,
            LeftFoot => LeftLowerLeg,
            RightFoot => RightLowerLeg,
            LeftToes => LeftFoot,
            RightToes => RightFoot,
            b => {
                let i = b.index();
                let (base, hand) = if i < RightThumbProximal.index() {
                    (LeftThumbProximal.index(), LeftHand)
                } else {
                    (RightThumbProximal.index(), RightHand)
                };
                if (i - base) % 3 == 0 { hand } else { Bone::from_index_const(i - 1) }
            }
        })
    }

    /// The side a bone belongs to (`None` for the midline).
    pub fn side(self) -> Option<Side> {
        let n = self.name();
        if n.starts_with("Left") {
            Some(Side::Left)
        } else if n.starts_with("Right") {
            Some(Side::Right)
        } else {
            None
        }
    }

    /// The same bone on the other side (midline bones map to themselves).
    pub fn mirror(self) -> Bone {
        let n = self.name();
        let other = if let Some(rest) = n.strip_prefix("Left") {
            format!("Right{rest}")
        } else if let Some(rest) = n.strip_prefix("Right") {
            format!("Left{rest}")
        } else {
            return self;
        };
        Bone::ALL.into_iter().find(|b| b.name() == other).expect("every side bone has a mirror")
    }
}

/// Every bone, parents before children.
pub const EVAL_ORDER: [Bone; BONES] = {
    use Bone::*;
    [
        Hips,
        Spine,
        Chest,
        UpperChest,
        Neck,
        Head,
        LeftEye,
        RightEye,
        Jaw,
        LeftShoulder,
        LeftUpperArm,
        LeftLowerArm,
        LeftHand,
        LeftThumbProximal,
        LeftThumbIntermediate,
        LeftThumbDistal,
        LeftIndexProximal,
        LeftIndexIntermediate,
        LeftIndexDistal,
        LeftMiddleProximal,
        LeftMiddleIntermediate,
        LeftMiddleDistal,
        LeftRingProximal,
        LeftRingIntermediate,
        LeftRingDistal,
        LeftLittleProximal,
        LeftLittleIntermediate,
        LeftLittleDistal,
        RightShoulder,
        RightUpperArm,
        RightLowerArm,
        RightHand,
        RightThumbProximal,
        RightThumbIntermediate,
        RightThumbDistal,
        RightIndexProximal,
        RightIndexIntermediate,
        RightIndexDistal,
        RightMiddleProximal,
        RightMiddleIntermediate,
        RightMiddleDistal,
        RightRingProximal,
        RightRingIntermediate,
        RightRingDistal,
        RightLittleProximal,
        RightLittleIntermediate,
        RightLittleDistal,
        LeftUpperLeg,
        LeftLowerLeg,
        LeftFoot,
        LeftToes,
        RightUpperLeg,
        RightLowerLeg,
        RightFoot,
        RightToes,
    ]
};

/// One muscle acting on a bone: its index and the (signed, unit, bone-local) axis that a
/// positive value turns about.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MuscleAxis {
    pub muscle: usize,
    pub axis: Vector3<f32>,
}

/// A bone's rest geometry and muscle axes.
#[derive(Clone, Copy, Debug)]
pub struct BoneDef {
    pub parent: Option<Bone>,
    /// From the parent's joint to this joint, in the parent's frame (T-pose = character axes).
    pub offset: Vector3<f32>,
    /// From this joint to the bone's end point, in this bone's frame.
    pub tip: Vector3<f32>,
    /// Rotation relative to the parent at muscle zero.
    pub zero: UnitQuaternion<f32>,
    /// Unit twist axis (along the bone), whether or not a muscle twists it.
    pub twist_axis: Vector3<f32>,
    pub twist: Option<MuscleAxis>,
    pub swing: [Option<MuscleAxis>; 2],
}

impl BoneDef {
    /// The bone's rotation relative to its parent for these muscle values.
    #[inline]
    pub fn local_rotation(&self, m: &[f32; MUSCLES]) -> UnitQuaternion<f32> {
        // Unity's ZYRoll: the swing quaternion's vector part over its scalar part holds
        // tan(angle / 2) along each swing axis (not an exponential map: the two differ by up
        // to ~10° when both swing muscles act), and the twist comes after.
        let mut tan_half = Vector3::zeros();
        for s in self.swing.iter().flatten() {
            tan_half += s.axis * (0.5 * muscle_degrees(s.muscle, m[s.muscle]).to_radians()).tan();
        }
        let mut q = self.zero;
        if tan_half != Vector3::zeros() {
            q *= UnitQuaternion::from_quaternion(Quaternion::from_parts(1.0, tan_half));
        }
        if let Some(t) = self.twist {
            let a = muscle_degrees(t.muscle, m[t.muscle]).to_radians();
            if a != 0.0 {
                q *= UnitQuaternion::from_scaled_axis(t.axis * a);
            }
        }
        q
    }

    fn muscles(&self) -> impl Iterator<Item = MuscleAxis> + '_ {
        self.twist.iter().chain(self.swing.iter().flatten()).copied()
    }
}

/// The skeleton of one person: bone geometry scaled to a body height.
#[derive(Clone, Debug)]
pub struct Skeleton {
    height: f32,
    bones: [BoneDef; BONES],
    /// Points on the soles (foot frame: heel; toes frame: ball, tip) that the floor touches.
    sole_foot: Vector3<f32>,
    sole_toes: [Vector3<f32>; 2],
}

/// Reference body height the proportions below are written for.
pub const REFERENCE_HEIGHT: f32 = 1.70;

/// Mirror of a position/direction through the body's midplane.
fn mirror_p(v: Vector3<f32>) -> Vector3<f32> {
    Vector3::new(-v.x, v.y, v.z)
}

/// Mirror of a rotation axis (an axial vector) through the midplane: the mirrored motion turns
/// by the same angle about this axis.
fn mirror_a(v: Vector3<f32>) -> Vector3<f32> {
    Vector3::new(v.x, -v.y, -v.z)
}

/// Left-side muscle for a right-side one.
fn left_muscle(right: usize) -> usize {
    match right {
        17 | 18 => right - 2,
        29..=36 => right - 8,
        46..=54 => right - 9,
        75..=94 => right - 20,
        _ => panic!("muscle {right} is not a right-side muscle"),
    }
}

/// Bone definitions at a body's scale (lengths given for the reference height).
struct Defs {
    scale: f32,
}

impl Defs {
    /// A bone under `parent`, at `offset` from its joint, reaching `tip`; no muscle yet.
    fn bone(&self, parent: Bone, offset: Vector3<f32>, tip: Vector3<f32>) -> BoneDef {
        BoneDef {
            parent: Some(parent),
            offset: offset * self.scale,
            tip: tip * self.scale,
            zero: UnitQuaternion::identity(),
            twist_axis: tip.normalize(),
            twist: None,
            swing: [None, None],
        }
    }
}

/// Muscle `muscle` turning about `axis`.
fn ma(muscle: usize, axis: Vector3<f32>) -> Option<MuscleAxis> {
    Some(MuscleAxis { muscle, axis: axis.normalize() })
}

fn v(x: f32, y: f32, z: f32) -> Vector3<f32> {
    Vector3::new(x, y, z)
}

/// The spine chain: twist about +y (+ = turn right), front-back about −x (+ = back),
/// left-right about −z (+ = lean right); and the jaw.
fn spine_and_head(d: &Defs) -> Vec<(Bone, BoneDef)> {
    use Bone::*;
    let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
    // bone, parent, offset, tip, its front-back muscle (left-right and twist follow it)
    let spine = [
        (Spine, Hips, 0.07, 0.13, idx::SPINE_FRONT_BACK),
        (Chest, Spine, 0.13, 0.12, idx::CHEST_FRONT_BACK),
        (UpperChest, Chest, 0.12, 0.17, idx::UPPER_CHEST_FRONT_BACK),
        (Neck, UpperChest, 0.17, 0.085, idx::NECK_NOD),
        (Head, Neck, 0.085, 0.17, idx::HEAD_NOD),
    ];
    let mut out: Vec<(Bone, BoneDef)> = spine
        .into_iter()
        .map(|(b, p, off, tip, m)| {
            let mut def = d.bone(p, v(0.0, off, 0.0), v(0.0, tip, 0.0));
            def.twist = ma(m + 2, y);
            def.swing = [ma(m, -x), ma(m + 1, -z)];
            (b, def)
        })
        .collect();
    let mut jaw = d.bone(Head, v(0.0, 0.005, 0.02), v(0.0, -0.055, 0.065));
    jaw.twist_axis = z;
    jaw.swing = [ma(idx::JAW_CLOSE, -x), ma(idx::JAW_LEFT_RIGHT, y)];
    out.push((Jaw, jaw));
    out
}

/// The right eye, shoulder, upper and lower arm, and hand.
fn right_eye_and_arm(d: &Defs) -> Vec<(Bone, BoneDef)> {
    use Bone::*;
    let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
    let arm = |k: usize| idx::RIGHT_ARM + k;
    let mut eye = d.bone(Head, v(0.032, 0.075, 0.082), v(0.0, 0.0, 0.012));
    eye.swing = [ma(idx::RIGHT_EYE_DOWN_UP, -x), ma(idx::RIGHT_EYE_IN_OUT, y)];
    let mut sh = d.bone(UpperChest, v(0.025, 0.11, 0.0), v(0.145, 0.01, 0.0));
    sh.twist_axis = x;
    sh.swing = [ma(arm(idx::SHOULDER_DOWN_UP), z), ma(arm(idx::SHOULDER_FRONT_BACK), y)];
    let mut ua = d.bone(RightShoulder, v(0.145, 0.01, 0.0), v(0.28, 0.0, 0.0));
    // Unity's upper-arm neutral: 48.65° about (0, 0.593, 0.805) in its axes.
    ua.zero = UnitQuaternion::from_axis_angle(&Unit::new_normalize(v(0.0, -0.593, -0.805)), 48.65f32.to_radians());
    ua.twist = ma(arm(idx::ARM_TWIST), -x);
    ua.swing = [ma(arm(idx::ARM_DOWN_UP), z), ma(arm(idx::ARM_FRONT_BACK), y)];
    let mut la = d.bone(RightUpperArm, v(0.28, 0.0, 0.0), v(0.25, 0.0, 0.0));
    la.zero = deg(v(0.0, -80.0, 0.0));
    la.twist = ma(arm(idx::FOREARM_TWIST), -x);
    la.swing = [ma(arm(idx::FOREARM_STRETCH), y), None];
    let mut hand = d.bone(RightLowerArm, v(0.25, 0.0, 0.0), v(0.097, 0.0, 0.0));
    // Hand In-Out +1 bends the hand towards the thumb (palm down: forward), "out" as
    // abduction, the sense of Eye and Upper Leg In-Out here; the GOND recording holds it at
    // 0.11 while pointing, too little to tell the sign from its rays.
    hand.swing = [ma(arm(idx::HAND_DOWN_UP), z), ma(arm(idx::HAND_IN_OUT), -y)];
    vec![(RightEye, eye), (RightShoulder, sh), (RightUpperArm, ua), (RightLowerArm, la), (RightHand, hand)]
}

/// The right hand's four fingers: knuckle offsets from the wrist and phalanx lengths (palm
/// down, thumb forward). Stretched about +z (+ = straight), spread about ∓y (index/middle fan
/// towards the thumb, ring/little towards the little-finger side).
fn right_fingers(d: &Defs) -> Vec<(Bone, BoneDef)> {
    const ZERO_FLEX: [f32; 3] = [40.0, 45.0, 40.0];
    let fingers = [
        (Finger::Index, v(0.094, 0.0, 0.028), [0.043, 0.025, 0.021], -1.0),
        (Finger::Middle, v(0.097, 0.0, 0.008), [0.047, 0.029, 0.022], -1.0),
        (Finger::Ring, v(0.092, 0.0, -0.012), [0.044, 0.027, 0.021], 1.0),
        (Finger::Little, v(0.083, -0.003, -0.031), [0.034, 0.020, 0.019], 1.0),
    ];
    let z = Vector3::z();
    let mut out = Vec::with_capacity(12);
    for (f, knuckle, len, spread_sign) in fingers {
        // its four muscles: 1 Stretched, Spread, 2 Stretched, 3 Stretched
        let m0 = idx::RIGHT_FINGERS + 4 * f as usize;
        let (mut prev, mut off) = (Bone::RightHand, knuckle);
        for (ph, zero_flex) in ZERO_FLEX.into_iter().enumerate() {
            let b = Bone::finger(Side::Right, f, ph);
            let mut def = d.bone(prev, off, v(len[ph], 0.0, 0.0));
            def.zero = deg(v(0.0, 0.0, -zero_flex));
            def.swing = match ph {
                0 => [ma(m0, z), ma(m0 + 1, v(0.0, spread_sign, 0.0))],
                _ => [ma(m0 + 1 + ph, z), None],
            };
            out.push((b, def));
            (prev, off) = (b, v(len[ph], 0.0, 0.0));
        }
    }
    out
}

/// The right thumb: it leaves the wrist forward and a little under the palm, curls across the
/// palm towards the little finger, and spreads away from the palm.
fn right_thumb(d: &Defs) -> Vec<(Bone, BoneDef)> {
    let dt = v(0.78, -0.28, 0.56).normalize();
    let curl_to = v(0.05, -0.35, -0.94).normalize();
    let flex = dt.cross(&curl_to).normalize();
    let ext = -flex;
    let mut spread = dt.cross(&ext).normalize();
    if spread.cross(&dt).y > 0.0 {
        spread = -spread;
    }
    let m0 = idx::RIGHT_FINGERS;
    let (mut prev, mut off) = (Bone::RightHand, v(0.022, -0.012, 0.022));
    let mut out = Vec::with_capacity(3);
    for (ph, len) in [0.046, 0.032, 0.028].into_iter().enumerate() {
        let b = Bone::finger(Side::Right, Finger::Thumb, ph);
        let mut def = d.bone(prev, off, dt * len);
        def.twist_axis = dt;
        if ph == 0 {
            def.swing = [ma(m0, ext), ma(m0 + 1, spread)];
        } else {
            def.zero = UnitQuaternion::from_scaled_axis(ext * (-30.0f32).to_radians());
            def.swing = [ma(m0 + 1 + ph, ext), None];
        }
        out.push((b, def));
        (prev, off) = (b, dt * len);
    }
    out
}

/// The right leg: front-back about +x (+ = back), in-out about +z (+ = out), twist about +y
/// (+ = out); knee stretch about −x (+ = straight); foot/toes up-down about +x (+ = down).
fn right_leg(d: &Defs) -> Vec<(Bone, BoneDef)> {
    use Bone::*;
    let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
    let leg = |k: usize| idx::RIGHT_LEG + k;
    let mut ul = d.bone(Hips, v(0.09, -0.065, 0.0), v(0.0, -0.42, 0.0));
    ul.zero = deg(v(-30.0, 0.0, 0.0));
    ul.twist = ma(leg(idx::UPPER_LEG_TWIST), y);
    ul.swing = [ma(leg(idx::UPPER_LEG_FRONT_BACK), x), ma(leg(idx::UPPER_LEG_IN_OUT), z)];
    let mut ll = d.bone(RightUpperLeg, v(0.0, -0.42, 0.0), v(0.0, -0.40, 0.0));
    ll.zero = deg(v(80.0, 0.0, 0.0));
    ll.twist = ma(leg(idx::LOWER_LEG_TWIST), y);
    ll.swing = [ma(leg(idx::LOWER_LEG_STRETCH), -x), None];
    let mut foot = d.bone(RightLowerLeg, v(0.0, -0.40, 0.0), v(0.0, -0.045, 0.13));
    foot.twist_axis = z;
    foot.swing = [ma(leg(idx::FOOT_UP_DOWN), x), ma(leg(idx::FOOT_TWIST), y)];
    let mut toes = d.bone(RightFoot, v(0.0, -0.045, 0.13), v(0.0, 0.0, 0.055));
    toes.swing = [ma(leg(idx::TOES_UP_DOWN), x), None];
    vec![(RightUpperLeg, ul), (RightLowerLeg, ll), (RightFoot, foot), (RightToes, toes)]
}

/// A right-side bone's left twin: mirrored across the body's plane, on the left's muscles.
fn mirrored(d: &BoneDef) -> BoneDef {
    let mirror_axis =
        |m: Option<MuscleAxis>| m.map(|m| MuscleAxis { muscle: left_muscle(m.muscle), axis: mirror_a(m.axis) });
    let (axis, angle) = d.zero.axis_angle().map(|(a, t)| (a.into_inner(), t)).unwrap_or((Vector3::x(), 0.0));
    BoneDef {
        parent: d.parent.map(Bone::mirror),
        offset: mirror_p(d.offset),
        tip: mirror_p(d.tip),
        zero: UnitQuaternion::from_scaled_axis(mirror_a(axis) * angle),
        twist_axis: mirror_p(d.twist_axis),
        twist: mirror_axis(d.twist),
        swing: [mirror_axis(d.swing[0]), mirror_axis(d.swing[1])],
    }
}

fn deg(v: Vector3<f32>) -> UnitQuaternion<f32> {
    UnitQuaternion::from_scaled_axis(v.map(f32::to_radians))
}

impl Skeleton {
    /// An adult skeleton of `height` metres (crown to sole): the spine and head, then the right
    /// side (an eye, the arm, the fingers, the thumb, the leg) and its mirror image.
    pub fn new(height: f32) -> Skeleton {
        let d = Defs { scale: height / REFERENCE_HEIGHT };
        let mut bones = [BoneDef {
            parent: None,
            offset: Vector3::zeros(),
            tip: Vector3::new(0.0, 0.07, 0.0) * d.scale,
            zero: UnitQuaternion::identity(),
            twist_axis: Vector3::y(),
            twist: None,
            swing: [None, None],
        }; BONES];
        for (b, def) in spine_and_head(&d) {
            bones[b.index()] = def;
        }
        let right = [right_eye_and_arm(&d), right_fingers(&d), right_thumb(&d), right_leg(&d)].concat();
        for (b, def) in right {
            bones[b.mirror().index()] = mirrored(&def);
            bones[b.index()] = def;
        }
        let s = d.scale;
        Skeleton {
            height,
            bones,
            sole_foot: Vector3::new(0.0, -0.075, -0.045) * s,
            sole_toes: [Vector3::new(0.0, -0.03, 0.0) * s, Vector3::new(0.0, -0.03, 0.055) * s],
        }
    }

    pub fn height(&self) -> f32 {
        self.height
    }

    pub fn bone_def(&self, b: Bone) -> &BoneDef {
        &self.bones[b.index()]
    }

    /// The bone and muscle axis that a muscle drives.
    pub fn muscle_axis(&self, muscle: usize) -> (Bone, MuscleAxis) {
        for b in Bone::ALL {
            if let Some(m) = self.bones[b.index()].muscles().find(|m| m.muscle == muscle) {
                return (b, m);
            }
        }
        panic!("muscle {muscle} drives no bone")
    }

    /// Forward kinematics. `root` is the point on the floor under the hips (its y is the floor
    /// height); the person faces `heading(yaw_deg)`; the hips are raised until the lowest sole
    /// point touches the floor.
    pub fn pose(&self, muscles: &[f32; MUSCLES], root: Point3<f32>, yaw_deg: f32) -> SkeletonPose {
        let mut p = SkeletonPose {
            rot: [UnitQuaternion::identity(); BONES],
            pos: [Point3::origin(); BONES],
            tip: [Point3::origin(); BONES],
        };
        let yaw = yaw_rotation(yaw_deg);
        for b in EVAL_ORDER {
            let i = b.index();
            let d = &self.bones[i];
            let local = d.local_rotation(muscles);
            match d.parent {
                None => {
                    p.rot[i] = yaw * local;
                    p.pos[i] = Point3::new(root.x, 0.0, root.z);
                }
                Some(parent) => {
                    let j = parent.index();
                    p.pos[i] = p.pos[j] + p.rot[j] * d.offset;
                    p.rot[i] = p.rot[j] * local;
                }
            }
        }
        let lift = root.y - self.lowest_sole(&p);
        for i in 0..BONES {
            p.pos[i].y += lift;
            p.tip[i] = p.pos[i] + p.rot[i] * self.bones[i].tip;
        }
        p
    }

    /// World y of the lowest sole point of either foot.
    fn lowest_sole(&self, p: &SkeletonPose) -> f32 {
        let mut lo = f32::INFINITY;
        for (foot, toes) in [(Bone::LeftFoot, Bone::LeftToes), (Bone::RightFoot, Bone::RightToes)] {
            lo = lo.min((p.pos[foot.index()] + p.rot[foot.index()] * self.sole_foot).y);
            for s in &self.sole_toes {
                lo = lo.min((p.pos[toes.index()] + p.rot[toes.index()] * s).y);
            }
        }
        lo
    }

    /// Height of the hips above the floor for these muscles (the lift `pose` applies).
    pub fn hips_height(&self, muscles: &[f32; MUSCLES]) -> f32 {
        self.pose(muscles, Point3::origin(), 0.0).position(Bone::Hips).y
    }

    /// Position and rotation of one bone with the hips at the origin and yaw 0, walking only
    /// the bone's ancestors: the cheap evaluation that inverse kinematics iterates.
    pub fn chain(&self, muscles: &[f32; MUSCLES], bone: Bone) -> (Point3<f32>, UnitQuaternion<f32>) {
        let mut path = [Bone::Hips; 16];
        let mut n = 0;
        let mut b = Some(bone);
        while let Some(x) = b {
            path[n] = x;
            n += 1;
            b = self.bones[x.index()].parent;
        }
        let mut pos = Point3::origin();
        let mut rot = UnitQuaternion::identity();
        for &x in path[..n].iter().rev() {
            let d = &self.bones[x.index()];
            pos += rot * d.offset;
            rot *= d.local_rotation(muscles);
        }
        (pos, rot)
    }
}

/// World transforms of every bone for one frame.
#[derive(Clone, Debug)]
pub struct SkeletonPose {
    rot: [UnitQuaternion<f32>; BONES],
    pos: [Point3<f32>; BONES],
    tip: [Point3<f32>; BONES],
}

impl SkeletonPose {
    /// The bone's frame in the world (origin at its joint; T-pose axes as the character's).
    pub fn bone(&self, b: Bone) -> Isometry3<f32> {
        Isometry3::from_parts(Translation3::from(self.pos[b.index()].coords), self.rot[b.index()])
    }

    /// World position of the bone's joint (its start).
    pub fn position(&self, b: Bone) -> Point3<f32> {
        self.pos[b.index()]
    }

    pub fn rotation(&self, b: Bone) -> UnitQuaternion<f32> {
        self.rot[b.index()]
    }

    /// World position of the bone's end point (for a distal finger bone: the fingertip).
    pub fn tip(&self, b: Bone) -> Point3<f32> {
        self.tip[b.index()]
    }

    /// Unit direction from the bone's joint to its end point.
    pub fn direction(&self, b: Bone) -> Vector3<f32> {
        (self.tip[b.index()] - self.pos[b.index()]).normalize()
    }

    /// Centre of the head (between the ears, at eye height).
    pub fn head_position(&self) -> Point3<f32> {
        // The crown is the head bone's tip; eye height is 44% of the way up from the atlas.
        let h = Bone::Head.index();
        self.pos[h] + (self.tip[h] - self.pos[h]) * 0.44
    }

    /// Where the face points (the head's local +z).
    pub fn head_forward(&self) -> Vector3<f32> {
        self.rot[Bone::Head.index()] * Vector3::z()
    }

    /// The wrist.
    pub fn hand_position(&self, side: Side) -> Point3<f32> {
        self.pos[Bone::hand(side).index()]
    }

    /// Along the hand, wrist towards the middle knuckle.
    pub fn hand_direction(&self, side: Side) -> Vector3<f32> {
        self.direction(Bone::hand(side))
    }

    /// Outward normal of the palm (T-pose: down).
    pub fn palm_normal(&self, side: Side) -> Vector3<f32> {
        self.rot[Bone::hand(side).index()] * -Vector3::y()
    }

    /// Centre of the palm.
    pub fn palm_center(&self, side: Side) -> Point3<f32> {
        let h = Bone::hand(side);
        self.pos[h.index()] + (self.tip[h.index()] - self.pos[h.index()]) * 0.55
    }

    pub fn fingertip(&self, side: Side, finger: Finger) -> Point3<f32> {
        self.tip(Bone::finger(side, finger, 2))
    }

    /// Where the index finger's last segment points.
    pub fn index_direction(&self, side: Side) -> Vector3<f32> {
        self.direction(Bone::finger(side, Finger::Index, 2))
    }

    /// The ray a bone "points" along: the head along its face, every other bone along itself
    /// from its joint (as the original evaluator cast rays from `Transform.forward` of the
    /// head and `Transform.right` of hand and finger bones).
    pub fn ray(&self, b: Bone) -> (Point3<f32>, Vector3<f32>) {
        if b == Bone::Head { (self.position(b), self.head_forward()) } else { (self.position(b), self.direction(b)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::humanoid::muscles::{MUSCLE_NAMES, MUSCLE_RANGES};

    fn zero() -> [f32; MUSCLES] {
        [0.0; MUSCLES]
    }

    fn angle_between(a: Vector3<f32>, b: Vector3<f32>) -> f32 {
        a.normalize().dot(&b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn bone_table_is_consistent() {
        for b in Bone::ALL {
            assert_eq!(Bone::from_index(b.index()), Some(b));
            assert_eq!(b.mirror().mirror(), b);
            if let Some(p) = b.parent() {
                let order = |x: Bone| EVAL_ORDER.iter().position(|&y| y == x).unwrap();
                assert!(order(p) < order(b), "{b:?} evaluated before its parent");
            }
        }
        assert_eq!(Bone::RightIndexDistal.parent(), Some(Bone::RightIndexIntermediate));
        assert_eq!(Bone::LeftLittleProximal.parent(), Some(Bone::LeftHand));
        assert_eq!(Bone::finger(Side::Right, Finger::Ring, 1), Bone::RightRingIntermediate);
        let sk = Skeleton::new(1.7);
        for b in Bone::ALL {
            assert_eq!(sk.bone_def(b).parent, b.parent(), "{b:?}");
        }
        // Every muscle drives exactly one bone axis.
        let mut seen = [0; MUSCLES];
        for b in Bone::ALL {
            for m in sk.bone_def(b).muscles() {
                seen[m.muscle] += 1;
                assert!(m.axis.dot(&sk.bone_def(b).twist_axis).abs() < 1e-5 || Some(m) == sk.bone_def(b).twist);
            }
        }
        assert!(seen.iter().all(|&n| n == 1), "{seen:?}");
    }

    /// All muscles at 0 gives Unity's muscle-zero pose as documented in the module.
    #[test]
    fn muscle_zero_pose() {
        let sk = Skeleton::new(1.7);
        let p = sk.pose(&zero(), Point3::origin(), 0.0);
        // Upper arms: Unity's neutral, 48.65° from the T-pose about (0, 0.593, 0.805) (about
        // 39° below horizontal, 29° forward of the frontal plane), outwards.
        for side in Side::BOTH {
            let d = p.direction(Bone::upper_arm(side));
            let t = deg(Vector3::new(0.0, -0.593, -0.805).normalize() * 48.65) * Vector3::x();
            let expect = Vector3::new(t.x * side.sign(), t.y, t.z);
            assert!(angle_between(d, expect) < 0.5, "{side:?} upper arm {d:?}");
            assert!(d.y < -0.5 && d.z > 0.3 && d.x * side.sign() > 0.4, "{side:?} {d:?}");
            // Elbow bent 80°, forearm forwards.
            let f = p.direction(Bone::lower_arm(side));
            assert!((angle_between(d, f) - 80.0).abs() < 0.5);
            // Torso upright, head facing forward.
        }
        assert!(angle_between(p.direction(Bone::Spine), Vector3::y()) < 1e-3);
        assert!(angle_between(p.head_forward(), Vector3::z()) < 1e-3);
        // Thighs 30° forward, knees bent 80°, feet on the floor.
        for (ul, ll) in [(Bone::LeftUpperLeg, Bone::LeftLowerLeg), (Bone::RightUpperLeg, Bone::RightLowerLeg)] {
            let t = p.direction(ul);
            assert!((angle_between(t, -Vector3::y()) - 30.0).abs() < 0.5 && t.z > 0.0);
            assert!((angle_between(t, p.direction(ll)) - 80.0).abs() < 0.5);
        }
        assert!(p.position(Bone::Hips).y < 0.9, "crouching: hips at {}", p.position(Bone::Hips).y);
        // Fingers half curled.
        let i0 = p.direction(Bone::RightIndexProximal);
        let i1 = p.direction(Bone::RightIndexIntermediate);
        assert!((angle_between(p.hand_direction(Side::Right), i0) - 40.0).abs() < 0.5);
        assert!((angle_between(i0, i1) - 45.0).abs() < 0.5);
    }

    /// The T-pose muscle values give the T-pose (arms horizontal to the sides, legs straight).
    #[test]
    fn t_pose_muscles() {
        let sk = Skeleton::new(1.7);
        let mut m = zero();
        for (i, v) in [
            (21, 0.6),
            (29, 0.6),
            (24, 1.0),
            (32, 1.0),
            (39, 0.4),
            (48, 0.4),
            (40, 0.3),
            (49, 0.3),
            (42, 1.0),
            (51, 1.0),
        ] {
            m[i] = v;
        }
        let p = sk.pose(&m, Point3::origin(), 0.0);
        assert!(angle_between(p.direction(Bone::RightUpperArm), Vector3::x()) < 1.0);
        assert!(angle_between(p.direction(Bone::LeftLowerArm), -Vector3::x()) < 1.0);
        assert!(angle_between(p.direction(Bone::LeftLowerLeg), -Vector3::y()) < 1.0);
        assert!((p.tip(Bone::Head).y - 1.70).abs() < 0.02, "crown at {}", p.tip(Bone::Head).y);
        let span = p.fingertip(Side::Right, Finger::Middle).x - p.fingertip(Side::Left, Finger::Middle).x;
        assert!(span > 1.5 && span < 1.9, "arm span {span}");
    }

    /// Every muscle at ±1 turns its bone, relative to muscle zero, by the documented limit
    /// about its documented axis; the left muscle does the mirror image of the right.
    #[test]
    fn each_muscle_reaches_its_limit_about_its_axis() {
        let sk = Skeleton::new(1.7);
        let p0 = sk.pose(&zero(), Point3::origin(), 0.0);
        for i in 0..MUSCLES {
            let (bone, axis) = sk.muscle_axis(i);
            for v in [-1.0f32, 1.0] {
                let mut m = zero();
                m[i] = v;
                let p = sk.pose(&m, Point3::origin(), 0.0);
                let parent = bone.parent().unwrap();
                let local = p.rotation(parent).inverse() * p.rotation(bone);
                let local0 = p0.rotation(parent).inverse() * p0.rotation(bone);
                let rel = local0.inverse() * local;
                let want = if v > 0.0 { MUSCLE_RANGES[i].1 } else { -MUSCLE_RANGES[i].0 };
                assert!(
                    (rel.angle().to_degrees() - want).abs() < 0.01,
                    "{} at {v}: {}°",
                    MUSCLE_NAMES[i],
                    rel.angle().to_degrees()
                );
                let got = rel.axis().unwrap().into_inner() * v.signum();
                assert!((got - axis.axis).norm() < 1e-3, "{} at {v}: axis {got:?} vs {:?}", MUSCLE_NAMES[i], axis.axis);
                // Mirror check: the left twin turns about the mirrored axis.
                if bone.side() == Some(Side::Right) {
                    let (lb, la) = sk.muscle_axis(left_muscle(i));
                    assert_eq!(lb, bone.mirror());
                    assert!((la.axis - mirror_a(axis.axis)).norm() < 1e-6);
                }
            }
        }
    }

    /// Anatomical meaning of the muscles that gestures depend on, checked on world directions.
    #[test]
    fn muscles_move_the_way_their_names_say() {
        let sk = Skeleton::new(1.7);
        let dir = |i: usize, v: f32, b: Bone| {
            let mut m = zero();
            m[i] = v;
            sk.pose(&m, Point3::origin(), 0.0).direction(b)
        };
        let head = |i: usize, v: f32| {
            let mut m = zero();
            m[i] = v;
            sk.pose(&m, Point3::origin(), 0.0).head_forward()
        };
        // Arm Down-Up +1 raises the arm (both sides); Front-Back −1 swings it forward (at −0.5
        // straight ahead, at −1 across the chest) and +1 back.
        for (du, fb, b) in [(48, 49, Bone::RightUpperArm), (39, 40, Bone::LeftUpperArm)] {
            assert!(dir(du, 1.0, b).y > 0.8 && dir(du, -1.0, b).y < -0.9);
            assert!(dir(fb, -0.5, b).z > 0.9 && dir(fb, 1.0, b).z < -0.9);
            assert!(dir(fb, -1.0, b).x * dir(fb, 1.0, b).x < 0.0, "crosses the midline");
        }
        // Right arm is on +x, left on −x.
        assert!(dir(48, 0.4, Bone::RightUpperArm).x > 0.7 && dir(39, 0.4, Bone::LeftUpperArm).x < -0.7);
        // Forearm Stretch +1 straightens the elbow.
        let mut m = zero();
        m[51] = 1.0;
        let p = sk.pose(&m, Point3::origin(), 0.0);
        assert!(angle_between(p.direction(Bone::RightUpperArm), p.direction(Bone::RightLowerArm)) < 0.1);
        // Head Turn −1 looks to the person's left (−x), Nod +1 looks up.
        assert!(head(14, -1.0).x < -0.6 && head(14, 1.0).x > 0.6);
        assert!(head(11, -1.0).x < -0.6);
        assert!(head(12, 1.0).y > 0.6 && head(9, -1.0).y < -0.6);
        // Spine Front-Back −1 bends forward.
        assert!(dir(0, -1.0, Bone::Spine).z > 0.6);
        // Spine Left-Right +1 leans right.
        assert!(dir(1, 1.0, Bone::Spine).x > 0.6);
        // Upper Leg In-Out +1 spreads the legs; Front-Back −1 lifts the thigh forward.
        assert!(dir(30, 1.0, Bone::RightUpperLeg).x > 0.6 && dir(22, 1.0, Bone::LeftUpperLeg).x < -0.6);
        assert!(
            dir(29, -1.0, Bone::RightUpperLeg).z > 0.8 && dir(29, -1.0, Bone::RightUpperLeg).y > 0.4,
            "120° hip flexion"
        );
        // Fingers: +1 straight (in line with the hand), −1 curled towards the palm.
        let mut m = zero();
        m[79] = 1.0;
        m[81] = 1.0;
        m[82] = 1.0;
        let p = sk.pose(&m, Point3::origin(), 0.0);
        let hand = p.hand_direction(Side::Right);
        assert!(angle_between(hand, p.index_direction(Side::Right)) < 20.0);
        let mut m = zero();
        for k in [79, 81, 82] {
            m[k] = -1.0;
        }
        let p = sk.pose(&m, Point3::origin(), 0.0);
        let tip = p.fingertip(Side::Right, Finger::Index) - p.position(Bone::RightHand);
        assert!(tip.dot(&p.palm_normal(Side::Right)) > 0.02, "curled index tip lies on the palm side");
        // Index Spread +1 fans the index away from the middle finger (towards the thumb, +z
        // in the hand's own frame), on both hands.
        for (i, side) in [(80, Side::Right), (60, Side::Left)] {
            let local = |v: f32| {
                let mut m = zero();
                m[i] = v;
                let p = sk.pose(&m, Point3::origin(), 0.0);
                p.rotation(Bone::hand(side)).inverse() * p.direction(Bone::finger(side, Finger::Index, 0))
            };
            assert!(local(1.0).z > local(-1.0).z + 0.3, "{side:?}");
        }
    }

    #[test]
    fn yaw_and_root_place_the_person() {
        let sk = Skeleton::new(1.7);
        let mut m = zero();
        m[21] = 0.6;
        m[29] = 0.6;
        m[24] = 1.0;
        m[32] = 1.0;
        let root = Point3::new(2.0, 0.0, -1.0);
        let p = sk.pose(&m, root, 90.0);
        // Facing +x; the person's right is −z.
        assert!((p.head_forward() - Vector3::x()).norm() < 1e-4);
        let r = p.position(Bone::RightUpperArm) - p.position(Bone::LeftUpperArm);
        assert!(r.z < -0.3 && r.x.abs() < 1e-4);
        let h = p.position(Bone::Hips);
        assert!((h.x - 2.0).abs() < 1e-4 && (h.z + 1.0).abs() < 1e-4);
        assert!((h.y - 0.96).abs() < 0.01, "standing hips at {}", h.y);
        // Scaling the body scales the height.
        let tall = Skeleton::new(1.9).pose(&m, root, 90.0);
        assert!((tall.tip(Bone::Head).y - 1.9).abs() < 0.03);
    }

    #[test]
    fn chain_matches_full_pose() {
        let sk = Skeleton::new(1.7);
        let mut m = zero();
        for (i, v) in m.iter_mut().enumerate() {
            *v = ((i * 37 % 19) as f32 / 9.0 - 1.0) * 0.8;
        }
        let p = sk.pose(&m, Point3::origin(), 0.0);
        let lift = p.position(Bone::Hips).coords;
        for b in [Bone::RightIndexDistal, Bone::Head, Bone::LeftHand] {
            let (pos, rot) = sk.chain(&m, b);
            assert!((pos + lift - p.position(b)).norm() < 1e-5);
            assert!(rot.angle_to(&p.rotation(b)) < 1e-5);
        }
    }
}
