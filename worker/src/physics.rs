//! Collision queries with rapier3d: static colliders for the scene's parts (and the person),
//! the robot as a kinematic capsule moved by shape casts, and rays for line of sight.
//!
//! The robot's height is held fixed and the floor is left out of every query: the capsule
//! would otherwise touch the floor and every move would count as blocked.

use nalgebra::{Point2, Point3, Vector2, Vector3};
use rapier3d::geometry::{
    BroadPhaseBvh, Capsule, ColliderBuilder, ColliderHandle, ColliderSet, DefaultBroadPhase, Ray, SharedShape,
};
use rapier3d::math::{Pose3, Rot3, Vec3};
use rapier3d::parry::query::{DefaultQueryDispatcher, ShapeCastOptions};
use rapier3d::prelude::{IntegrationParameters, QueryFilter, RigidBodySet};

use crate::geometry::{ID_HUMAN, ID_STRUCTURE, Part, Shape};

/// Robot body (§3.2.2): a capsule of radius 0.3 m and height 1.5 m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotBody {
    pub radius: f32,
    pub height: f32,
}

impl Default for RobotBody {
    fn default() -> Self {
        RobotBody { radius: 0.3, height: 1.5 }
    }
}

/// Gap kept between the capsule's bottom and the floor so that the floor never counts.
const FLOOR_CLEARANCE: f32 = 0.03;

/// The person is an obstacle of this radius and height.
pub const HUMAN_RADIUS: f32 = 0.25;
pub const HUMAN_HEIGHT: f32 = 1.8;

fn v3(p: Point3<f32>) -> Vec3 {
    Vec3::new(p.x, p.y, p.z)
}

/// Static collision world of one scene (+ optionally the person).
pub struct Physics {
    colliders: ColliderSet,
    bodies: RigidBodySet,
    broad_phase: BroadPhaseBvh,
    robot: RobotBody,
    capsule: SharedShape,
    human: Option<ColliderHandle>,
}

impl Physics {
    /// Builds colliders for every part except the floor slab (parts with id `ID_STRUCTURE`
    /// lying entirely below y = 0.01) and the ceiling. Parts that are seen but not solid (a
    /// shower curtain, a rug) become sensors: they stop lines of sight, not the robot.
    pub fn new(parts: &[Part], robot: RobotBody) -> Physics {
        let mut colliders = ColliderSet::new();
        let mut handles = Vec::with_capacity(parts.len());
        for p in parts {
            let (lo, hi) = p.aabb();
            if p.id == ID_STRUCTURE && (hi.y <= 0.01 || lo.y >= 2.0 && p.half_extents.y < 0.2) {
                continue;
            }
            let mut c = collider_of(p);
            c.set_sensor(!p.solid);
            handles.push(colliders.insert(c));
        }
        let capsule_half = (robot.height / 2.0 - robot.radius).max(0.0);
        let mut phys = Physics {
            colliders,
            bodies: RigidBodySet::new(),
            broad_phase: DefaultBroadPhase::new(),
            robot,
            capsule: SharedShape::capsule_y(capsule_half, robot.radius),
            human: None,
        };
        phys.refresh(&handles, &[]);
        phys
    }

    fn refresh(&mut self, modified: &[ColliderHandle], removed: &[ColliderHandle]) {
        let mut events = Vec::new();
        self.broad_phase.update(
            &IntegrationParameters::default(),
            &self.colliders,
            &self.bodies,
            modified,
            removed,
            &mut events,
        );
    }

    pub fn robot(&self) -> RobotBody {
        self.robot
    }

