//! Scenes: rooms with walls, furniture and target objects, as plain serde data.
//!
//! A scene file is JSON that a person can write by hand: the room's size and surfaces, extra
//! wall segments, and a list of objects (category, bounding-box centre, yaw, size, colour,
//! style). Geometry is derived from that description by the catalog, so hand-written and
//! generated scenes are built the same way.

pub mod catalog;
pub mod generate;

use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

pub use catalog::{Category, Placement, targets_of};
pub use farm::rooms::{SceneId, SceneType, Split};

use crate::geometry::{ID_FIRST_OBJECT, ID_STRUCTURE, Material, Part, Shape, yaw_rotation};

/// A surface's look.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Surface {
    pub color: [f32; 3],
    #[serde(default)]
    pub material: Material,
}

/// The room: an axis-aligned box centred on the origin, floor at y = 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Room {
    /// Extent along x (metres).
    pub width: f32,
    /// Extent along z (metres).
    pub depth: f32,
    /// Floor to ceiling (metres).
    pub height: f32,
    pub floor: Surface,
    pub walls: Surface,
    pub ceiling: Surface,
}

impl Room {
    pub fn half(&self) -> (f32, f32) {
        (self.width / 2.0, self.depth / 2.0)
    }

    /// Whether an (x, z) point lies inside the room, `margin` metres from every wall.
    pub fn contains(&self, x: f32, z: f32, margin: f32) -> bool {
        let (hx, hz) = self.half();
        x >= -hx + margin && x <= hx - margin && z >= -hz + margin && z <= hz - margin
    }
}

/// An extra wall piece inside the room (a partition, the side of an alcove).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallSegment {
    /// (x, z) of one end.
    pub from: [f32; 2],
    /// (x, z) of the other end.
    pub to: [f32; 2],
    pub thickness: f32,
}

/// One object in the room.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Object {
    pub category: Category,
    /// Centre of the bounding box (x, y, z) in metres. A target's position is this point.
    pub position: [f32; 3],
    /// Degrees, clockwise from above; the object's front faces the heading of this yaw.
    pub yaw: f32,
    /// Full extents (width x, height y, depth z) before the yaw.
    pub size: [f32; 3],
    /// Base colour, linear RGB 0..1.
    pub color: [f32; 3],
    /// Picks among the category's geometric variants.
    #[serde(default)]
    pub style: u32,
    /// Index of the object this one rests on or hangs from, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on: Option<usize>,
}

impl Object {
    pub fn center(&self) -> Point3<f32> {
        Point3::from(self.position)
    }

    pub fn parts(&self, index: usize) -> Vec<Part> {
        catalog::build_parts(
            self.category,
            self.center(),
            self.yaw,
            Vector3::from(self.size),
            self.color,
            self.style,
            object_id(index),
        )
    }
}

/// The instance id that object `index` renders with.
pub fn object_id(index: usize) -> u16 {
    ID_FIRST_OBJECT + index as u16
}

/// The object index of an instance id, if it is one.
pub fn object_index(id: u16) -> Option<usize> {
    id.checked_sub(ID_FIRST_OBJECT).map(usize::from)
}

/// A room and everything in it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// "FloorPlan201" for the generated rooms; any name for hand-written ones.
    pub name: String,
    pub scene_type: SceneType,
    /// The seed it was generated from (0 for hand-written scenes).
    #[serde(default)]
    pub seed: u64,
    pub room: Room,
    #[serde(default)]
    pub walls: Vec<WallSegment>,
    pub objects: Vec<Object>,
}

/// A scene file that cannot be used, with the file and the field at fault.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{file}: cannot read: {reason}")]
    Io { file: String, reason: std::io::Error },
    #[error("{file}: field `{field}`: {message}")]
    Field { file: String, field: String, message: String },
}

