//! The humanoid person: Unity's humanoid skeleton posed by the 95 muscle values of a motion
//! frame (forward kinematics), and its avatar drawn as primitive parts.
//!
//! ```text
//! muscles [f32; 95] ──pose──▶ SkeletonPose (55 bone frames) ──parts──▶ Vec<Part> (id ID_HUMAN)
//! ```
//!
//! Both steps take a few microseconds, so a renderer can pose and draw the person every frame.

pub mod avatar;
pub mod muscles;
pub mod skeleton;

use nalgebra::Point3;
use rand::Rng;

pub use avatar::{Appearance, HairStyle};
pub use muscles::{MUSCLE_NAMES, MUSCLE_RANGES, MUSCLES, muscle_degrees, muscle_index, muscle_value};
pub use skeleton::{BONES, Bone, Finger, REFERENCE_HEIGHT, Side, Skeleton, SkeletonPose};

use crate::geometry::Part;

/// One person: body proportions (from the height) and looks.
#[derive(Clone, Debug)]
pub struct Humanoid {
    skeleton: Skeleton,
    appearance: Appearance,
    shape: avatar::AvatarShape,
}

impl Default for Humanoid {
    /// A 1.70 m person with the default look.
    fn default() -> Self {
        Humanoid::new(REFERENCE_HEIGHT, Appearance::default())
    }
}

impl Humanoid {
    /// A person `height` metres tall (crown to sole; 1.2–2.2 m).
    pub fn new(height: f32, appearance: Appearance) -> Humanoid {
        let height = height.clamp(1.2, 2.2);
        let skeleton = Skeleton::new(height);
        let shape = avatar::AvatarShape::new(&skeleton);
        Humanoid { skeleton, appearance, shape }
    }

    /// The default person, built once: what gesture synthesis and accuracy use when no body
    /// is given.
    pub fn standard() -> &'static Humanoid {
        static STANDARD: std::sync::OnceLock<Humanoid> = std::sync::OnceLock::new();
        STANDARD.get_or_init(Humanoid::default)
    }

    /// A person whose height (1.55–1.90 m) and look are drawn from `seed`.
    pub fn seeded(seed: u64) -> Humanoid {
        let mut r = farm::seed::rng(seed, &[0x4E16_4700]);
        let height = (REFERENCE_HEIGHT + r.random_range(-0.15..0.2f32)).clamp(1.55, 1.90);
        Humanoid::new(height, Appearance::seeded(seed))
    }

    pub fn height(&self) -> f32 {
        self.skeleton.height()
    }

    pub fn appearance(&self) -> &Appearance {
        &self.appearance
    }

    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Forward kinematics for one frame: `root` is the floor point under the hips, the person
    /// faces `geometry::heading(yaw_deg)`, feet rest on the floor.
    pub fn pose(&self, muscles: &[f32; MUSCLES], root: Point3<f32>, yaw_deg: f32) -> SkeletonPose {
        self.skeleton.pose(muscles, root, yaw_deg)
    }

    /// The avatar for a pose, every part with id `ID_HUMAN`.
    pub fn parts(&self, pose: &SkeletonPose) -> Vec<Part> {
        self.shape.parts(&self.appearance, pose)
    }
}
