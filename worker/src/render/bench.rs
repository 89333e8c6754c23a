//! Render throughput measurement (`orchestrator bench sim`, `cargo bench --bench render`) and
//! the fixtures it measures: a hand-built living room of about 150 parts and a simple standing
//! figure in place of the person.

use std::time::Instant;

use nalgebra::{Point3, UnitQuaternion, Vector3};

use super::{RenderError, Renderer, View, ViewOut};
use crate::camera::Camera;
use crate::geometry::{ID_HUMAN, ID_STRUCTURE, Material, Part, Shape, yaw_rotation};
use crate::scene::{Category, Object, Room, Scene, SceneType, Surface};

/// A furnished 6 m × 5 m living room with a dining corner and a desk: 33 objects, about 150
/// parts, the size of the generated rooms. Built by hand so benchmarks and tests do not
/// depend on the room generator.
pub fn benchmark_room() -> Scene {
    use Category::*;
    let o = |category, position: [f32; 3], yaw: f32, size: [f32; 3], color: [f32; 3], style: u32, on: Option<usize>| {
        Object { category, position, yaw, size, color, style, on }
    };
    let wood = [0.55, 0.38, 0.22];
    let dark_wood = [0.36, 0.22, 0.12];
    // heights of the host surfaces
    let (coffee_h, side_h, dining_h, desk_h, stand_h) = (0.43, 0.6, 0.76, 0.76, 0.5);
    let objects = vec![
        o(Sofa, [0.0, 0.45, -2.05], 0.0, [2.0, 0.9, 0.9], [0.18, 0.28, 0.50], 1, None), // 0
        o(CoffeeTable, [0.0, coffee_h / 2.0, -1.0], 0.0, [1.1, coffee_h, 0.6], wood, 0, None), // 1
        o(ArmChair, [-2.0, 0.45, -1.0], 90.0, [0.85, 0.9, 0.8], [0.55, 0.12, 0.10], 0, None), // 2
        o(ArmChair, [2.0, 0.45, -1.0], 270.0, [0.85, 0.9, 0.8], [0.45, 0.45, 0.42], 0, None), // 3
        o(Rug, [0.0, 0.005, -1.0], 0.0, [2.2, 0.01, 1.5], [0.55, 0.20, 0.15], 0, None), // 4
        o(SideTable, [1.4, side_h / 2.0, -2.2], 0.0, [0.5, side_h, 0.45], dark_wood, 1, None), // 5
        o(DeskLamp, [1.4, side_h + 0.2, -2.2], 0.0, [0.2, 0.4, 0.2], [0.95, 0.88, 0.65], 0, Some(5)), // 6
        o(FloorLamp, [-2.6, 0.8, -2.1], 0.0, [0.38, 1.6, 0.38], [0.90, 0.90, 0.85], 0, None), // 7
        o(Window, [-1.6, 1.5, -2.47], 0.0, [1.0, 1.0, 0.06], [0.80, 0.90, 1.00], 0, None), // 8
        o(Window, [2.97, 1.45, -1.0], 270.0, [1.2, 1.1, 0.06], [0.80, 0.90, 1.00], 1, None), // 9
        o(Poster, [-2.99, 1.5, -0.6], 90.0, [0.6, 0.8, 0.02], [0.20, 0.45, 0.75], 1, None), // 10
        o(TvStand, [-1.5, stand_h / 2.0, 2.29], 180.0, [1.4, stand_h, 0.42], dark_wood, 0, None), // 11
        o(Television, [-1.5, stand_h + 0.3, 2.3], 180.0, [1.0, 0.6, 0.09], [0.05, 0.05, 0.06], 1, Some(11)), // 12
        o(TissueBox, [-0.95, stand_h + 0.06, 2.3], 180.0, [0.22, 0.12, 0.12], [0.30, 0.55, 0.80], 0, Some(11)), // 13
        o(Shelf, [-2.82, 0.75, 0.8], 90.0, [0.9, 1.5, 0.35], wood, 0, None),            // 14
        o(Door, [2.4, 1.04, 2.47], 180.0, [0.9, 2.08, 0.05], [0.90, 0.90, 0.88], 0, None), // 15
        o(DiningTable, [1.0, dining_h / 2.0, 1.1], 0.0, [1.4, dining_h, 0.85], wood, 0, None), // 16
        o(Chair, [0.65, 0.46, 0.4], 0.0, [0.46, 0.92, 0.5], wood, 0, None),             // 17
        o(Chair, [1.35, 0.46, 0.4], 0.0, [0.46, 0.92, 0.5], wood, 1, None),             // 18
        o(Chair, [0.65, 0.46, 1.8], 180.0, [0.46, 0.92, 0.5], wood, 1, None),           // 19
        o(Chair, [1.35, 0.46, 1.8], 180.0, [0.46, 0.92, 0.5], wood, 0, None),           // 20
        o(Plate, [0.75, dining_h + 0.014, 1.1], 0.0, [0.25, 0.028, 0.25], [0.95, 0.95, 0.93], 0, Some(16)), // 21
        o(Plate, [1.25, dining_h + 0.014, 1.1], 0.0, [0.25, 0.028, 0.25], [0.75, 0.85, 0.90], 0, Some(16)), // 22
        o(Fork, [0.55, dining_h + 0.007, 1.1], 90.0, [0.19, 0.014, 0.028], [0.75, 0.75, 0.78], 0, Some(16)), // 23
        o(Knife, [0.95, dining_h + 0.009, 1.1], 90.0, [0.28, 0.018, 0.035], [0.75, 0.75, 0.78], 0, Some(16)), // 24
        o(Apple, [1.0, dining_h + 0.045, 1.35], 0.0, [0.09, 0.09, 0.09], [0.75, 0.08, 0.06], 0, Some(16)), // 25
        o(Bread, [1.45, dining_h + 0.06, 1.4], 20.0, [0.28, 0.12, 0.13], [0.72, 0.48, 0.22], 0, Some(16)), // 26
        o(Desk, [2.7, desk_h / 2.0, 1.0], 270.0, [1.2, desk_h, 0.6], dark_wood, 0, None), // 27
        o(Laptop, [2.7, desk_h + 0.12, 0.8], 270.0, [0.35, 0.24, 0.25], [0.25, 0.25, 0.27], 0, Some(27)), // 28
        o(Cup, [2.6, desk_h + 0.05, 1.3], 0.0, [0.09, 0.1, 0.09], [0.20, 0.40, 0.70], 0, Some(27)), // 29
        o(RemoteControl, [-0.2, coffee_h + 0.011, -1.1], 10.0, [0.05, 0.022, 0.18], [0.08, 0.08, 0.09], 0, Some(1)), // 30
        o(Newspaper, [0.25, coffee_h + 0.015, -0.95], -15.0, [0.3, 0.03, 0.22], [0.80, 0.79, 0.74], 0, Some(1)), // 31
        o(Box, [2.6, 0.15, 2.0], 30.0, [0.4, 0.3, 0.35], [0.68, 0.50, 0.30], 0, None),                           // 32
    ];
    Scene {
        name: "BenchmarkLivingRoom".into(),
        scene_type: SceneType::LivingRoom,
        seed: 0,
        room: Room {
            width: 6.0,
            depth: 5.0,
            height: 2.7,
            floor: Surface { color: [0.62, 0.46, 0.30], material: Material::Wood },
            walls: Surface { color: [0.85, 0.82, 0.74], material: Material::Matte },
            ceiling: Surface { color: [0.95, 0.95, 0.95], material: Material::Matte },
        },
        walls: vec![],
        objects,
    }
}

