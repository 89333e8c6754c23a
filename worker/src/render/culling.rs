//! Frustum culling: per view, the parts whose bounding sphere may show in the image, copied
//! into the chunk's instance list with one draw per unit mesh. Conservative, so it never
//! changes a pixel.

use nalgebra::Vector3;

use super::config::RenderConfig;
use super::instances::{Grouped, Instance};
use super::projection::projection_scale;
use crate::camera::{Camera, FAR, NEAR};

/// The view volume of a camera, for skipping parts that cannot appear in its image.
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    eye: Vector3<f32>,
    right: Vector3<f32>,
    up: Vector3<f32>,
    forward: Vector3<f32>,
    /// Projection scales and 1/√(s² + 1), the length of the side planes' normals.
    sx: f32,
    sy: f32,
    nx: f32,
    ny: f32,
}

impl Frustum {
    pub fn new(camera: &Camera, cfg: &RenderConfig) -> Frustum {
        let (right, up, forward) = camera.basis();
        let (sx, sy) = projection_scale(cfg);
        Frustum {
            eye: camera.position.coords,
            right,
            up,
            forward,
            sx,
            sy,
            nx: 1.0 / (sx * sx + 1.0).sqrt(),
            ny: 1.0 / (sy * sy + 1.0).sqrt(),
        }
    }

    /// Whether a sphere may show in the image. Conservative (a centimetre of slack on every
    /// plane): it never drops a sphere the rasteriser would draw, so culling cannot change
    /// a single pixel.
    pub fn may_see_sphere(&self, center: [f32; 3], radius: f32) -> bool {
        let d = Vector3::from(center) - self.eye;
        let r = radius + 0.01;
        let (x, y, z) = (d.dot(&self.right), d.dot(&self.up), d.dot(&self.forward));
        z + r >= NEAR
            && z - r <= FAR
            && (x.abs() * self.sx - z) * self.nx <= r
            && (y.abs() * self.sy - z) * self.ny <= r
    }
}

/// One draw call: `count` instances from `first` in the chunk's instance list.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Draw {
    pub mesh: usize,
    pub first: u32,
    pub count: u32,
}

/// Appends, for each group of `parts`, its instances whose bounding sphere may show in the
/// frustum to `out`, and one draw for the survivors.
pub(super) fn cull(frustum: Option<&Frustum>, parts: &Grouped, out: &mut Vec<Instance>, draws: &mut Vec<Draw>) {
    for g in &parts.groups {
        let first = out.len() as u32;
        for i in g.first as usize..(g.first + g.count) as usize {
            let b = parts.bounds[i];
            if frustum.is_none_or(|f| f.may_see_sphere([b[0], b[1], b[2]], b[3])) {
                out.push(parts.instances[i]);
            }
        }
        let count = out.len() as u32 - first;
        if count > 0 {
            draws.push(Draw { mesh: g.mesh, first, count });
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;
    use crate::render::project;

    #[test]
    fn frustum_keeps_every_sphere_with_a_visible_point() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let c = RenderConfig { width: 160, height: 96, fov_deg: 75.0, max_views_per_submit: 1 };
        let mut culled = 0;
        for _ in 0..2000 {
            let cam = Camera {
                position: Point3::new(rng.random_range(-2.0..2.0), 1.5, rng.random_range(-2.0..2.0)),
                yaw_deg: rng.random_range(0.0..360.0),
                pitch_deg: rng.random_range(-30.0..30.0),
            };
            let f = Frustum::new(&cam, &c);
            let center = [rng.random_range(-6.0..6.0), rng.random_range(-1.0..4.0), rng.random_range(-6.0..6.0)];
            let radius = rng.random_range(0.01..1.0f32);
            if f.may_see_sphere(center, radius) {
                continue;
            }
            culled += 1;
            for _ in 0..200 {
                let v = Vector3::new(
                    rng.random_range(-1.0..1.0f32),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                if v.norm() > 1.0 {
                    continue;
                }
                let p = Point3::from(center) + v * radius;
                assert!(project(&cam, &c, p).is_none(), "culled sphere {center:?} r {radius} has visible point {p:?}");
            }
        }
        assert!(culled > 500, "{culled}");
    }
}
