//! Whether a thing is in view without rendering: project sample points of its parts with the
//! renderer's camera, then cast rays for occlusion.
//!
//! This is conservative with respect to the renderer's "at least one pixel" rule: a sample
//! point must land a pixel inside the frame and be unoccluded, so whenever this says visible
//! the rendered id image shows the thing too. Used where no frame is rendered: by the expert,
//! by the dataset builder (the target seen from the person), and by env loops without rendering.

use nalgebra::Point3;

use crate::camera::{Camera, Intrinsics, MAX_DEPTH};
use crate::geometry::Part;
use crate::physics::Physics;

/// Sample points of a set of parts (the parts of one object).
pub fn sample_points(parts: &[Part]) -> Vec<Point3<f32>> {
    parts.iter().flat_map(|p| p.sample_points()).collect()
}

/// Whether any of `points` (belonging to the thing with instance `id`) is in the frame of
/// `camera` and not hidden behind something else.
pub fn visible(physics: &Physics, camera: &Camera, k: &Intrinsics, points: &[Point3<f32>], id: u16) -> bool {
    points
        .iter()
        .any(|p| camera.in_view(k, p, 1.0) && camera.to_eye(p).z < MAX_DEPTH && physics.sees(camera.position, *p, id))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::physics::RobotBody;
    use nalgebra::Vector3;

    #[test]
    fn occluded_behind_a_wall_and_outside_the_frame() {
        let cup =
            Part::new(Shape::Cylinder, Point3::new(0.0, 1.0, 3.0), Vector3::new(0.05, 0.05, 0.05), [1.0; 3]).with_id(5);
        let wall = Part::new(Shape::Box, Point3::new(0.0, 1.0, 1.5), Vector3::new(1.0, 1.0, 0.05), [0.5; 3]).with_id(6);
        let k = Intrinsics { width: 224, height: 224, fov_deg: 90.0 };
        let cam = Camera { position: Point3::new(0.0, 1.5, 0.0), yaw_deg: 0.0, pitch_deg: 0.0 };
        let pts = sample_points(&[cup]);
        let open = Physics::new(&[cup], RobotBody::default());
        assert!(visible(&open, &cam, &k, &pts, 5));
        let walled = Physics::new(&[cup, wall], RobotBody::default());
        assert!(!visible(&walled, &cam, &k, &pts, 5));
        let behind = Camera { yaw_deg: 180.0, ..cam };
        assert!(!visible(&open, &behind, &k, &pts, 5));
    }
}
