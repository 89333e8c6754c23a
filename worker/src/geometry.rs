//! World conventions and the primitive parts everything visible or solid is built from.
//!
//! The world follows the original (Unity) convention so that GOND metadata maps one to one:
//! metres, **x right, y up, z forward**; a yaw is in degrees, clockwise seen from above, and
//! yaw 0 faces +z, so the heading of yaw θ is (sin θ, 0, cos θ) and its right is
//! (cos θ, 0, −sin θ). Rendering, physics and kinematics all speak this convention.

use nalgebra::{Point3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Instance id of pixels that show nothing (clear colour).
pub const ID_NONE: u16 = 0;
/// Instance id of floor, walls and ceiling.
pub const ID_STRUCTURE: u16 = 1;
/// Instance id of the person in the scene.
pub const ID_HUMAN: u16 = 2;
/// Scene object `i` (index into `Scene::objects`) renders with id `ID_FIRST_OBJECT + i`.
pub const ID_FIRST_OBJECT: u16 = 3;

/// Heading (unit vector in the x–z plane) of a yaw in degrees.
pub fn heading(yaw_deg: f32) -> Vector2<f32> {
    let r = yaw_deg.to_radians();
    Vector2::new(r.sin(), r.cos())
}

/// Yaw in degrees (0..360) that faces along `dir` (x, z).
pub fn yaw_of(dir: Vector2<f32>) -> f32 {
    wrap_deg(dir.x.atan2(dir.y).to_degrees())
}

/// Wraps an angle to [0, 360).
pub fn wrap_deg(a: f32) -> f32 {
    let w = a.rem_euclid(360.0);
    if w >= 360.0 { 0.0 } else { w }
}

/// Signed smallest difference `to − from` in degrees, in (−180, 180].
pub fn angle_diff_deg(from: f32, to: f32) -> f32 {
    let d = (to - from).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// Rotation about +y for a yaw in degrees (clockwise from above, yaw 0 faces +z).
pub fn yaw_rotation(yaw_deg: f32) -> UnitQuaternion<f32> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians())
}

/// Drops y.
pub fn xz(p: &Point3<f32>) -> Vector2<f32> {
    Vector2::new(p.x, p.z)
}

/// The unit primitives parts are made of. Each is centred on its origin and spans
/// [−1, 1] on every axis before scaling by the part's half extents; `Cylinder` and `Cone`
/// stand along local +y (the cone's apex at +1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Shape {
    Box,
    Cylinder,
    Sphere,
    Cone,
}

impl Shape {
    pub const ALL: [Shape; 4] = [Shape::Box, Shape::Cylinder, Shape::Sphere, Shape::Cone];
}

/// Surface look; the renderer adds a procedural pattern per material so that surfaces read as
/// what they are, and the policy has texture to see.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
pub enum Material {
    #[default]
    Matte,
    Wood,
    Fabric,
    Metal,
    Glass,
    Tile,
    Screen,
    Paper,
    Skin,
    /// Lit from inside (lamp shades, windows): ignores shading.
    Emissive,
}

impl Material {
    pub const fn index(self) -> u32 {
        self as u32
    }
}

/// One primitive in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part {
    pub shape: Shape,
    pub center: Point3<f32>,
    pub rotation: UnitQuaternion<f32>,
    /// Half size along the local axes (for a sphere: the three radii).
    pub half_extents: Vector3<f32>,
    /// Linear RGB in 0..1.
    pub color: [f32; 3],
    pub material: Material,
    /// Instance id written to the id target (`ID_*` above).
    pub id: u16,
    /// Whether the part blocks the robot and rays. Rugs, curtains' light fabric and the like do not.
    pub solid: bool,
}

impl Part {
    pub fn new(shape: Shape, center: Point3<f32>, half_extents: Vector3<f32>, color: [f32; 3]) -> Self {
        Part {
            shape,
            center,
            rotation: UnitQuaternion::identity(),
            half_extents,
            color,
            material: Material::Matte,
            id: ID_STRUCTURE,
            solid: true,
        }
    }

    pub fn with_rotation(mut self, r: UnitQuaternion<f32>) -> Self {
        self.rotation = r;
        self
    }

    pub fn with_material(mut self, m: Material) -> Self {
        self.material = m;
        self
    }

    pub fn with_id(mut self, id: u16) -> Self {
        self.id = id;
        self
    }

    pub fn non_solid(mut self) -> Self {
        self.solid = false;
        self
    }

    /// Axis-aligned bounds (min, max) in world space.
    pub fn aabb(&self) -> (Point3<f32>, Point3<f32>) {
        let m = self.rotation.to_rotation_matrix();
        let h = self.half_extents;
        let mut ext = Vector3::zeros();
        for i in 0..3 {
            ext[i] = (0..3).map(|j| m[(i, j)].abs() * h[j]).sum();
        }
        (self.center - ext, self.center + ext)
    }

    /// Points on the part that visibility tests aim at: the centre and the centres of the
    /// six faces pulled 20% inwards (so a grazing ray still lands on the part).
    pub fn sample_points(&self) -> [Point3<f32>; 7] {
        let mut out = [self.center; 7];
        let mut k = 1;
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut local = Vector3::zeros();
                local[axis] = sign * self.half_extents[axis] * 0.8;
                out[k] = self.center + self.rotation * local;
                k += 1;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_zero_faces_plus_z_and_right_is_plus_x() {
        let h = heading(0.0);
        assert!((h - Vector2::new(0.0, 1.0)).norm() < 1e-6);
        let r = yaw_rotation(0.0) * Vector3::x();
        assert!((r - Vector3::x()).norm() < 1e-6);
        // yaw 90 faces +x: the rotation of +z by the yaw quaternion agrees with heading().
        let f = yaw_rotation(90.0) * Vector3::z();
        let h = heading(90.0);
        assert!((f.x - h.x).abs() < 1e-6 && (f.z - h.y).abs() < 1e-6);
    }

    #[test]
    fn yaw_of_inverts_heading() {
        for k in 0..24 {
            let y = k as f32 * 15.0;
            assert!(angle_diff_deg(yaw_of(heading(y)), y).abs() < 1e-3);
        }
    }

    #[test]
    fn angle_diff_is_smallest() {
        assert!((angle_diff_deg(350.0, 10.0) - 20.0).abs() < 1e-5);
        assert!((angle_diff_deg(10.0, 350.0) + 20.0).abs() < 1e-5);
        assert!((angle_diff_deg(0.0, 180.0) - 180.0).abs() < 1e-5);
    }

    #[test]
    fn aabb_of_rotated_box_grows() {
        let p = Part::new(Shape::Box, Point3::origin(), Vector3::new(1.0, 1.0, 0.0), [1.0; 3])
            .with_rotation(yaw_rotation(45.0));
        let (lo, hi) = p.aabb();
        assert!((hi.x - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5);
        assert!((lo.z + std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5);
    }
}
