//! Unit meshes of the four primitive shapes, built once on the CPU and drawn as instances.
//!
//! Every mesh spans [−1, 1]³ like `geometry::Shape` says (cylinder and cone stand along +y,
//! the cone's apex at +1), and every triangle is wound so that the cross product of its edges
//! points *out* of the solid. Through the left-handed camera of `camera.rs` that winding
//! appears clockwise on screen for a face turned towards the viewer, hence `FrontFace::Cw`.

use bytemuck::{Pod, Zeroable};

use crate::geometry::Shape;

/// Segments around the axis of cylinders, cones and spheres: enough for round silhouettes at
/// 224 px, few enough that a room of ~150 parts stays cheap on a CPU rasteriser.
pub const SEGMENTS: u32 = 24;
/// Latitude bands of the sphere.
pub const SPHERE_RINGS: u32 = 12;
/// Coarser tessellation for small round parts (legs, handles, fruit, hands): a few pixels
/// across at the robot's distances, where 24 segments would only cost vertex work.
pub const SMALL_SEGMENTS: u32 = 10;
pub const SMALL_SPHERE_RINGS: u32 = 6;
/// Round parts with a radius below this use the coarse meshes (metres).
pub const SMALL_RADIUS: f32 = 0.08;
/// A round part is also drawn with its coarse mesh in a view where that moves its silhouette
/// by at most this many pixels (images up to 5 px in radius): at 64×64 most round parts
/// beyond a metre, where the fine mesh's hundreds of triangles fall on a handful of pixels.
pub const LOD_TOLERANCE_PX: f32 = 0.25;
/// Number of unit meshes: box, then fine cylinder, sphere, cone, then coarse ones.
pub const MESH_COUNT: usize = 7;

/// One vertex of a unit mesh: position and outward normal in the shape's own frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// A triangle mesh with 16-bit indices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u16>,
}

impl Mesh {
    fn vertex(&mut self, position: [f32; 3], normal: [f32; 3]) -> u16 {
        let i = self.vertices.len();
        assert!(i < u16::MAX as usize, "unit mesh too large for 16-bit indices");
        self.vertices.push(Vertex { position, normal });
        i as u16
    }

    /// Adds triangle (a, b, c), flipped if needed so that its edge cross product points
    /// along `outward`.
    fn tri(&mut self, a: u16, b: u16, c: u16, outward: [f32; 3]) {
        let p = |i: u16| self.vertices[i as usize].position;
        let (pa, pb, pc) = (p(a), p(b), p(c));
        let e1 = sub(pb, pa);
        let e2 = sub(pc, pa);
        let n = cross(e1, e2);
        if dot(n, outward) >= 0.0 {
            self.indices.extend_from_slice(&[a, b, c]);
        } else {
            self.indices.extend_from_slice(&[a, c, b]);
        }
    }

    /// The unit mesh of a shape.
    pub fn unit(shape: Shape) -> Mesh {
        match shape {
            Shape::Box => unit_box(),
            Shape::Cylinder => unit_cylinder(SEGMENTS),
            Shape::Sphere => unit_sphere(SEGMENTS, SPHERE_RINGS),
            Shape::Cone => unit_cone(SEGMENTS),
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Box with flat normals: four vertices per face so edges stay crisp.
fn unit_box() -> Mesh {
    let mut m = Mesh::default();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut n = [0.0; 3];
            n[axis] = sign;
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut corner = |a: f32, b: f32| {
                let mut p = [0.0; 3];
                p[axis] = sign;
                p[u] = a;
                p[v] = b;
                m.vertex(p, n)
            };
            let q = [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)];
            m.tri(q[0], q[1], q[2], n);
            m.tri(q[0], q[2], q[3], n);
        }
    }
    m
}

fn ring(k: u32, segments: u32) -> (f32, f32) {
    let a = std::f32::consts::TAU * k as f32 / segments as f32;
    (a.cos(), a.sin())
}

/// A flat disc at height `y` facing `ny` (±1), radius 1.
fn cap(m: &mut Mesh, y: f32, ny: f32, segments: u32) {
    let n = [0.0, ny, 0.0];
    let c = m.vertex([0.0, y, 0.0], n);
    let first = m.vertices.len() as u16;
    for k in 0..segments {
        let (x, z) = ring(k, segments);
        m.vertex([x, y, z], n);
    }
    for k in 0..segments as u16 {
        let a = first + k;
        let b = first + (k + 1) % segments as u16;
        m.tri(c, a, b, n);
    }
}