    /// Puts the person (a cylinder on the floor) at `pos`, or removes them with `None`.
    pub fn set_human(&mut self, pos: Option<Point2<f32>>) {
        let mut removed = Vec::new();
        if let Some(h) = self.human.take() {
            self.colliders.remove(h, &mut Default::default(), &mut self.bodies, &mut Default::default(), false);
            removed.push(h);
        }
        let mut modified = Vec::new();
        if let Some(p) = pos {
            let c = ColliderBuilder::cylinder(HUMAN_HEIGHT / 2.0, HUMAN_RADIUS)
                .position(Pose3::from_translation(Vec3::new(p.x, HUMAN_HEIGHT / 2.0, p.y)))
                .user_data(ID_HUMAN as u128)
                .build();
            let h = self.colliders.insert(c);
            self.human = Some(h);
            modified.push(h);
        }
        self.refresh(&modified, &removed);
    }

    /// Queries of the robot's motion: sensors (see-only parts) do not block it.
    fn query(&self) -> rapier3d::pipeline::QueryPipeline<'_> {
        self.broad_phase.as_query_pipeline(
            &DefaultQueryDispatcher,
            &self.bodies,
            &self.colliders,
            QueryFilter::default().exclude_sensors(),
        )
    }

    /// Queries of lines of sight: everything that is drawn blocks them.
    fn sight(&self) -> rapier3d::pipeline::QueryPipeline<'_> {
        self.broad_phase.as_query_pipeline(
            &DefaultQueryDispatcher,
            &self.bodies,
            &self.colliders,
            QueryFilter::default(),
        )
    }

    fn capsule_pose(&self, xz: Point2<f32>) -> Pose3 {
        Pose3::from_translation(Vec3::new(xz.x, FLOOR_CLEARANCE + self.robot.height / 2.0, xz.y))
    }

    /// Whether the robot fits at (x, z) without touching anything.
    pub fn robot_fits(&self, xz: Point2<f32>) -> bool {
        let q = self.query();
        q.intersect_shape(self.capsule_pose(xz), self.capsule.as_ref()).next().is_none()
    }

    /// Whether a robot `slack` thinner than ours fits at (x, z): true wherever ours fits within
    /// `slack` of the point (the thinner capsule lies inside ours there).
    pub fn thinner_robot_fits(&self, xz: Point2<f32>, slack: f32) -> bool {
        let ours = self.capsule.as_capsule().expect("the robot is a capsule");
        let thinner = Capsule { radius: (ours.radius - slack).max(0.0), ..*ours };
        self.query().intersect_shape(self.capsule_pose(xz), &thinner).next().is_none()
    }

    /// Sweeps the robot from `from` by `delta` (x, z). Returns whether the whole motion is free;
    /// a blocked move leaves the robot where it was (the caller does not move it).
    pub fn move_is_free(&self, from: Point2<f32>, delta: Vector2<f32>) -> bool {
        let q = self.query();
        let opts = ShapeCastOptions {
            max_time_of_impact: 1.0,
            target_distance: 0.0,
            stop_at_penetration: true,
            compute_impact_geometry_on_penetration: false,
        };
        q.cast_shape(&self.capsule_pose(from), Vec3::new(delta.x, 0.0, delta.y), self.capsule.as_ref(), opts).is_none()
    }

    /// The id of the first solid thing a ray from `from` towards `to` hits before reaching
    /// `to` (within `slack` metres of it), or None when the way is clear.
    pub fn first_hit(&self, from: Point3<f32>, to: Point3<f32>, slack: f32) -> Option<u16> {
        let d = to - from;
        let len = d.norm();
        if len < 1e-6 {
            return None;
        }
        let ray = Ray::new(v3(from), Vec3::new(d.x / len, d.y / len, d.z / len));
        let q = self.sight();
        let (h, toi) = q.cast_ray(&ray, len, true)?;
        if toi >= len - slack {
            return None;
        }
        Some(self.colliders[h].user_data as u16)
    }

    /// Whether `to` is seen from `from`: the first thing on the ray is `id` or nothing.
    pub fn sees(&self, from: Point3<f32>, to: Point3<f32>, id: u16) -> bool {
        match self.first_hit(from, to, 0.02) {
            None => true,
            Some(hit) => hit == id,
        }
    }
}

