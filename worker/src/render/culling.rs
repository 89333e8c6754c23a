//! Frustum culling and level of detail: per view, the parts whose bounding sphere may show in
//! the image and cover a pixel centre, copied into the chunk's instance list with one draw per run of parts that use
//! one unit mesh. Culling is conservative, so it never changes a pixel; round parts whose
//! image is small enough take their coarse mesh (`mesh::LOD_TOLERANCE_PX`).

use nalgebra::Vector3;

use super::config::RenderConfig;
use super::instances::{Grouped, Instance};
use super::mesh::{LOD_TOLERANCE_PX, coarse_error, coarse_of};
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
}

impl Frustum {
    /// An upper bound on how many pixels a length of `radius` at a part (bounding sphere
    /// `center`, `bound`) spans in the image: f·r·|d| / (z − bound)², the largest stretch of
    /// the perspective projection over the sphere. Infinite when the sphere reaches the eye's
    /// plane.
    pub fn max_pixels(&self, center: [f32; 3], bound: f32, radius: f32) -> f32 {
        let d = Vector3::from(center) - self.eye;
        let z = d.dot(&self.forward) - bound;
        if z <= NEAR {
            return f32::INFINITY;
        }
        self.focal_px * radius * d.norm() / (z * z)
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
/// frustum and cover a pixel centre (all of them without `culling`) to `out`, and one draw per run of survivors that
/// share a mesh: a fine round part whose coarse mesh stays within `LOD_TOLERANCE_PX` of its
/// silhouette takes the coarse one. Order is kept, so without coarse swaps the draws are the
/// groups themselves.
pub(super) fn cull(frustum: &Frustum, culling: bool, parts: &Grouped, out: &mut Vec<Instance>, draws: &mut Vec<Draw>) {
    let max_radius_px = LOD_TOLERANCE_PX / coarse_error();
    for g in &parts.groups {
        let coarse = coarse_of(g.mesh);
        let mut run: Option<Draw> = None;
        for i in g.first as usize..(g.first + g.count) as usize {
            let b = parts.bounds[i];
            let center = [b[0], b[1], b[2]];
            if culling && !(frustum.may_see_sphere(center, b[3]) && frustum.may_cover_a_pixel_center(center, b[3])) {
                continue;
            }
            let mesh = match coarse {
                Some(c) if frustum.max_pixels(center, b[3], parts.round[i]) <= max_radius_px => c,
                _ => g.mesh,
            };
            match &mut run {
                Some(d) if d.mesh == mesh => d.count += 1,
                _ => {
                    draws.extend(run.take());
                    run = Some(Draw { mesh, first: out.len() as u32, count: 1 });
                }
            }
            out.push(parts.instances[i]);
        }
        draws.extend(run);
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

    #[test]
    fn round_parts_take_the_coarse_mesh_where_it_stays_within_the_tolerance_and_keep_their_order() {
        use crate::geometry::{Part, Shape};
        let head = |z: f32| Part::new(Shape::Sphere, Point3::new(0.0, 1.5, z), Vector3::repeat(0.11), [0.8; 3]);
        let cam = Camera::new(Point3::new(0.0, 1.5, 0.0), 0.0);
        let meshes = |size: u32, parts: &[Part]| {
            let c = RenderConfig { width: size, height: size, fov_deg: 90.0, max_views_per_submit: 1 };
            let mut g = Grouped::default();
            g.push(parts, true);
            let (mut out, mut draws) = (Vec::new(), Vec::new());
            cull(&Frustum::new(&cam, &c), true, &g, &mut out, &mut draws);
            assert_eq!(out.len(), parts.len());
            draws.iter().map(|d| (d.mesh, d.count)).collect::<Vec<_>>()
        };
        let (fine, coarse) = (2, 5);
        // a head at 1.5 m spans at most 3 px at 64x64: within a quarter pixel with the coarse
        // mesh; at half a metre it does not
        assert_eq!(meshes(64, &[head(1.5)]), [(coarse, 1)]);
        assert_eq!(meshes(64, &[head(0.5)]), [(fine, 1)]);
        // at 224x224 it spans up to 19 px at 1 m: fine until it is about 2.8 m away
        assert_eq!(meshes(224, &[head(1.0)]), [(fine, 1)]);
        assert_eq!(meshes(224, &[head(3.0)]), [(coarse, 1)]);
        // a run that switches keeps the parts in order
        assert_eq!(meshes(224, &[head(1.0), head(4.0), head(5.0), head(1.5)]), [(fine, 1), (coarse, 2), (fine, 1)]);
        // the swap stays within the tolerance: coarse error × image radius
        let c = RenderConfig { width: 64, height: 64, fov_deg: 90.0, max_views_per_submit: 1 };
        let px = Frustum::new(&cam, &c).max_pixels([0.0, 1.5, 1.5], 0.11 * 3f32.sqrt(), 0.11);
        assert!(px * coarse_error() <= LOD_TOLERANCE_PX, "{px} px");
    }
}