/// Cylinder of radius 1 from y = −1 to 1 with smooth sides and flat caps.
fn unit_cylinder(segments: u32) -> Mesh {
    let mut m = Mesh::default();
    let first = m.vertices.len() as u16;
    for k in 0..=segments {
        let (x, z) = ring(k, segments);
        m.vertex([x, -1.0, z], [x, 0.0, z]);
        m.vertex([x, 1.0, z], [x, 0.0, z]);
    }
    for k in 0..segments as u16 {
        let (b0, t0, b1, t1) = (first + 2 * k, first + 2 * k + 1, first + 2 * k + 2, first + 2 * k + 3);
        let (x, z) = ring(k as u32 * 2 + 1, segments * 2);
        m.tri(b0, b1, t1, [x, 0.0, z]);
        m.tri(b0, t1, t0, [x, 0.0, z]);
    }
    cap(&mut m, 1.0, 1.0, segments);
    cap(&mut m, -1.0, -1.0, segments);
    m
}

/// Sphere of radius 1 with smooth normals, `segments` around and `rings` from pole to pole.
fn unit_sphere(segments: u32, rings: u32) -> Mesh {
    let mut m = Mesh::default();
    for r in 0..=rings {
        let phi = std::f32::consts::PI * r as f32 / rings as f32;
        let (sp, cp) = phi.sin_cos();
        for k in 0..=segments {
            let (x, z) = ring(k, segments);
            let p = [x * sp, -cp, z * sp];
            m.vertex(p, p);
        }
    }
    let row = segments as u16 + 1;
    for r in 0..rings as u16 {
        for k in 0..segments as u16 {
            let a = r * row + k;
            let b = a + 1;
            let c = a + row;
            let d = c + 1;
            let centre = {
                let v = |i: u16| m.vertices[i as usize].position;
                let (pa, pb, pc, pd) = (v(a), v(b), v(c), v(d));
                [
                    (pa[0] + pb[0] + pc[0] + pd[0]) / 4.0,
                    (pa[1] + pb[1] + pc[1] + pd[1]) / 4.0,
                    (pa[2] + pb[2] + pc[2] + pd[2]) / 4.0,
                ]
            };
            // the bands touching a pole have one degenerate triangle each: skip it
            if r != 0 {
                m.tri(a, b, c, centre);
            }
            if r != rings as u16 - 1 {
                m.tri(b, d, c, centre);
            }
        }
    }
    m
}

/// Cone of radius 1 at y = −1 with its apex at y = 1; one apex vertex per segment so the
/// side normals stay smooth around and correct up the slope.
fn unit_cone(segments: u32) -> Mesh {
    let mut m = Mesh::default();
    // side normal of a cone of height 2 and radius 1: (2 cos θ, 1, 2 sin θ) / √5
    let s5 = 5.0f32.sqrt();
    let base = m.vertices.len() as u16;
    for k in 0..=segments {
        let (x, z) = ring(k, segments);
        m.vertex([x, -1.0, z], [2.0 * x / s5, 1.0 / s5, 2.0 * z / s5]);
    }
    for k in 0..segments {
        let (x, z) = ring(2 * k + 1, 2 * segments);
        let n = [2.0 * x / s5, 1.0 / s5, 2.0 * z / s5];
        let apex = m.vertex([0.0, 1.0, 0.0], n);
        m.tri(base + k as u16, base + k as u16 + 1, apex, n);
    }
    cap(&mut m, -1.0, -1.0, segments);
    m
}

/// Where one shape's mesh lies in the shared vertex and index buffers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MeshRange {
    pub first_index: u32,
    pub index_count: u32,
    pub base_vertex: i32,
}

/// All unit meshes concatenated, with each one's range (indexed by `mesh_index`).
pub fn all_unit_meshes() -> (Vec<Vertex>, Vec<u16>, [MeshRange; MESH_COUNT]) {
    let mut vertices = Vec::new();
    let mut indices = Vec::new();
    let mut ranges = [MeshRange::default(); MESH_COUNT];
    let meshes = [
        Mesh::unit(Shape::Box),
        Mesh::unit(Shape::Cylinder),
        Mesh::unit(Shape::Sphere),
        Mesh::unit(Shape::Cone),
        unit_cylinder(SMALL_SEGMENTS),
        unit_sphere(SMALL_SEGMENTS, SMALL_SPHERE_RINGS),
        unit_cone(SMALL_SEGMENTS),
    ];
    for (i, m) in meshes.iter().enumerate() {
        ranges[i] = MeshRange {
            first_index: indices.len() as u32,
            index_count: m.indices.len() as u32,
            base_vertex: vertices.len() as i32,
        };
        vertices.extend_from_slice(&m.vertices);
        indices.extend_from_slice(&m.indices);
    }
    // wgpu copies must be a multiple of 4 bytes
    if indices.len() % 2 == 1 {
        indices.push(0);
    }
    (vertices, indices, ranges)
}

