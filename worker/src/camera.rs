//! The pinhole camera shared by the renderer and the CPU visibility checks, so that "in view"
//! means the same thing to both: its basis, intrinsics, projection, clip planes, and the
//! encoding of the depth image it sees.
//!
//! Frame: x right, y up, z forward (left-handed, as in Unity). At yaw 0 the camera looks along +z
//! and +x is on the right of the image; pitch > 0 looks up. Pixel (0, 0) is the top-left corner.

use nalgebra::{Point3, Vector3};

/// Near and far clip planes (metres).
pub const NEAR: f32 = 0.02;
pub const FAR: f32 = 20.0;
/// Depth images are linear in 0..MAX_DEPTH metres (§3.2.2).
pub const MAX_DEPTH: f32 = 10.0;

/// Linear depth (metres) to the 16-bit value of the depth image: 0..10 m → 0..65535, clamped.
/// The renderer's shader (scene.wgsl, `fs_main`) packs depth the same way.
pub fn encode_depth(metres: f32) -> u16 {
    ((metres / MAX_DEPTH).clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

/// The inverse of `encode_depth` (to the nearest step of 10 m / 65535).
pub fn decode_depth(value: u16) -> f32 {
    value as f32 / 65535.0 * MAX_DEPTH
}

/// An encoded depth as a ROS `16UC1` depth image holds it: whole millimetres.
pub fn depth_mm(value: u16) -> u16 {
    (decode_depth(value) * 1000.0).round() as u16
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: Point3<f32>,
    pub yaw_deg: f32,
    pub pitch_deg: f32,
}

/// Image size and field of view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    /// Vertical field of view (degrees); the horizontal one follows from the aspect ratio.
    pub fov_deg: f32,
}

impl Intrinsics {
    /// The resolution at which geometric visibility is judged for navigation (success regions,
    /// the expert, dataset constraints), whatever the run renders: the dissertation's 224².
    /// Datasets thus do not depend on a run's frame size.
    pub fn reference(fov_deg: f32) -> Intrinsics {
        Intrinsics { width: 224, height: 224, fov_deg }
    }

    pub fn tan_half_fov_y(&self) -> f32 {
        (self.fov_deg.to_radians() / 2.0).tan()
    }
    pub fn tan_half_fov_x(&self) -> f32 {
        self.tan_half_fov_y() * self.width as f32 / self.height as f32
    }
}

impl Camera {
    /// A level camera (pitch 0).
    pub fn new(position: Point3<f32>, yaw_deg: f32) -> Camera {
        Camera { position, yaw_deg, pitch_deg: 0.0 }
    }

    /// Unit vectors (right, up, forward) of the camera in world space.
    pub fn basis(&self) -> (Vector3<f32>, Vector3<f32>, Vector3<f32>) {
        let (y, p) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        let forward = Vector3::new(y.sin() * p.cos(), p.sin(), y.cos() * p.cos());
        let right = Vector3::new(y.cos(), 0.0, -y.sin());
        let up = forward.cross(&right);
        (right, up, forward)
    }

    /// World → eye (x right, y up, z = distance along the view axis).
    pub fn to_eye(&self, p: &Point3<f32>) -> Vector3<f32> {
        let (r, u, f) = self.basis();
        let d = p - self.position;
        Vector3::new(r.dot(&d), u.dot(&d), f.dot(&d))
    }

    /// Pixel coordinates (x right, y down, continuous) and eye depth of a world point,
    /// or None if it lies behind the near plane.
    pub fn project(&self, k: &Intrinsics, p: &Point3<f32>) -> Option<(f32, f32, f32)> {
        let e = self.to_eye(p);
        if e.z <= NEAR {
            return None;
        }
        let nx = e.x / (e.z * k.tan_half_fov_x());
        let ny = e.y / (e.z * k.tan_half_fov_y());
        let px = (nx + 1.0) * 0.5 * k.width as f32;
        let py = (1.0 - ny) * 0.5 * k.height as f32;
        Some((px, py, e.z))
    }

    /// Whether a world point projects inside the image, at least `margin` pixels from its edges.
    pub fn in_view(&self, k: &Intrinsics, p: &Point3<f32>, margin: f32) -> bool {
        match self.project(k, p) {
            Some((x, y, z)) => {
                z < FAR && x >= margin && y >= margin && x <= k.width as f32 - margin && y <= k.height as f32 - margin
            }
            None => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const K: Intrinsics = Intrinsics { width: 224, height: 224, fov_deg: 90.0 };

    fn cam(yaw: f32) -> Camera {
        Camera { position: Point3::new(0.0, 1.5, 0.0), yaw_deg: yaw, pitch_deg: 0.0 }
    }

    #[test]
    fn straight_ahead_is_the_image_centre() {
        let (x, y, z) = cam(0.0).project(&K, &Point3::new(0.0, 1.5, 2.0)).unwrap();
        assert!((x - 112.0).abs() < 1e-3 && (y - 112.0).abs() < 1e-3 && (z - 2.0).abs() < 1e-5);
    }

    #[test]
    fn plus_x_is_right_and_up_is_up() {
        let (x, _, _) = cam(0.0).project(&K, &Point3::new(1.0, 1.5, 2.0)).unwrap();
        assert!(x > 112.0);
        let (_, y, _) = cam(0.0).project(&K, &Point3::new(0.0, 2.5, 2.0)).unwrap();
        assert!(y < 112.0);
        // yaw 90 looks along +x
        let (x, _, z) = cam(90.0).project(&K, &Point3::new(2.0, 1.5, 0.0)).unwrap();
        assert!((x - 112.0).abs() < 1e-3 && (z - 2.0).abs() < 1e-5);
    }

    #[test]
    fn ninety_degree_fov_edges() {
        // at 45° off axis a point sits on the image edge
        let (x, _, _) = cam(0.0).project(&K, &Point3::new(2.0, 1.5, 2.0)).unwrap();
        assert!((x - 224.0).abs() < 1e-3);
        assert!(!cam(0.0).in_view(&K, &Point3::new(0.0, 1.5, -1.0), 0.0));
    }

    #[test]
    fn depth_encoding_is_linear_and_saturates() {
        assert_eq!(encode_depth(0.0), 0);
        assert_eq!(encode_depth(10.0), 65535);
        assert_eq!(encode_depth(25.0), 65535);
        assert_eq!(encode_depth(5.0), 32768);
        assert!((decode_depth(encode_depth(2.0)) - 2.0).abs() < 1e-3);
        // ROS's 16UC1: whole millimetres, 10 m the farthest
        assert_eq!((depth_mm(encode_depth(1.234)), depth_mm(encode_depth(25.0)), depth_mm(0)), (1234, 10000, 0));
    }
}
