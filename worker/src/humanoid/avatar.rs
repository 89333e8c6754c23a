//! The person as the robot sees it: capsule-like limbs, clothes, a head whose face shows which
//! way it looks, and hands with separate fingers, all as [`Part`]s with id [`ID_HUMAN`].

use nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

use super::skeleton::{BONES, Bone, Finger, REFERENCE_HEIGHT, Side, Skeleton, SkeletonPose};
use crate::geometry::{ID_HUMAN, Material, Part, Shape};

/// How the hair is cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HairStyle {
    Short,
    Long,
    Shaved,
}

/// Colours and cut of one person (linear RGB).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Appearance {
    pub skin: [f32; 3],
    pub hair: [f32; 3],
    pub hair_style: HairStyle,
    pub shirt: [f32; 3],
    pub long_sleeves: bool,
    pub trousers: [f32; 3],
    pub shoes: [f32; 3],
}

fn srgb(c: [u8; 3]) -> [f32; 3] {
    c.map(|v| {
        let v = v as f32 / 255.0;
        if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
    })
}

const SKIN: [[u8; 3]; 7] =
    [[255, 219, 190], [241, 194, 160], [224, 172, 138], [198, 134, 100], [160, 105, 75], [120, 78, 55], [90, 56, 38]];
const HAIR: [[u8; 3]; 6] = [[30, 25, 22], [60, 40, 28], [100, 68, 42], [190, 160, 100], [140, 60, 35], [150, 150, 150]];
const SHIRT: [[u8; 3]; 12] = [
    [200, 40, 40],
    [40, 80, 170],
    [40, 130, 70],
    [230, 200, 60],
    [240, 240, 240],
    [60, 60, 60],
    [150, 80, 160],
    [240, 130, 50],
    [90, 160, 200],
    [170, 30, 80],
    [20, 120, 130],
    [200, 180, 150],
];
const TROUSERS: [[u8; 3]; 6] = [[40, 50, 90], [30, 30, 30], [110, 90, 70], [80, 80, 85], [150, 130, 100], [60, 80, 60]];
const SHOES: [[u8; 3]; 4] = [[30, 30, 30], [90, 60, 40], [230, 230, 230], [60, 60, 90]];

impl Default for Appearance {
    fn default() -> Self {
        Appearance {
            skin: srgb(SKIN[2]),
            hair: srgb(HAIR[1]),
            hair_style: HairStyle::Short,
            shirt: srgb(SHIRT[1]),
            long_sleeves: false,
            trousers: srgb(TROUSERS[0]),
            shoes: srgb(SHOES[0]),
        }
    }
}

impl Appearance {
    /// A person's look drawn from `seed` (same seed, same look).
    pub fn seeded(seed: u64) -> Appearance {
        let mut r = farm::seed::rng(seed, &[0xA77E_A2A4]);
        let pick = |r: &mut rand_chacha::ChaCha8Rng, n: usize| r.random_range(0..n);
        Appearance {
            skin: srgb(SKIN[pick(&mut r, SKIN.len())]),
            hair: srgb(HAIR[pick(&mut r, HAIR.len())]),
            hair_style: [HairStyle::Short, HairStyle::Short, HairStyle::Long, HairStyle::Shaved][pick(&mut r, 4)],
            shirt: srgb(SHIRT[pick(&mut r, SHIRT.len())]),
            long_sleeves: r.random_bool(0.5),
            trousers: srgb(TROUSERS[pick(&mut r, TROUSERS.len())]),
            shoes: srgb(SHOES[pick(&mut r, SHOES.len())]),
        }
    }
}