/// Which unit mesh draws a part: its shape, coarse for small round parts.
pub fn mesh_index(part: &crate::geometry::Part) -> usize {
    let radius = round_radius(part);
    match part.shape {
        Shape::Box => 0,
        _ if radius < SMALL_RADIUS => fine_mesh(part.shape) + 3,
        _ => fine_mesh(part.shape),
    }
}

fn fine_mesh(shape: Shape) -> usize {
    match shape {
        Shape::Box => 0,
        Shape::Cylinder => 1,
        Shape::Sphere => 2,
        Shape::Cone => 3,
    }
}

/// The radius of a round part's cross-section (what its segment count approximates); 0 for
/// a box.
pub fn round_radius(part: &crate::geometry::Part) -> f32 {
    let h = part.half_extents;
    match part.shape {
        Shape::Box => 0.0,
        Shape::Cylinder | Shape::Cone => h.x.max(h.z),
        Shape::Sphere => h.x.max(h.y).max(h.z),
    }
}

/// The coarse mesh of a fine round one (None for the box and the coarse meshes).
pub fn coarse_of(mesh: usize) -> Option<usize> {
    (1..=3).contains(&mesh).then_some(mesh + 3)
}

/// How far the coarse meshes' silhouettes lie inside the true surface, as a share of the
/// radius: 1 − cos(π / segments) (the sphere's 30° latitude bands deviate less).
pub fn coarse_error() -> f32 {
    1.0 - (std::f32::consts::PI / SMALL_SEGMENTS as f32).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Closed meshes: every edge is shared by exactly two triangles in opposite directions.
    fn assert_closed(m: &Mesh, what: &str) {
        use std::collections::HashMap;
        // weld by position so the seams of flat-shaded faces count as shared
        let key = |i: u16| {
            let p = m.vertices[i as usize].position;
            [(p[0] * 1e4).round() as i64, (p[1] * 1e4).round() as i64, (p[2] * 1e4).round() as i64]
        };
        let mut edges: HashMap<([i64; 3], [i64; 3]), i32> = HashMap::new();
        for t in m.indices.chunks_exact(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let (ka, kb) = (key(a), key(b));
                if ka == kb {
                    continue;
                }
                *edges.entry((ka, kb)).or_default() += 1;
            }
        }
        for ((a, b), n) in &edges {
            let back = edges.get(&(*b, *a)).copied().unwrap_or(0);
            assert_eq!(*n, back, "{what}: edge {a:?}->{b:?} used {n} times one way and {back} the other");
        }
    }

    #[test]
    fn unit_meshes_are_closed_outward_and_span_the_unit_cube() {
        for shape in Shape::ALL {
            let m = Mesh::unit(shape);
            assert_closed(&m, &format!("{shape:?}"));
            let mut lo = [f32::MAX; 3];
            let mut hi = [f32::MIN; 3];
            for v in &m.vertices {
                for k in 0..3 {
                    lo[k] = lo[k].min(v.position[k]);
                    hi[k] = hi[k].max(v.position[k]);
                }
                let len = dot(v.normal, v.normal).sqrt();
                assert!((len - 1.0).abs() < 1e-4, "{shape:?}: normal not unit");
            }
            for k in 0..3 {
                assert!((lo[k] + 1.0).abs() < 1e-5 && (hi[k] - 1.0).abs() < 1e-5, "{shape:?} spans {lo:?}..{hi:?}");
            }
            // every triangle faces away from the centre (all shapes are convex around it)
            for t in m.indices.chunks_exact(3) {
                let p = |i: u16| m.vertices[i as usize].position;
                let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
                let n = cross(sub(b, a), sub(c, a));
                let centroid = [(a[0] + b[0] + c[0]) / 3.0, (a[1] + b[1] + c[1]) / 3.0, (a[2] + b[2] + c[2]) / 3.0];
                assert!(dot(n, centroid) > 0.0, "{shape:?}: inward triangle");
            }
        }
    }

    #[test]
    fn coarse_meshes_are_closed_too() {
        assert_closed(&unit_cylinder(SMALL_SEGMENTS), "small cylinder");
        assert_closed(&unit_sphere(SMALL_SEGMENTS, SMALL_SPHERE_RINGS), "small sphere");
        assert_closed(&unit_cone(SMALL_SEGMENTS), "small cone");
        let (v, i, r) = all_unit_meshes();
        assert!(v.len() < u16::MAX as usize);
        let last = r[MESH_COUNT - 1];
        assert!((last.first_index + last.index_count) as usize <= i.len());
    }

    #[test]
    fn meshes_are_moderate() {
        let tris: Vec<usize> = Shape::ALL.iter().map(|s| Mesh::unit(*s).triangle_count()).collect();
        assert_eq!(tris[0], 12);
        assert!(tris.iter().all(|t| *t <= 600), "{tris:?}");
    }
}
