//! Gestures (§3.3): 100 frames of the 95 humanoid muscles at 30 fps.
//!
//! - [`referencing`]: the person points at the target (index finger, open palm or two fingers,
//!   either arm, straight or bent elbow, varied timing, tremor and aiming error);
//! - [`intervention`]: 20 rejective gestures shown towards whoever the person faces;
//! - [`bvh`]: motion capture retargeted to the muscles;
//! - [`capture`]: a person's own gesture from a video's body and hand landmarks;
//! - [`motion`]: the original file formats (motion.csv, metadata JSON);
//! - [`accuracy`]: the original evaluator's measure of how well a gesture points at a target;
//!
//! A [`Motion`] is also the gesture network's input, 100 × 95 values, frame-major.

pub mod accuracy;
pub mod bvh;
pub mod capture;
pub mod intervention;
pub mod motion;
pub mod referencing;
mod synth;

use std::fmt;

use crate::humanoid::MUSCLES;

pub use accuracy::{DEFAULT_RADIUS, LineErrors, accuracy, accuracy_with, line_errors};
pub use intervention::{INTERVENTION_NAMES, INTERVENTIONS, intervention};
pub use referencing::{HandShape, Pointing, ReferencingStyle, referencing, referencing_with};
pub use synth::STANDING;

/// Frames per gesture (§3.3.1: "exactly 100 time steps").
pub const FRAMES: usize = 100;
/// Recording rate of Kinect and Leap Motion (§3.3.1).
pub const FPS: f32 = 30.0;

/// One gesture: `FRAMES` frames of `MUSCLES` muscle values.
#[derive(Clone, PartialEq)]
pub struct Motion {
    frames: Box<[[f32; MUSCLES]; FRAMES]>,
}

impl fmt::Debug for Motion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let first = &self.frames[0];
        write!(f, "Motion({FRAMES}×{MUSCLES}, frame 0: [{:.3}, {:.3}, {:.3}, …])", first[0], first[1], first[2])
    }
}

impl Motion {
    /// Every frame the same pose.
    pub fn constant(pose: &[f32; MUSCLES]) -> Motion {
        Motion { frames: Box::new([*pose; FRAMES]) }
    }

    /// From exactly `FRAMES` frames.
    pub fn from_frames(frames: &[[f32; MUSCLES]]) -> Option<Motion> {
        let arr: &[[f32; MUSCLES]; FRAMES] = frames.try_into().ok()?;
        Some(Motion { frames: Box::new(*arr) })
    }

    /// From `FRAMES × MUSCLES` values, frame-major (the layout of [`Motion::as_flat`]).
    pub fn from_flat(values: &[f32]) -> Option<Motion> {
        if values.len() != FRAMES * MUSCLES {
            return None;
        }
        let mut m = Motion::constant(&[0.0; MUSCLES]);
        m.as_flat_mut().copy_from_slice(values);
        Some(m)
    }

    pub fn frame(&self, i: usize) -> &[f32; MUSCLES] {
        &self.frames[i]
    }

    pub fn frame_mut(&mut self, i: usize) -> &mut [f32; MUSCLES] {
        &mut self.frames[i]
    }

    pub fn frames(&self) -> &[[f32; MUSCLES]; FRAMES] {
        &self.frames
    }

    /// The values of one muscle over time.
    pub fn muscle(&self, i: usize) -> [f32; FRAMES] {
        std::array::from_fn(|t| self.frames[t][i])
    }

    /// All values, frame after frame: the 9,500-value input of the gesture network.
    pub fn as_flat(&self) -> &[f32] {
        self.frames.as_flattened()
    }

    pub fn as_flat_mut(&mut self) -> &mut [f32] {
        self.frames.as_flattened_mut()
    }

    /// The same gesture performed with the other side of the body: left and right muscles
    /// swap, sideways bends and turns change sign.
    pub fn mirrored(&self) -> Motion {
        let mut out = self.clone();
        for t in 0..FRAMES {
            out.frames[t] = mirror_pose(&self.frames[t]);
        }
        out
    }
}

/// A pose done with the other side of the body.
pub fn mirror_pose(m: &[f32; MUSCLES]) -> [f32; MUSCLES] {
    let mut o = *m;
    // Left-Right bends and Twist/Turn of spine, chest, upper chest, neck, head; jaw sideways.
    for i in [1, 2, 4, 5, 7, 8, 10, 11, 13, 14, 20] {
        o[i] = -m[i];
    }
    // Eyes, legs, arms, fingers swap sides (their muscles already mean the same anatomical
    // motion on both sides).
    for (l, r, n) in [(15, 17, 2), (21, 29, 8), (37, 46, 9), (55, 75, 20)] {
        o[l..l + n].copy_from_slice(&m[r..r + n]);
        o[r..r + n].copy_from_slice(&m[l..l + n]);
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_layout_is_frame_major() {
        let mut m = Motion::constant(&[0.0; MUSCLES]);
        m.frame_mut(2)[7] = 1.5;
        assert_eq!(m.as_flat()[2 * MUSCLES + 7], 1.5);
        assert_eq!(Motion::from_flat(m.as_flat()).unwrap(), m);
        assert!(Motion::from_flat(&[0.0; 10]).is_none());
        assert_eq!(m.muscle(7)[2], 1.5);
    }

    #[test]
    fn mirroring_twice_is_identity_and_swaps_arms() {
        let mut p = STANDING;
        p[48] = 0.7;
        p[14] = 0.3;
        let q = mirror_pose(&p);
        assert_eq!(q[39], 0.7);
        assert_eq!(q[14], -0.3);
        assert_eq!(mirror_pose(&q), p);
    }
}
