//! The observation the policy acts on, assembled from the robot's topics in the bytes a worker
//! writes for one env (`shm_schema`): the record's fields the policy reads, the frames, the
//! gesture.

use farm::stepper::PayloadBuf;
use half::f16;
use shm_schema::{EnvRecord, GESTURE_DIMS, GESTURE_FRAMES, ObsSections, ObsShape, action, gesture_kind};

use super::camera::Sampling;
use super::drive::{Pose2, wrap};
use super::msgs::{Gesture, Image};

/// What the policy is told besides the frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Facts {
    /// The first step of an episode (the recurrent memory starts afresh).
    pub start: bool,
    pub step: u32,
    pub last_action: u8,
    /// The target's index among `Category::targets()`.
    pub target: u32,
}

/// A colour image and its aligned depth, sampled to the policy's view, and their stamp (s).
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub stamp: f64,
    pub rgb: Vec<u8>,
    pub depth: Vec<u16>,
}

impl Frame {
    /// Samples a colour image and its depth (same stamp) to the policy's view.
    pub fn sample(sampling: &Sampling, colour: &Image, depth: &Image, size: u32) -> Result<Frame, String> {
        let px = (size * size) as usize;
        let (mut rgb, mut d) = (vec![0; px * 3], vec![0; px]);
        sampling.colour(colour, &mut rgb)?;
        sampling.depth(depth, &mut d)?;
        Ok(Frame { stamp: super::dds::seconds(colour.header.stamp), rgb, depth: d })
    }
}

/// One env's observation buffer.
pub struct Observation {
    shape: ObsShape,
    buf: PayloadBuf,
}

/// The person relative to the robot as the simulator reports it: right and forward (m) of the
/// robot, and the person's yaw less the robot's (clockwise) / 360.
pub fn person_relative(robot: Pose2, person: Pose2) -> [f32; 3] {
    let (dx, dy) = (person.x - robot.x, person.y - robot.y);
    let (s, c) = robot.yaw.sin_cos();
    let (forward, left) = (dx * c + dy * s, -dx * s + dy * c);
    // clockwise yaw differences: the odometry frame turns the other way
    let turn = wrap(-(person.yaw - robot.yaw)).to_degrees();
    let turn = if turn <= -180.0 + 1e-9 { 180.0 } else { turn };
    [-left as f32, forward as f32, (turn / 360.0) as f32]
}

impl Observation {
    pub fn new(size: u32) -> Observation {
        let shape = ObsShape::new(1, size, size);
        Observation { buf: PayloadBuf::new(&shape.layout), shape }
    }

    /// Writes an observation from frames already sampled to the policy's view; a gesture of the
    /// wrong size says why.
    pub fn write(
        &mut self,
        facts: Facts,
        frame: &Frame,
        gesture: Option<&Gesture>,
        person: [f32; 3],
    ) -> Result<(), String> {
        let s = ObsSections::new(&self.shape, self.buf.bytes_mut()).expect("the buffer's own shape");
        s.rgb.copy_from_slice(&frame.rgb);
        s.depth.copy_from_slice(&frame.depth);
        let kind = gesture.map_or(gesture_kind::NONE, |g| g.kind);
        match gesture.filter(|g| g.kind != gesture_kind::NONE) {
            Some(g) => {
                if (g.frames as usize, g.dims as usize) != (GESTURE_FRAMES, GESTURE_DIMS)
                    || g.muscles.len() != GESTURE_FRAMES * GESTURE_DIMS
                {
                    return Err(format!(
                        "gesture: {}×{} with {} values; {GESTURE_FRAMES}×{GESTURE_DIMS} expected",
                        g.frames,
                        g.dims,
                        g.muscles.len()
                    ));
                }
                for (o, v) in s.gesture.iter_mut().zip(&g.muscles) {
                    *o = f16::from_f32(*v).to_bits();
                }
            }
            None => s.gesture.fill(0),
        }
        s.records[0] = EnvRecord {
            episode_start: facts.start as u8,
            episode_step: facts.step,
            last_action: if facts.start { action::NONE } else { facts.last_action } as u32,
            gesture_kind: kind,
            target_category: facts.target,
            person_rel: person,
            ..Default::default()
        };
        Ok(())
    }

    /// The bytes `learner act` reads.
    pub fn payload(&self) -> &[u8] {
        &self.buf.bytes()[..self.shape.layout.total_len as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulator's floor (x right, z forward, yaw clockwise in degrees) in the odometry
    /// frame (x forward, y left, yaw counter-clockwise in radians), as `robot sim` publishes it.
    fn odom(x: f32, z: f32, yaw_deg: f32) -> Pose2 {
        Pose2 { x: z as f64, y: -x as f64, yaw: -(yaw_deg as f64).to_radians() }
    }

    #[test]
    fn the_person_is_where_the_simulator_puts_them() {
        let cases = [
            ((0.0, 0.0, 0.0), (1.0, 2.0, 90.0)),
            ((1.0, -1.0, 135.0), (-2.0, 0.5, 300.0)),
            ((3.0, 2.0, 270.0), (3.0, 4.0, 80.0)),
        ];
        for ((rx, rz, ry), (px, pz, py)) in cases {
            // Program::person_relative, written out: right and forward of the heading (sin, cos)
            let h = worker::geometry::heading(ry);
            let (dx, dz) = (px - rx, pz - rz);
            let want = [dx * h.y - dz * h.x, dx * h.x + dz * h.y, worker::geometry::angle_diff_deg(ry, py) / 360.0];
            let got = person_relative(odom(rx, rz, ry), odom(px, pz, py));
            for (a, b) in want.iter().zip(&got) {
                assert!((a - b).abs() < 1e-4, "{want:?} vs {got:?}");
            }
        }
    }
}