const WALL_THICKNESS: f32 = 0.1;

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|reason| SceneError::Io { file: file.clone(), reason })?;
        Scene::from_json(&text, &file)
    }

    /// Parses and validates scene JSON; `file` names the source in errors.
    pub fn from_json(text: &str, file: &str) -> Result<Scene, SceneError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let scene: Scene = serde_path_to_error::deserialize(de).map_err(|e| SceneError::Field {
            file: file.to_string(),
            field: e.path().to_string(),
            message: e.inner().to_string(),
        })?;
        scene.validate().map_err(|(field, message)| SceneError::Field { file: file.to_string(), field, message })?;
        Ok(scene)
    }

    /// Pretty JSON with a trailing newline; byte-identical for identical scenes.
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).expect("scene serialises");
        s.push('\n');
        s
    }

    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        farm::files::write_atomic(path, self.to_json().as_bytes())
    }

    /// Checks what serde cannot: sizes, positions inside the room, references.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        let r = &self.room;
        for (name, v) in [("room.width", r.width), ("room.depth", r.depth), ("room.height", r.height)] {
            if !(v.is_finite() && v > 1.0 && v < 100.0) {
                return Err((name.into(), format!("must be between 1 and 100 metres, got {v}")));
            }
        }
        if self.objects.len() > (u16::MAX - ID_FIRST_OBJECT) as usize {
            return Err(("objects".into(), format!("at most {} objects", u16::MAX - ID_FIRST_OBJECT)));
        }
        let (hx, hz) = r.half();
        for (i, w) in self.walls.iter().enumerate() {
            if !(finite(&w.from) && finite(&w.to) && w.thickness > 0.0) {
                return Err((format!("walls[{i}]"), "ends must be finite and thickness positive".into()));
            }
        }
        for (i, o) in self.objects.iter().enumerate() {
            let f = |k: &str| format!("objects[{i}].{k}");
            if !finite(&o.position) {
                return Err((f("position"), "must be finite".into()));
            }
            if !(o.size.iter().all(|s| s.is_finite() && *s > 0.0 && *s < 20.0)) {
                return Err((f("size"), format!("each extent must be in (0, 20) metres, got {:?}", o.size)));
            }
            if !o.yaw.is_finite() {
                return Err((f("yaw"), "must be finite".into()));
            }
            if !o.color.iter().all(|c| (0.0..=1.0).contains(c)) {
                return Err((f("color"), format!("components must be in 0..1, got {:?}", o.color)));
            }
            let [x, y, z] = o.position;
            if x.abs() > hx + 0.01 || z.abs() > hz + 0.01 || y < -0.01 || y > r.height + 0.01 {
                return Err((
                    f("position"),
                    format!("{:?} lies outside the {}×{}×{} m room", o.position, r.width, r.height, r.depth),
                ));
            }
            if let Some(h) = o.on {
                if h >= self.objects.len() || h == i {
                    return Err((f("on"), format!("refers to object {h}, which does not exist")));
                }
            }
        }
        Ok(())
    }

    /// Indices of the objects of a category.
    pub fn instances(&self, category: Category) -> impl Iterator<Item = usize> + '_ {
        self.objects.iter().enumerate().filter(move |(_, o)| o.category == category).map(|(i, _)| i)
    }

    /// Floor, walls (outer and extra) and ceiling.
    pub fn structure_parts(&self) -> Vec<Part> {
        let r = &self.room;
        let (hx, hz) = r.half();
        let t = WALL_THICKNESS;
        let mut out = Vec::with_capacity(8 + self.walls.len());
        let s = |shape, c: [f32; 3], he: [f32; 3], surf: &Surface| {
            Part::new(shape, Point3::from(c), Vector3::from(he), surf.color)
                .with_material(surf.material)
                .with_id(ID_STRUCTURE)
        };
        out.push(s(Shape::Box, [0.0, -t / 2.0, 0.0], [hx + t, t / 2.0, hz + t], &r.floor));
        out.push(s(Shape::Box, [0.0, r.height + t / 2.0, 0.0], [hx + t, t / 2.0, hz + t], &r.ceiling));
        let hy = r.height / 2.0;
        out.push(s(Shape::Box, [-hx - t / 2.0, hy, 0.0], [t / 2.0, hy, hz + t], &r.walls));
        out.push(s(Shape::Box, [hx + t / 2.0, hy, 0.0], [t / 2.0, hy, hz + t], &r.walls));
        out.push(s(Shape::Box, [0.0, hy, -hz - t / 2.0], [hx + t, hy, t / 2.0], &r.walls));
        out.push(s(Shape::Box, [0.0, hy, hz + t / 2.0], [hx + t, hy, t / 2.0], &r.walls));
        // a skirting board so wall and floor meet visibly
        let skirt = Surface { color: [0.9, 0.9, 0.88], material: Material::Matte };
        for (c, he) in [
            ([-hx + 0.005, 0.04, 0.0], [0.005, 0.04, hz]),
            ([hx - 0.005, 0.04, 0.0], [0.005, 0.04, hz]),
            ([0.0, 0.04, -hz + 0.005], [hx, 0.04, 0.005]),
            ([0.0, 0.04, hz - 0.005], [hx, 0.04, 0.005]),
        ] {
            out.push(s(Shape::Box, c, he, &skirt).non_solid());
        }
        for w in &self.walls {
            let (a, b) = (nalgebra::Vector2::from(w.from), nalgebra::Vector2::from(w.to));
            let mid = (a + b) / 2.0;
            let d = b - a;
            let yaw = crate::geometry::yaw_of(d);
            out.push(
                s(Shape::Box, [mid.x, hy, mid.y], [w.thickness / 2.0, hy, d.norm() / 2.0], &r.walls)
                    .with_rotation(yaw_rotation(yaw)),
            );
        }
        out
    }

    /// Every part of the scene: structure, then each object's parts.
    pub fn parts(&self) -> Vec<Part> {
        let mut out = self.structure_parts();
        for (i, o) in self.objects.iter().enumerate() {
            out.extend(o.parts(i));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> Scene {
        let surf = Surface { color: [0.5; 3], material: Material::Matte };
        Scene {
            name: "Tiny".into(),
            scene_type: SceneType::Kitchen,
            seed: 0,
            room: Room { width: 4.0, depth: 3.0, height: 2.7, floor: surf, walls: surf, ceiling: surf },
            walls: vec![],
            objects: vec![Object {
                category: Category::Chair,
                position: [0.0, 0.45, 0.0],
                yaw: 0.0,
                size: [0.5, 0.9, 0.5],
                color: [0.4, 0.3, 0.2],
                style: 0,
                on: None,
            }],
        }
    }

    #[test]
    fn floorplan_names_and_splits() {
        let ids: Vec<_> = SceneId::all().collect();
        assert_eq!(ids.len(), 120);
        assert_eq!(ids[0].name(), "FloorPlan1");
        assert_eq!(ids[30].name(), "FloorPlan201");
        assert_eq!(ids[119].name(), "FloorPlan430");
        for s in Split::ALL {
            let n = SceneId::of_split(s).count();
            assert_eq!(
                n,
                match s {
                    Split::Train => 80,
                    _ => 20,
                }
            );
        }
        assert_eq!(SceneId::parse("FloorPlan321").unwrap().split(), Split::Val);
        assert_eq!(SceneId::parse("FloorPlan430").unwrap().split(), Split::Test);
        assert!(SceneId::parse("FloorPlan31").is_none());
    }

    #[test]
    fn json_round_trip() {
        let s = tiny();
        let back = Scene::from_json(&s.to_json(), "mem").unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn bad_field_is_named() {
        let mut v: serde_json::Value = serde_json::from_str(&tiny().to_json()).unwrap();
        v["objects"][0]["category"] = "Spaceship".into();
        let err = Scene::from_json(&v.to_string(), "room.json").unwrap_err().to_string();
        assert!(err.contains("room.json") && err.contains("objects[0].category"), "{err}");

        let mut v: serde_json::Value = serde_json::from_str(&tiny().to_json()).unwrap();
        v["objects"][0]["size"] = serde_json::json!([0.5, -1.0, 0.5]);
        let err = Scene::from_json(&v.to_string(), "room.json").unwrap_err().to_string();
        assert!(err.contains("objects[0].size"), "{err}");

        let mut v: serde_json::Value = serde_json::from_str(&tiny().to_json()).unwrap();
        v["room"]["colour"] = "red".into();
        let err = Scene::from_json(&v.to_string(), "room.json").unwrap_err().to_string();
        assert!(err.contains("room"), "{err}");
    }
}
