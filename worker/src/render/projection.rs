//! The camera's projection as the renderer applies it: the per-view uniform block the shader
//! reads (view basis, projection scales, reversed-Z coefficients) and [`project`], the same
//! math on the CPU.
//!
//! The world is left-handed (x right, y up, z forward): a camera at yaw 0 looks along +z and
//! sees +x on the right of its image. The view basis is (right, up, forward) and a point's
//! view coordinates are its offsets along them, so no handedness flip is needed anywhere:
//! NDC x = right, NDC y = up, and the forward offset is the linear depth the robot's depth
//! image reports (eye-space z, not the ray length, as a depth buffer gives it, §3.2.2).

use nalgebra::Point3;

use super::config::RenderConfig;
use crate::camera::{Camera, FAR, NEAR};

/// Scale factors of the projection: (x, y) multipliers of view x and y before the divide.
pub fn projection_scale(cfg: &RenderConfig) -> (f32, f32) {
    let k = cfg.intrinsics();
    (1.0 / k.tan_half_fov_x(), 1.0 / k.tan_half_fov_y())
}

/// Reversed-Z depth: clip z = A − B·z_view with w = z_view, so NDC z is 1 at the near plane
/// and 0 at the far plane (best use of float depth precision).
pub fn depth_coefficients() -> (f32, f32) {
    let a = NEAR * FAR / (FAR - NEAR);
    let b = NEAR / (FAR - NEAR);
    (a, b)
}

/// The per-view constants the shader reads (one uniform block per view).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ViewUniform {
    pub right: [f32; 4],
    pub up: [f32; 4],
    pub forward: [f32; 4],
    /// xyz = eye, w = the height of a pixel at 1 m depth (metres), for pattern anti-aliasing.
    pub eye: [f32; 4],
    /// (sx, sy, A, B) of `projection_scale` and `depth_coefficients`.
    pub proj: [f32; 4],
}

impl ViewUniform {
    pub fn new(camera: &Camera, cfg: &RenderConfig) -> ViewUniform {
        let (r, u, f) = camera.basis();
        let (sx, sy) = projection_scale(cfg);
        let (a, b) = depth_coefficients();
        let e = camera.position;
        ViewUniform {
            right: [r.x, r.y, r.z, 0.0],
            up: [u.x, u.y, u.z, 0.0],
            forward: [f.x, f.y, f.z, 0.0],
            eye: [e.x, e.y, e.z, 2.0 / (sy * cfg.height as f32)],
            proj: [sx, sy, a, b],
        }
    }
}

/// Projects a world point into the image of `camera`: (column, row, linear depth in metres),
/// with (0, 0) the top-left corner of the top-left pixel and pixel (i, j) covering
/// [i, i+1) × [j, j+1). None when the point lies outside the view frustum. Uses the same
/// math as the shader, so a point projected here lands on the pixel the renderer shades.
pub fn project(camera: &Camera, cfg: &RenderConfig, point: Point3<f32>) -> Option<(f32, f32, f32)> {
    let (px, py, zv) = camera.project(&cfg.intrinsics(), &point)?;
    let (w, h) = (cfg.width as f32, cfg.height as f32);
    ((NEAR..=FAR).contains(&zv) && px >= 0.0 && px < w && py >= 0.0 && py < h).then_some((px, py, zv))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> RenderConfig {
        RenderConfig { width: 224, height: 224, fov_deg: 90.0, max_views_per_submit: 1 }
    }

    #[test]
    fn basis_is_left_handed_and_yaw_follows_the_world_convention() {
        for yaw in [0.0, 37.0, 90.0, 215.0] {
            for pitch in [-30.0, 0.0, 20.0] {
                let (r, u, f) = Camera { position: Point3::origin(), yaw_deg: yaw, pitch_deg: pitch }.basis();
                assert!((r.cross(&u) - f).norm() < 1e-5);
                assert!(r.dot(&u).abs() < 1e-6 && r.dot(&f).abs() < 1e-6 && u.dot(&f).abs() < 1e-6);
                if pitch == 0.0 {
                    let h = crate::geometry::heading(yaw);
                    assert!((f.x - h.x).abs() < 1e-6 && (f.z - h.y).abs() < 1e-6);
                }
            }
        }
    }

    #[test]
    fn projection_puts_plus_x_right_and_plus_y_up() {
        let c = Camera::new(Point3::new(0.0, 1.5, 0.0), 0.0);
        let (px, py, d) = project(&c, &cfg(), Point3::new(0.0, 1.5, 2.0)).unwrap();
        assert!((px - 112.0).abs() < 1e-3 && (py - 112.0).abs() < 1e-3 && (d - 2.0).abs() < 1e-6);
        let (px, _, _) = project(&c, &cfg(), Point3::new(1.0, 1.5, 2.0)).unwrap();
        assert!((px - 168.0).abs() < 1e-3, "{px}");
        let (_, py, _) = project(&c, &cfg(), Point3::new(0.0, 2.5, 2.0)).unwrap();
        assert!((py - 56.0).abs() < 1e-3, "{py}");
        assert!(project(&c, &cfg(), Point3::new(0.0, 1.5, -2.0)).is_none());
        assert!(project(&c, &cfg(), Point3::new(3.0, 1.5, 2.0)).is_none());
        // depth is along the view axis, not along the ray
        let (_, _, d) = project(&c, &cfg(), Point3::new(1.5, 1.5, 2.0)).unwrap();
        assert!((d - 2.0).abs() < 1e-6);
        // yaw 90 looks along +x
        let c = Camera::new(Point3::new(0.0, 1.5, 0.0), 90.0);
        let (px, _, d) = project(&c, &cfg(), Point3::new(3.0, 1.5, 0.0)).unwrap();
        assert!((px - 112.0).abs() < 1e-3 && (d - 3.0).abs() < 1e-5);
        // ... and then −z is on its right
        let (px, _, _) = project(&c, &cfg(), Point3::new(3.0, 1.5, -1.0)).unwrap();
        assert!(px > 112.0);
    }

    #[test]
    fn pitch_up_moves_things_down_the_image() {
        let c = Camera { position: Point3::new(0.0, 1.5, 0.0), yaw_deg: 0.0, pitch_deg: 20.0 };
        let (_, py, _) = project(&c, &cfg(), Point3::new(0.0, 1.5, 2.0)).unwrap();
        assert!(py > 112.0);
    }
}
