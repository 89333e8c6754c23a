//! What an object covers seen from above: the convex hull of each part's mesh projected on the
//! floor (x–z).

use std::sync::OnceLock;

use nalgebra::Vector3;
use worker::geometry::{Part, Shape};
use worker::render::mesh::Mesh;

/// Convex hull (counter-clockwise) of 2D points, Andrew's monotone chain.
fn convex_hull(mut pts: Vec<(f32, f32)>) -> Vec<(f32, f32)> {
    pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: (f32, f32), a: (f32, f32), b: (f32, f32)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    let mut hull: Vec<(f32, f32)> = Vec::with_capacity(pts.len() * 2);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f32, f32)>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Unit-mesh vertex positions per shape, used to find a part's footprint.
fn shape_outline(shape: Shape) -> &'static [[f32; 3]] {
    static OUTLINES: OnceLock<Vec<Vec<[f32; 3]>>> = OnceLock::new();
    let all = OUTLINES.get_or_init(|| {
        Shape::ALL.iter().map(|&s| Mesh::unit(s).vertices.iter().map(|v| v.position).collect()).collect()
    });
    let i = Shape::ALL.iter().position(|&s| s == shape).expect("every shape is in Shape::ALL");
    &all[i]
}

/// The part's outline seen from above: the convex hull of its mesh projected on x–z.
pub(super) fn footprint(p: &Part) -> Vec<(f32, f32)> {
    let pts = shape_outline(p.shape)
        .iter()
        .map(|v| {
            let w = p.center + p.rotation * Vector3::from(*v).component_mul(&p.half_extents);
            (w.x, w.z)
        })
        .collect();
    convex_hull(pts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn convex_hull_of_a_square_with_inner_points() {
        let h = convex_hull(vec![(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.5, 0.5), (0.2, 0.7)]);
        assert_eq!(h.len(), 4);
    }

    #[test]
    fn footprint_of_a_turned_box_is_turned() {
        let p = Part::new(Shape::Box, Point3::new(1.0, 0.5, 2.0), Vector3::new(1.0, 0.5, 0.1), [1.0; 3])
            .with_rotation(worker::geometry::yaw_rotation(90.0));
        let f = footprint(&p);
        let (xs, zs): (Vec<f32>, Vec<f32>) = f.iter().copied().unzip();
        let span = |v: &[f32]| v.iter().cloned().fold(f32::MIN, f32::max) - v.iter().cloned().fold(f32::MAX, f32::min);
        assert!((span(&xs) - 0.2).abs() < 1e-4 && (span(&zs) - 2.0).abs() < 1e-4);
    }
}