/// A simple standing figure (15 parts, id `ID_HUMAN`) with its feet at `feet` facing `yaw_deg`:
/// what the person looks like to the renderer until the skinned humanoid replaces it in a
/// frame's dynamic parts. `raise_right` lifts the right arm forward, as when pointing.
pub fn figure_parts(feet: Point3<f32>, yaw_deg: f32, raise_right: bool) -> Vec<Part> {
    let rot = yaw_rotation(yaw_deg);
    let skin = [0.80, 0.60, 0.48];
    let shirt = [0.20, 0.45, 0.30];
    let trousers = [0.15, 0.17, 0.25];
    let shoes = [0.08, 0.07, 0.07];
    let mut out = Vec::with_capacity(15);
    let mut add = |shape, c: [f32; 3], he: [f32; 3], r: UnitQuaternion<f32>, color, m| {
        out.push(Part {
            shape,
            center: feet + rot * Vector3::from(c),
            rotation: rot * r,
            half_extents: Vector3::from(he),
            color,
            material: m,
            id: ID_HUMAN,
            solid: true,
        });
    };
    let id = UnitQuaternion::identity();
    for s in [-1.0f32, 1.0] {
        add(Shape::Box, [s * 0.1, 0.04, 0.04], [0.05, 0.04, 0.12], id, shoes, Material::Matte);
        add(Shape::Cylinder, [s * 0.1, 0.47, 0.0], [0.065, 0.4, 0.065], id, trousers, Material::Fabric);
    }
    add(Shape::Box, [0.0, 0.95, 0.0], [0.17, 0.1, 0.1], id, trousers, Material::Fabric);
    add(Shape::Box, [0.0, 1.25, 0.0], [0.19, 0.22, 0.11], id, shirt, Material::Fabric);
    add(Shape::Cylinder, [0.0, 1.5, 0.0], [0.05, 0.05, 0.05], id, skin, Material::Skin);
    add(Shape::Sphere, [0.0, 1.64, 0.01], [0.095, 0.12, 0.105], id, skin, Material::Skin);
    add(Shape::Sphere, [0.0, 1.69, -0.01], [0.1, 0.08, 0.1], id, [0.2, 0.13, 0.08], Material::Fabric);
    for s in [-1.0f32, 1.0] {
        let raised = raise_right && s > 0.0;
        if raised {
            // arm held forward, a little below shoulder height
            let fwd = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::FRAC_PI_2 - 0.2);
            add(Shape::Cylinder, [0.24, 1.37, 0.17], [0.045, 0.15, 0.045], fwd, shirt, Material::Fabric);
            add(Shape::Cylinder, [0.24, 1.3, 0.45], [0.04, 0.14, 0.04], fwd, skin, Material::Skin);
            add(Shape::Sphere, [0.24, 1.27, 0.63], [0.045, 0.045, 0.06], id, skin, Material::Skin);
        } else {
            add(Shape::Cylinder, [s * 0.24, 1.28, 0.0], [0.045, 0.15, 0.045], id, shirt, Material::Fabric);
            add(Shape::Cylinder, [s * 0.24, 0.99, 0.0], [0.04, 0.14, 0.04], id, skin, Material::Skin);
            add(Shape::Sphere, [s * 0.24, 0.8, 0.0], [0.045, 0.06, 0.03], id, skin, Material::Skin);
        }
    }
    out
}