/// Per-bone thickness of the limb drawn along it (0: not drawn as a segment).
fn segment_radius(b: Bone) -> f32 {
    use Bone::*;
    match b {
        LeftUpperArm | RightUpperArm => 0.045,
        LeftLowerArm | RightLowerArm => 0.037,
        LeftUpperLeg | RightUpperLeg => 0.07,
        LeftLowerLeg | RightLowerLeg => 0.052,
        Neck => 0.05,
        _ => match finger_of(b) {
            // Fingers stay at least 1.6 cm thick so that they show at 224 px from 2–3 m.
            Some((Finger::Thumb, ph)) => [0.0115, 0.0105, 0.0095][ph],
            Some((Finger::Index, ph)) => [0.0095, 0.009, 0.0085][ph],
            Some((Finger::Middle, ph)) => [0.0098, 0.0092, 0.0086][ph],
            Some((Finger::Ring, ph)) => [0.0093, 0.0088, 0.0083][ph],
            Some((Finger::Little, ph)) => [0.0086, 0.0083, 0.008][ph],
            None => 0.0,
        },
    }
}

fn finger_of(b: Bone) -> Option<(Finger, usize)> {
    let i = b.index();
    let base = if (Bone::LeftThumbProximal.index()..=Bone::LeftLittleDistal.index()).contains(&i) {
        Bone::LeftThumbProximal.index()
    } else if (Bone::RightThumbProximal.index()..=Bone::RightLittleDistal.index()).contains(&i) {
        Bone::RightThumbProximal.index()
    } else {
        return None;
    };
    Some((Finger::ALL[(i - base) / 3], (i - base) % 3))
}

/// What the avatar needs besides the skeleton: per-bone rotations that stand a cylinder (+y)
/// along each bone, and the body scale.
#[derive(Clone, Debug)]
pub(super) struct AvatarShape {
    align: [UnitQuaternion<f32>; BONES],
    scale: f32,
}

impl AvatarShape {
    pub(super) fn new(sk: &Skeleton) -> AvatarShape {
        let mut align = [UnitQuaternion::identity(); BONES];
        for b in Bone::ALL {
            let tip = sk.bone_def(b).tip;
            align[b.index()] = UnitQuaternion::rotation_between(&Vector3::y(), &tip)
                .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI));
        }
        AvatarShape { align, scale: sk.height() / REFERENCE_HEIGHT }
    }

    /// The person's parts in `look` at pose `p`: torso, head, face, arms and hands, legs and shoes.
    pub(super) fn parts(&self, look: &Appearance, p: &SkeletonPose) -> Vec<Part> {
        let mut d = Dresser { s: self.scale, align: &self.align, look, p, out: Vec::with_capacity(64) };
        d.torso();
        d.head();
        d.face();
        d.arms();
        d.legs();
        d.out
    }
}

/// Puts the parts on one pose, in the avatar's scale.
struct Dresser<'a> {
    s: f32,
    align: &'a [UnitQuaternion<f32>; BONES],
    look: &'a Appearance,
    p: &'a SkeletonPose,
    out: Vec<Part>,
}

const FAB: Material = Material::Fabric;
const SKIN_M: Material = Material::Skin;

fn v(x: f32, y: f32, z: f32) -> Vector3<f32> {
    Vector3::new(x, y, z)
}

