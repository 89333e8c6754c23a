//! Frustum culling: per view, the parts whose bounding sphere may show in the image and cover
//! a pixel centre, copied into the chunk's instance list with one draw per unit mesh.
//! Conservative, so it never changes a pixel.

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
    /// Pixels per unit of view-plane offset at 1 m depth (the focal length in pixels).
    focal_px: f32,
    /// Half the image size in pixels.
    half_w: f32,
    half_h: f32,
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
            focal_px: sy * cfg.height as f32 / 2.0,
            half_w: cfg.width as f32 / 2.0,
            half_h: cfg.height as f32 / 2.0,
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

    /// Whether a sphere's image may contain a pixel centre, the only points the rasteriser
    /// samples: a part whose image falls between the centres (common for sub-pixel parts at
    /// 64×64) produces no fragment at all, so skipping it changes nothing. Conservative: the
    /// image lies within f·r·(|d| + r)/(z − r)² of the projected centre (the largest stretch
    /// of the projection over the sphere), plus 1/64 px for the rasteriser's 1/256 px snapping
    /// and rounding.
    pub fn may_cover_a_pixel_center(&self, center: [f32; 3], radius: f32) -> bool {
        let d = Vector3::from(center) - self.eye;
        let z = d.dot(&self.forward);
        if z - radius <= NEAR {
            return true;
        }
        let reach = self.focal_px * radius * (d.norm() + radius) / ((z - radius) * (z - radius)) + 1.0 / 64.0;
        let x = (d.dot(&self.right) * self.sx / z + 1.0) * self.half_w;
        let y = (1.0 - d.dot(&self.up) * self.sy / z) * self.half_h;
        let has_center = |lo: f32, hi: f32| (hi - 0.5).floor() >= (lo - 0.5).ceil();
        has_center(x - reach, x + reach) && has_center(y - reach, y + reach)
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
/// frustum and cover a pixel centre to `out`, and one draw for the survivors.
pub(super) fn cull(frustum: Option<&Frustum>, parts: &Grouped, out: &mut Vec<Instance>, draws: &mut Vec<Draw>) {
    for g in &parts.groups {
        let first = out.len() as u32;
        for i in g.first as usize..(g.first + g.count) as usize {
            let b = parts.bounds[i];
            let center = [b[0], b[1], b[2]];
            if frustum.is_none_or(|f| f.may_see_sphere(center, b[3]) && f.may_cover_a_pixel_center(center, b[3])) {
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

    #[test]
    fn a_sphere_skipped_as_between_pixel_centres_has_its_whole_image_between_them() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let c = RenderConfig { width: 64, height: 48, fov_deg: 90.0, max_views_per_submit: 1 };
        let mut skipped = 0;
        for _ in 0..20000 {
            let cam = Camera {
                position: Point3::new(0.0, 1.5, 0.0),
                yaw_deg: rng.random_range(0.0..360.0),
                pitch_deg: rng.random_range(-30.0..30.0),
            };
            let f = Frustum::new(&cam, &c);
            let (right, up, forward) = cam.basis();
            let at = cam.position
                + forward * rng.random_range(0.3..6.0f32)
                + right * rng.random_range(-2.0..2.0f32)
                + up * rng.random_range(-2.0..2.0f32);
            let radius = rng.random_range(0.001..0.05f32);
            let center = [at.x, at.y, at.z];
            if !f.may_see_sphere(center, radius) || f.may_cover_a_pixel_center(center, radius) {
                continue;
            }
            skipped += 1;
            // the image's bounding box, from points all over the sphere, holds no pixel centre
            let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
            for i in 0..400 {
                let (t, p) = (i as f32 * 2.399_963, (i as f32 + 0.5) / 400.0);
                let (z, r) = (1.0 - 2.0 * p, (1.0 - (1.0 - 2.0 * p).powi(2)).sqrt());
                let q = at + Vector3::new(r * t.cos(), r * t.sin(), z) * radius;
                let (x, y, _) = cam.project(&c.intrinsics(), &q).unwrap();
                lo = [lo[0].min(x), lo[1].min(y)];
                hi = [hi[0].max(x), hi[1].max(y)];
            }
            let holds_center = |a: f32, b: f32| (b - 0.5).floor() >= (a - 0.5).ceil();
            assert!(
                !(holds_center(lo[0], hi[0]) && holds_center(lo[1], hi[1])),
                "sphere {center:?} r {radius}: image {lo:?}..{hi:?} holds a pixel centre"
            );
        }
        assert!(skipped > 1000, "{skipped}");
    }
}