/// Cameras at the robot's eye height spread over a room (an ellipse around its middle, each
/// turned a different way): `count` views that see different parts of the scene.
pub fn spread_cameras(parts: &[Part], count: usize) -> Vec<Camera> {
    let structure: Vec<&Part> = parts.iter().filter(|p| p.id == ID_STRUCTURE).collect();
    let pool: Vec<&Part> = if structure.is_empty() { parts.iter().collect() } else { structure };
    let mut lo = Point3::new(-1.0f32, 0.0, -1.0);
    let mut hi = Point3::new(1.0f32, 0.0, 1.0);
    if let Some(first) = pool.first() {
        (lo, hi) = first.aabb();
        for p in &pool {
            let (a, b) = p.aabb();
            lo = lo.inf(&a);
            hi = hi.sup(&b);
        }
    }
    let c = nalgebra::center(&lo, &hi);
    let (rx, rz) = ((hi.x - lo.x) * 0.25, (hi.z - lo.z) * 0.25);
    (0..count)
        .map(|i| {
            let t = std::f32::consts::TAU * (i as f32 + 0.5) / count.max(1) as f32;
            let position = Point3::new(c.x + rx * t.sin(), 1.5, c.z + rz * t.cos());
            Camera::new(position, (i as f32 * 137.5) % 360.0)
        })
        .collect()
}

/// Measures render throughput: renders `views_per_submit` views of `parts` (plus a standing
/// figure as the dynamic part) per call, with colour, depth and id readback, for about
/// `seconds` after a warm-up, and returns views per second. The renderer's own
/// `views_per_submit` should be at least as large, else each call is split into chunks.
pub fn bench_views(
    renderer: &mut Renderer,
    parts: &[Part],
    views_per_submit: usize,
    seconds: f64,
) -> Result<f64, RenderError> {
    let k = views_per_submit.max(1);
    let scene = renderer.upload_scene(parts);
    let cameras = spread_cameras(parts, k);
    let figure = {
        let c = cameras.iter().fold(Vector3::zeros(), |a, c| a + c.position.coords) / k as f32;
        figure_parts(Point3::new(c.x + 0.4, 0.0, c.z + 0.3), 200.0, true)
    };
    let views: Vec<View> = cameras.iter().map(|&camera| View { scene, camera, dynamic: &figure }).collect();
    let n = renderer.config().pixels();
    let mut rgb = vec![0u8; k * n * 3];
    let mut depth = vec![0u16; k * n];
    let mut ids = vec![0u16; k * n];
    let mut run = |r: &mut Renderer| -> Result<(), RenderError> {
        r.render(&views, &mut ViewOut::split(&mut rgb, &mut depth, &mut ids, n))
    };
    let result = (|| {
        for _ in 0..2 {
            run(renderer)?;
        }
        let start = Instant::now();
        let mut calls = 0u64;
        while calls < 3 || start.elapsed().as_secs_f64() < seconds {
            run(renderer)?;
            calls += 1;
        }
        Ok((calls * k as u64) as f64 / start.elapsed().as_secs_f64())
    })();
    renderer.release_scene(scene);
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn benchmark_room_is_valid_and_realistic() {
        let s = benchmark_room();
        s.validate().unwrap();
        let n = s.parts().len();
        assert!((130..=180).contains(&n), "{n} parts");
        for (i, o) in s.objects.iter().enumerate() {
            if let Some(h) = o.on {
                let host = &s.objects[h];
                let top = host.position[1] + host.size[1] / 2.0;
                let bottom = o.position[1] - o.size[1] / 2.0;
                assert!((top - bottom).abs() < 0.01, "object {i} does not rest on object {h}");
            }
        }
        assert_eq!(figure_parts(Point3::origin(), 0.0, false).len(), 15);
        assert_eq!(figure_parts(Point3::origin(), 0.0, true).len(), 15);
    }
}