impl Dresser<'_> {
    fn part(
        &mut self,
        shape: Shape,
        center: Point3<f32>,
        rotation: UnitQuaternion<f32>,
        he: Vector3<f32>,
        color: [f32; 3],
        material: Material,
    ) {
        self.out.push(Part { shape, center, rotation, half_extents: he, color, material, id: ID_HUMAN, solid: true });
    }

    /// A cylinder along bone `b`, a little longer than the bone so that bent joints close.
    fn limb(&mut self, b: Bone, color: [f32; 3], material: Material) {
        let r = segment_radius(b) * self.s;
        let (a, t) = (self.p.position(b), self.p.tip(b));
        let half = (t - a).norm() / 2.0 + 0.4 * r;
        let rot = self.p.rotation(b) * self.align[b.index()];
        self.part(Shape::Cylinder, nalgebra::center(&a, &t), rot, Vector3::new(r, half, r), color, material);
    }

    /// A `shape` in bone `b`'s frame, `off` from its joint (both in the reference height's metres).
    fn on(
        &mut self,
        shape: Shape,
        b: Bone,
        off: Vector3<f32>,
        half: Vector3<f32>,
        color: [f32; 3],
        material: Material,
    ) {
        let rot = self.p.rotation(b);
        self.part(shape, self.p.position(b) + rot * (off * self.s), rot, half * self.s, color, material);
    }

    /// A ball at bone `b`'s joint (shoulders, elbows, knees).
    fn joint(&mut self, b: Bone, radius: f32, color: [f32; 3], material: Material) {
        self.on(Shape::Sphere, b, Vector3::zeros(), Vector3::repeat(radius), color, material);
    }

    fn torso(&mut self) {
        let l = self.look;
        self.on(Shape::Sphere, Bone::Hips, v(0.0, 0.02, 0.0), v(0.165, 0.11, 0.115), l.trousers, FAB);
        self.on(Shape::Sphere, Bone::Spine, v(0.0, 0.08, 0.005), v(0.15, 0.13, 0.105), l.shirt, FAB);
        self.on(Shape::Sphere, Bone::UpperChest, v(0.0, 0.03, 0.0), v(0.175, 0.145, 0.108), l.shirt, FAB);
        for side in Side::BOTH {
            self.joint(Bone::upper_arm(side), 0.056, l.shirt, FAB);
        }
        self.limb(Bone::Neck, l.skin, SKIN_M);
    }

    /// The head, and hair on top and at the back.
    fn head(&mut self) {
        let l = self.look;
        self.on(Shape::Sphere, Bone::Head, v(0.0, 0.06, 0.012), v(0.076, 0.112, 0.094), l.skin, SKIN_M);
        let hair = |d: &mut Self, off, radii| d.on(Shape::Sphere, Bone::Head, off, radii, l.hair, Material::Matte);
        match l.hair_style {
            HairStyle::Short => hair(self, v(0.0, 0.088, -0.012), v(0.081, 0.1, 0.094)),
            HairStyle::Long => {
                hair(self, v(0.0, 0.088, -0.012), v(0.081, 0.1, 0.094));
                self.on(Shape::Box, Bone::Head, v(0.0, 0.0, -0.062), v(0.078, 0.11, 0.035), l.hair, Material::Matte);
            }
            HairStyle::Shaved => hair(self, v(0.0, 0.1, -0.01), v(0.078, 0.085, 0.09)),
        }
    }

    /// Nose, eyes and mouth.
    fn face(&mut self) {
        let (p, s) = (self.p, self.s);
        let head_rot = p.rotation(Bone::Head);
        let nose_rot = head_rot * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 100f32.to_radians());
        let darker = self.look.skin.map(|c| c * 0.8);
        let nose = p.position(Bone::Head) + head_rot * (v(0.0, 0.05, 0.1) * s);
        self.part(Shape::Cone, nose, nose_rot, v(0.013, 0.014, 0.011) * s, darker, SKIN_M);
        for eye in [Bone::LeftEye, Bone::RightEye] {
            self.joint(eye, 0.0135, [0.85, 0.85, 0.85], Material::Matte);
            self.on(
                Shape::Sphere,
                eye,
                v(0.0, 0.0, 0.009),
                Vector3::repeat(0.0078),
                [0.03, 0.025, 0.02],
                Material::Matte,
            );
        }
        self.on(
            Shape::Box,
            Bone::Jaw,
            v(0.0, -0.012, 0.071),
            v(0.021, 0.004, 0.006),
            [0.35, 0.08, 0.08],
            Material::Matte,
        );
    }

    /// Arms in sleeves (short ones show the forearm's skin) and hands with their fingers.
    fn arms(&mut self) {
        let l = self.look;
        let sleeve = if l.long_sleeves { (l.shirt, FAB) } else { (l.skin, SKIN_M) };
        for side in Side::BOTH {
            self.limb(Bone::upper_arm(side), l.shirt, FAB);
            let la = Bone::lower_arm(side);
            self.joint(la, 0.041, sleeve.0, sleeve.1);
            self.limb(la, sleeve.0, sleeve.1);
            self.on(
                Shape::Box,
                Bone::hand(side),
                v(0.05 * side.sign(), -0.002, 0.0),
                v(0.05, 0.0135, 0.042),
                l.skin,
                SKIN_M,
            );
            for f in Finger::ALL {
                for ph in 0..3 {
                    self.limb(Bone::finger(side, f, ph), l.skin, SKIN_M);
                }
            }
        }
    }

    fn legs(&mut self) {
        let l = self.look;
        for side in Side::BOTH {
            let (ul, ll, foot) = match side {
                Side::Left => (Bone::LeftUpperLeg, Bone::LeftLowerLeg, Bone::LeftFoot),
                Side::Right => (Bone::RightUpperLeg, Bone::RightLowerLeg, Bone::RightFoot),
            };
            self.limb(ul, l.trousers, FAB);
            self.joint(ll, 0.057, l.trousers, FAB);
            self.limb(ll, l.trousers, FAB);
            self.on(Shape::Box, foot, v(0.0, -0.042, 0.045), v(0.046, 0.034, 0.118), l.shoes, Material::Matte);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gesture::STANDING;
    use crate::humanoid::Humanoid;

    #[test]
    fn parts_are_the_persons_and_well_formed() {
        let h = Humanoid::seeded(3);
        let p = h.pose(&STANDING, Point3::new(1.0, 0.0, 2.0), 135.0);
        let parts = h.parts(&p);
        assert!(parts.len() > 50 && parts.len() < 80, "{} parts", parts.len());
        for part in &parts {
            assert_eq!(part.id, ID_HUMAN);
            assert!(part.center.coords.iter().chain(part.half_extents.iter()).all(|v| v.is_finite()));
            assert!(part.half_extents.iter().all(|&e| e > 0.0));
            assert!((part.rotation.norm() - 1.0).abs() < 1e-4);
        }
        // Nothing below the floor, the top of the head near the body height.
        let (lo, hi) =
            parts.iter().map(Part::aabb).fold((f32::MAX, f32::MIN), |(lo, hi), (a, b)| (lo.min(a.y), hi.max(b.y)));
        assert!(lo > -0.01 && lo < 0.03, "lowest point {lo}");
        assert!((hi - h.height()).abs() < 0.06, "top {hi} for a {} m person", h.height());
    }

    #[test]
    fn fingers_are_separate_and_thick_enough_and_the_face_shows_the_heading() {
        let h = Humanoid::default();
        let p = h.pose(&STANDING, Point3::origin(), 90.0);
        let parts = h.parts(&p);
        let fingers: Vec<&Part> =
            parts.iter().filter(|q| q.shape == Shape::Cylinder && q.half_extents.x < 0.012).collect();
        assert_eq!(fingers.len(), 30, "15 finger segments per hand");
        assert!(fingers.iter().all(|f| f.half_extents.x >= 0.008), "at least 1.6 cm thick");
        // The nose sits in front of the head, in the facing direction (yaw 90: +x).
        let nose = parts.iter().find(|q| q.shape == Shape::Cone).unwrap();
        let head = p.head_position();
        assert!((nose.center - head).normalize().dot(&p.head_forward()) > 0.8);
        assert!(p.head_forward().x > 0.99);
    }

    #[test]
    fn appearance_is_seeded() {
        assert_eq!(Appearance::seeded(7), Appearance::seeded(7));
        let looks: std::collections::HashSet<String> =
            (0..20).map(|s| format!("{:?}", Appearance::seeded(s))).collect();
        assert!(looks.len() > 15);
        let heights: Vec<f32> = (0..20).map(|s| Humanoid::seeded(s).height()).collect();
        assert!(heights.iter().all(|h| (1.55..=1.9).contains(h)));
        assert!(heights.iter().any(|&h| h < 1.65) && heights.iter().any(|&h| h > 1.75));
    }
}