fn collider_of(p: &Part) -> rapier3d::geometry::Collider {
    let h = p.half_extents;
    let shape = match p.shape {
        Shape::Box => SharedShape::cuboid(h.x, h.y, h.z),
        Shape::Cylinder => SharedShape::cylinder(h.y, h.x.max(h.z)),
        Shape::Cone => SharedShape::cone(h.y, h.x.max(h.z)),
        Shape::Sphere => {
            if (h.x - h.y).abs() < 1e-4 && (h.y - h.z).abs() < 1e-4 {
                SharedShape::ball(h.x)
            } else {
                // An ellipsoid is its box here: fine for blocking and occlusion of small fruit.
                SharedShape::cuboid(h.x, h.y, h.z)
            }
        }
    };
    let q = p.rotation.into_inner();
    let rot = Rot3::from_xyzw(q.i, q.j, q.k, q.w);
    ColliderBuilder::new(shape).position(Pose3::from_parts(v3(p.center), rot)).user_data(p.id as u128).build()
}

/// Unit helper for callers working in nalgebra.
pub fn up() -> Vector3<f32> {
    Vector3::y()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn wall_world() -> Physics {
        // floor slab, and a wall 1 m thick at z in [2, 3]
        let floor = Part::new(Shape::Box, Point3::new(0.0, -0.05, 0.0), Vector3::new(10.0, 0.05, 10.0), [0.5; 3]);
        let wall = Part::new(Shape::Box, Point3::new(0.0, 1.0, 2.5), Vector3::new(5.0, 1.0, 0.5), [0.5; 3]).with_id(9);
        Physics::new(&[floor, wall], RobotBody::default())
    }

    #[test]
    fn floor_does_not_block() {
        let p = wall_world();
        assert!(p.robot_fits(Point2::new(0.0, 0.0)));
        assert!(p.move_is_free(Point2::new(0.0, 0.0), Vector2::new(0.25, 0.0)));
    }

    #[test]
    fn wall_blocks_moves_into_it() {
        let p = wall_world();
        // capsule front at z = 1.5 + 0.3 = 1.8; a 0.25 move reaches 2.05 > 2.0
        assert!(!p.move_is_free(Point2::new(0.0, 1.5), Vector2::new(0.0, 0.25)));
        assert!(p.move_is_free(Point2::new(0.0, 1.2), Vector2::new(0.0, 0.25)));
        assert!(!p.robot_fits(Point2::new(0.0, 2.0)));
        // moving away from it is fine
        assert!(p.move_is_free(Point2::new(0.0, 1.5), Vector2::new(0.0, -0.25)));
    }

    #[test]
    fn rays_report_occluders() {
        let p = wall_world();
        let eye = Point3::new(0.0, 1.5, 0.0);
        assert_eq!(p.first_hit(eye, Point3::new(0.0, 1.5, 5.0), 0.01), Some(9));
        assert!(p.sees(eye, Point3::new(0.0, 1.5, 1.9), 0));
        assert!(p.sees(eye, Point3::new(0.0, 1.0, 2.1), 9));
    }

    #[test]
    fn a_curtain_blocks_sight_not_motion() {
        let curtain = Part::new(Shape::Box, Point3::new(0.0, 1.0, 1.0), Vector3::new(1.0, 1.0, 0.02), [0.8; 3])
            .with_id(5)
            .non_solid();
        let p = Physics::new(&[curtain], RobotBody::default());
        assert!(p.robot_fits(Point2::new(0.0, 1.0)));
        assert!(p.move_is_free(Point2::new(0.0, 0.5), Vector2::new(0.0, 1.0)));
        assert_eq!(p.first_hit(Point3::new(0.0, 1.5, 0.0), Point3::new(0.0, 1.5, 2.0), 0.01), Some(5));
    }

    #[test]
    fn human_is_an_obstacle() {
        let mut p = wall_world();
        p.set_human(Some(Point2::new(0.0, 1.0)));
        assert!(!p.robot_fits(Point2::new(0.0, 0.6)));
        p.set_human(None);
        assert!(p.robot_fits(Point2::new(0.0, 0.6)));
    }
}
