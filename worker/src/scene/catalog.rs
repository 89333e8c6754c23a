//! What can stand in a room: the target categories of T3.3 and the furniture that hosts them,
//! with where each is placed and the primitives its geometry is built from.
//!
//! T3.3 lists 37 distinct category names over the four scene types (the text counts 38; its
//! "Break" is Bread). All 37 are targets here; the furniture below them (counters, beds,
//! toilets, ...) is context that hosts targets and blocks the way.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::{Material, Part, Shape, yaw_rotation};
use crate::scene::SceneType;

/// Target categories of a scene type (T3.3).
pub fn targets_of(scene_type: SceneType) -> &'static [Category] {
    use Category::*;
    match scene_type {
        SceneType::Kitchen => &[
            Apple,
            Bread,
            ButterKnife,
            Chair,
            Cup,
            DiningTable,
            Fork,
            Knife,
            PaperTowelRoll,
            Plate,
            Potato,
            RemoteControl,
            SideTable,
            Spoon,
            Tomato,
            Window,
        ],
        SceneType::LivingRoom => &[
            ArmChair,
            Box,
            Chair,
            CoffeeTable,
            DeskLamp,
            DiningTable,
            FloorLamp,
            Laptop,
            Newspaper,
            Plate,
            SideTable,
            Sofa,
            Television,
            TissueBox,
            Window,
        ],
        SceneType::Bedroom => &[
            AlarmClock,
            Box,
            Chair,
            DeskLamp,
            Laptop,
            Poster,
            RemoteControl,
            SideTable,
            Sofa,
            Television,
            TissueBox,
            Window,
        ],
        SceneType::Bathroom => &[
            HandTowel,
            HandTowelHolder,
            PaperTowelRoll,
            Plunger,
            ShowerCurtain,
            ShowerDoor,
            SideTable,
            TissueBox,
            ToiletPaper,
            ToiletPaperHanger,
            Towel,
            TowelHolder,
            Window,
        ],
    }
}

/// Where an object of a category goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// Stands on the floor, away from walls or against one.
    Floor,
    /// Stands on the floor with its back to a wall.
    FloorAgainstWall,
    /// Lies or stands on top of a host (table, counter, dresser, ...).
    Surface,
    /// Hangs on a wall at a height.
    Wall,
    /// Hangs on a holder of the given category.
    HangsOn(Category),
}

macro_rules! categories {
    ($($name:ident = $target:expr),* $(,)?) => {
        /// Every kind of object a scene can hold. Targets first (T3.3), then context furniture.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
        pub enum Category { $($name),* }

        impl Category {
            pub const ALL: &'static [Category] = &[$(Category::$name),*];

            pub const fn name(self) -> &'static str {
                match self { $(Category::$name => stringify!($name)),* }
            }

            /// Whether the category is a navigation target (listed in T3.3).
            pub const fn is_target(self) -> bool {
                match self { $(Category::$name => $target),* }
            }
        }
    };
}

categories! {
    // targets (T3.3)
    AlarmClock = true, Apple = true, ArmChair = true, Box = true, Bread = true,
    ButterKnife = true, Chair = true, CoffeeTable = true, Cup = true, DeskLamp = true,
    DiningTable = true, FloorLamp = true, Fork = true, HandTowel = true, HandTowelHolder = true,
    Knife = true, Laptop = true, Newspaper = true, PaperTowelRoll = true, Plate = true,
    Plunger = true, Poster = true, Potato = true, RemoteControl = true, ShowerCurtain = true,
    ShowerDoor = true, SideTable = true, Sofa = true, Spoon = true, Television = true,
    TissueBox = true, Tomato = true, ToiletPaper = true, ToiletPaperHanger = true, Towel = true,
    TowelHolder = true, Window = true,
    // context furniture
    CounterTop = false, Fridge = false, Stove = false, Bed = false, Dresser = false,
    Desk = false, TvStand = false, Shelf = false, Toilet = false, Bathtub = false,
    Sink = false, Rug = false, Door = false, Mirror = false,
}

impl Category {
    /// All target categories, in a fixed order: the index is the semantic label the policy sees.
    pub fn targets() -> impl Iterator<Item = Category> {
        Category::ALL.iter().copied().filter(|c| c.is_target())
    }

    /// Index among targets (the embedding index), None for context furniture.
    pub fn target_index(self) -> Option<u32> {
        Category::targets().position(|c| c == self).map(|i| i as u32)
    }

    pub fn from_target_index(i: u32) -> Option<Category> {
        Category::targets().nth(i as usize)
    }

    pub fn from_name(s: &str) -> Option<Category> {
        let s = if s == "Break" { "Bread" } else { s };
        Category::ALL.iter().copied().find(|c| c.name().eq_ignore_ascii_case(s))
    }

    pub fn placement(self) -> Placement {
        use Category::*;
        match self {
            Chair | ArmChair | DiningTable | CoffeeTable | SideTable | FloorLamp | Plunger | Rug => Placement::Floor,
            Sofa | Fridge | Stove | CounterTop | Bed | Dresser | Desk | TvStand | Shelf | Toilet | Bathtub | Sink
            | ShowerDoor | ShowerCurtain => Placement::FloorAgainstWall,
            Window | Poster | HandTowelHolder | TowelHolder | ToiletPaperHanger | Door | Mirror => Placement::Wall,
            HandTowel => Placement::HangsOn(HandTowelHolder),
            Towel => Placement::HangsOn(TowelHolder),
            _ => Placement::Surface,
        }
    }

    /// Whether other objects can be put on top of it, and at what height above its base the
    /// surface is (as a fraction of its height).
    pub fn is_host(self) -> bool {
        use Category::*;
        matches!(self, DiningTable | CoffeeTable | SideTable | CounterTop | Dresser | Desk | TvStand | Shelf)
    }

    /// Size range (width x, height y, depth z) in metres: (min, max).
    pub fn size_range(self) -> ([f32; 3], [f32; 3]) {
        use Category::*;
        match self {
            AlarmClock => ([0.10, 0.09, 0.06], [0.16, 0.14, 0.09]),
            Apple => ([0.07, 0.07, 0.07], [0.10, 0.10, 0.10]),
            ArmChair => ([0.75, 0.80, 0.75], [0.95, 1.00, 0.90]),
            Box => ([0.25, 0.18, 0.20], [0.50, 0.40, 0.40]),
            Bread => ([0.22, 0.10, 0.11], [0.32, 0.14, 0.15]),
            ButterKnife => ([0.20, 0.012, 0.025], [0.24, 0.015, 0.03]),
            Chair => ([0.42, 0.85, 0.45], [0.52, 1.00, 0.55]),
            CoffeeTable => ([0.80, 0.38, 0.50], [1.30, 0.48, 0.75]),
            Cup => ([0.08, 0.09, 0.08], [0.11, 0.12, 0.11]),
            DeskLamp => ([0.16, 0.35, 0.16], [0.25, 0.55, 0.25]),
            DiningTable => ([1.10, 0.74, 0.75], [1.80, 0.78, 1.00]),
            FloorLamp => ([0.30, 1.45, 0.30], [0.45, 1.75, 0.45]),
            Fork => ([0.18, 0.012, 0.025], [0.21, 0.015, 0.03]),
            HandTowel => ([0.25, 0.35, 0.04], [0.32, 0.45, 0.05]),
            HandTowelHolder => ([0.18, 0.06, 0.06], [0.26, 0.08, 0.08]),
            Knife => ([0.25, 0.015, 0.03], [0.33, 0.02, 0.04]),
            Laptop => ([0.32, 0.22, 0.23], [0.38, 0.26, 0.27]),
            Newspaper => ([0.28, 0.02, 0.20], [0.34, 0.04, 0.24]),
            PaperTowelRoll => ([0.11, 0.24, 0.11], [0.13, 0.28, 0.13]),
            Plate => ([0.22, 0.025, 0.22], [0.28, 0.03, 0.28]),
            Plunger => ([0.14, 0.45, 0.14], [0.16, 0.55, 0.16]),
            Poster => ([0.45, 0.60, 0.02], [0.80, 1.00, 0.02]),
            Potato => ([0.08, 0.06, 0.06], [0.12, 0.08, 0.08]),
            RemoteControl => ([0.05, 0.02, 0.16], [0.06, 0.025, 0.21]),
            ShowerCurtain => ([1.20, 1.80, 0.05], [1.60, 1.95, 0.05]),
            ShowerDoor => ([0.80, 1.85, 0.05], [1.10, 1.95, 0.05]),
            SideTable => ([0.40, 0.50, 0.40], [0.60, 0.70, 0.55]),
            Sofa => ([1.70, 0.85, 0.85], [2.30, 0.95, 1.00]),
            Spoon => ([0.16, 0.02, 0.035], [0.19, 0.025, 0.045]),
            Television => ([0.80, 0.50, 0.08], [1.20, 0.75, 0.10]),
            TissueBox => ([0.20, 0.10, 0.11], [0.24, 0.14, 0.13]),
            Tomato => ([0.07, 0.06, 0.07], [0.09, 0.08, 0.09]),
            ToiletPaper => ([0.10, 0.10, 0.10], [0.12, 0.11, 0.12]),
            ToiletPaperHanger => ([0.16, 0.06, 0.08], [0.20, 0.08, 0.10]),
            Towel => ([0.45, 0.60, 0.05], [0.60, 0.80, 0.06]),
            TowelHolder => ([0.50, 0.06, 0.08], [0.65, 0.08, 0.10]),
            Window => ([0.80, 0.90, 0.06], [1.40, 1.30, 0.06]),
            CounterTop => ([1.20, 0.90, 0.60], [2.40, 0.92, 0.65]),
            Fridge => ([0.70, 1.75, 0.70], [0.85, 1.95, 0.75]),
            Stove => ([0.60, 0.90, 0.60], [0.76, 0.92, 0.65]),
            Bed => ([1.40, 0.55, 2.00], [1.80, 0.65, 2.10]),
            Dresser => ([0.80, 0.80, 0.45], [1.30, 1.00, 0.55]),
            Desk => ([1.00, 0.74, 0.55], [1.40, 0.78, 0.70]),
            TvStand => ([1.00, 0.45, 0.40], [1.60, 0.55, 0.45]),
            Shelf => ([0.70, 1.20, 0.32], [1.00, 1.80, 0.38]),
            Toilet => ([0.40, 0.75, 0.65], [0.45, 0.80, 0.72]),
            Bathtub => ([1.50, 0.55, 0.75], [1.70, 0.60, 0.80]),
            Sink => ([0.55, 0.88, 0.45], [0.80, 0.92, 0.50]),
            Rug => ([1.40, 0.01, 1.00], [2.40, 0.01, 1.70]),
            Door => ([0.85, 2.05, 0.05], [0.95, 2.10, 0.05]),
            Mirror => ([0.50, 0.70, 0.02], [0.80, 0.90, 0.02]),
        }
    }

    /// Height of the centre above the floor for wall items (metres); None elsewhere.
    pub fn wall_height(self) -> Option<(f32, f32)> {
        use Category::*;
        match self {
            Window => Some((1.35, 1.60)),
            Poster => Some((1.35, 1.60)),
            Mirror => Some((1.45, 1.60)),
            HandTowelHolder => Some((1.05, 1.20)),
            TowelHolder => Some((1.10, 1.30)),
            ToiletPaperHanger => Some((0.65, 0.75)),
            Door => Some((1.03, 1.05)),
            _ => None,
        }
    }

    /// A small palette of plausible base colours (linear RGB) per category.
    pub fn palette(self) -> &'static [[f32; 3]] {
        use Category::*;
        const WOODS: &[[f32; 3]] = &[[0.42, 0.26, 0.13], [0.62, 0.44, 0.26], [0.30, 0.18, 0.10], [0.75, 0.62, 0.45]];
        const FABRICS: &[[f32; 3]] =
            &[[0.55, 0.12, 0.10], [0.18, 0.28, 0.50], [0.45, 0.45, 0.42], [0.25, 0.40, 0.22], [0.70, 0.60, 0.45]];
        const CLOTHS: &[[f32; 3]] = &[[0.85, 0.85, 0.80], [0.30, 0.55, 0.75], [0.80, 0.40, 0.45], [0.45, 0.70, 0.50]];
        const METALS: &[[f32; 3]] = &[[0.75, 0.75, 0.78], [0.55, 0.56, 0.58]];
        const WHITES: &[[f32; 3]] = &[[0.92, 0.92, 0.90], [0.85, 0.86, 0.88]];
        match self {
            AlarmClock => &[[0.80, 0.15, 0.12], [0.15, 0.15, 0.16], [0.90, 0.85, 0.30]],
            Apple => &[[0.75, 0.08, 0.06], [0.45, 0.70, 0.15], [0.85, 0.55, 0.10]],
            ArmChair | Sofa => FABRICS,
            Box => &[[0.68, 0.50, 0.30], [0.60, 0.44, 0.26]],
            Bread => &[[0.72, 0.48, 0.22], [0.60, 0.36, 0.16]],
            ButterKnife | Fork | Knife | Spoon => METALS,
            Chair | DiningTable | CoffeeTable | SideTable | Desk | Dresser | Shelf | TvStand => WOODS,
            Cup => &[[0.90, 0.90, 0.88], [0.20, 0.40, 0.70], [0.75, 0.25, 0.20], [0.30, 0.55, 0.35]],
            DeskLamp | FloorLamp => &[[0.95, 0.88, 0.65], [0.90, 0.90, 0.85], [0.85, 0.70, 0.50]],
            HandTowel | Towel => CLOTHS,
            HandTowelHolder | TowelHolder | ToiletPaperHanger => METALS,
            Laptop => &[[0.25, 0.25, 0.27], [0.70, 0.70, 0.72]],
            Newspaper => &[[0.80, 0.79, 0.74]],
            PaperTowelRoll | ToiletPaper => WHITES,
            Plate => &[[0.95, 0.95, 0.93], [0.75, 0.85, 0.90], [0.90, 0.80, 0.60]],
            Plunger => &[[0.70, 0.15, 0.10], [0.15, 0.15, 0.15]],
            Poster => &[[0.20, 0.45, 0.75], [0.85, 0.55, 0.20], [0.35, 0.65, 0.35], [0.75, 0.25, 0.45]],
            Potato => &[[0.62, 0.48, 0.28], [0.55, 0.40, 0.22]],
            RemoteControl => &[[0.08, 0.08, 0.09], [0.30, 0.30, 0.32]],
            ShowerCurtain => &[[0.85, 0.88, 0.92], [0.55, 0.75, 0.85], [0.90, 0.80, 0.85]],
            ShowerDoor => &[[0.80, 0.88, 0.92]],
            Television => &[[0.05, 0.05, 0.06]],
            TissueBox => &[[0.30, 0.55, 0.80], [0.85, 0.75, 0.40], [0.60, 0.30, 0.55]],
            Tomato => &[[0.85, 0.12, 0.06]],
            Window => &[[0.80, 0.90, 1.00]],
            CounterTop => &[[0.85, 0.84, 0.80], [0.30, 0.30, 0.32], [0.55, 0.40, 0.28]],
            Fridge | Stove => &[[0.88, 0.88, 0.88], [0.70, 0.71, 0.73]],
            Bed => &[[0.85, 0.85, 0.90], [0.60, 0.70, 0.85], [0.85, 0.75, 0.70]],
            Toilet | Bathtub | Sink => WHITES,
            Rug => &[[0.55, 0.20, 0.15], [0.25, 0.30, 0.45], [0.65, 0.60, 0.50]],
            Door => &[[0.55, 0.38, 0.22], [0.90, 0.90, 0.88]],
            Mirror => &[[0.75, 0.80, 0.85]],
        }
    }
}

/// Builds the primitives of one object: `pos` is the centre of its bounding box, `size` its
/// full extents (x width, y height, z depth) before the yaw, `style` picks among variants.
/// Local +z is the object's front (a chair's seat faces +z, a wall item's face points +z).
pub fn build_parts(
    category: Category,
    pos: Point3<f32>,
    yaw: f32,
    size: Vector3<f32>,
    color: [f32; 3],
    style: u32,
    id: u16,
) -> Vec<Part> {
    let mut b = Builder { pos, rot: yaw_rotation(yaw), size, color, id, parts: Vec::new() };
    use Category::*;
    match category {
        Apple | Tomato | Potato | Bread | ButterKnife | Knife | Fork | Spoon | Cup | Plate | PaperTowelRoll
        | ToiletPaper => kitchen_item(&mut b, category, color, style),
        RemoteControl | AlarmClock | TissueBox | Newspaper | Laptop | DeskLamp | FloorLamp | Box => {
            small_item(&mut b, category, color, style)
        }
        Chair | ArmChair | Sofa | DiningTable | CoffeeTable | SideTable | Desk | Bed | Rug => {
            seat_or_table(&mut b, category, color, style)
        }
        CounterTop | Dresser | TvStand | Shelf | Fridge | Stove | Sink | Television => {
            cabinet_or_appliance(&mut b, category, color, style)
        }
        Window | Poster | Mirror | Door | HandTowelHolder | TowelHolder | ToiletPaperHanger | HandTowel | Towel => {
            wall_item(&mut b, category, color, style)
        }
        Plunger | ShowerCurtain | ShowerDoor | Toilet | Bathtub => bathroom_fixture(&mut b, category, color),
    }
    if category == Rug || category == ShowerCurtain {
        // the robot drives over rugs and pushes curtains aside: visible, not solid
        for p in &mut b.parts {
            p.solid = false;
        }
    }
    b.parts
}

/// Food, cutlery and tableware.
fn kitchen_item(b: &mut Builder, category: Category, color: [f32; 3], style: u32) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        Apple | Tomato | Potato => {
            b.ellipsoid([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Matte);
            let stem = if category == Tomato { [0.15, 0.45, 0.12] } else { [0.30, 0.20, 0.10] };
            if category != Potato {
                b.cyl([0.0, hh, 0.0], [0.008, hh * 0.25, 0.008], stem, M::Matte);
            }
        }
        Bread => {
            b.boxp([0.0, -hh * 0.3, 0.0], [hw, hh * 0.7, hd], color, M::Matte);
            b.cyl_x([0.0, hh * 0.3, 0.0], [hh * 0.7, hw * 0.98, hd * 0.9], darker(color, 0.85), M::Matte);
        }
        ButterKnife | Knife => {
            let blade = if category == Knife { 0.62 } else { 0.55 };
            b.boxp([hw * (1.0 - blade), 0.0, 0.0], [hw * blade, hh * 0.4, hd * 0.8], [0.8, 0.8, 0.82], M::Metal);
            let handle = if style % 2 == 0 { [0.12, 0.10, 0.09] } else { color };
            b.boxp([-hw * blade, 0.0, 0.0], [hw * (1.0 - blade), hh, hd * 0.6], handle, M::Matte);
        }
        Fork => {
            b.boxp([-hw * 0.3, 0.0, 0.0], [hw * 0.7, hh * 0.5, hd * 0.25], color, M::Metal);
            for k in [-1.0f32, 0.0, 1.0] {
                b.boxp([hw * 0.7, 0.0, k * hd * 0.3], [hw * 0.3, hh * 0.4, hd * 0.08], color, M::Metal);
            }
        }
        Spoon => {
            b.boxp([-hw * 0.25, 0.0, 0.0], [hw * 0.75, hh * 0.4, hd * 0.22], color, M::Metal);
            b.ellipsoid([hw * 0.72, 0.0, 0.0], [hw * 0.28, hh, hd], color, M::Metal);
        }
        Cup => {
            b.cyl([0.0, 0.0, 0.0], [hw * 0.8, hh, hd * 0.8], color, M::Matte);
            b.boxp([hw * 0.85, 0.0, 0.0], [hw * 0.15, hh * 0.55, hd * 0.12], color, M::Matte);
        }
        Plate => {
            b.cyl([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Matte);
            b.cyl([0.0, hh * 0.2, 0.0], [hw * 0.65, hh * 0.85, hd * 0.65], darker(color, 0.92), M::Matte);
        }
        PaperTowelRoll | ToiletPaper => {
            b.cyl([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Paper);
            b.cyl([0.0, 0.0, 0.0], [hw * 0.35, hh * 1.02, hd * 0.35], [0.55, 0.40, 0.25], M::Paper);
        }
        _ => unreachable!("{category:?} is not one of kitchen_item's"),
    }
}

/// Small things of the living room and bedroom.
fn small_item(b: &mut Builder, category: Category, color: [f32; 3], style: u32) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        RemoteControl => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Matte);
            for k in 0..3 {
                let z = hd * (0.5 - 0.3 * k as f32);
                b.boxp([0.0, hh, z], [hw * 0.5, hh * 0.2, hd * 0.06], [0.7, 0.1, 0.1], M::Matte);
            }
        }
        AlarmClock => {
            if style % 2 == 0 {
                b.cyl_z([0.0, 0.0, 0.0], [hw.min(hh), hw.min(hh), hd], color, M::Matte);
            } else {
                b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Matte);
            }
            b.boxp([0.0, 0.0, hd], [hw * 0.6, hh * 0.6, 0.004], [0.95, 0.95, 0.9], M::Screen);
        }
        TissueBox => {
            b.boxp([0.0, -hh * 0.15, 0.0], [hw, hh * 0.85, hd], color, M::Paper);
            b.ellipsoid([0.0, hh * 0.75, 0.0], [hw * 0.3, hh * 0.3, hd * 0.3], [0.97, 0.97, 0.97], M::Paper);
        }
        Newspaper => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Paper);
            b.boxp([0.0, hh, -hd * 0.4], [hw * 0.8, 0.002, hd * 0.15], [0.15, 0.15, 0.15], M::Paper);
        }
        Laptop => {
            let base_h = hh * 0.12;
            b.boxp([0.0, -hh + base_h, 0.0], [hw, base_h, hd], color, M::Metal);
            let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -0.35);
            let screen_c = [0.0, 0.0, -hd * 0.75];
            b.rotated(Shape::Box, screen_c, tilt, [hw, hh * 0.85, 0.01], color, M::Metal);
            b.rotated(
                Shape::Box,
                [0.0, 0.0, -hd * 0.75 + 0.012],
                tilt,
                [hw * 0.9, hh * 0.75, 0.003],
                [0.15, 0.25, 0.45],
                M::Screen,
            );
        }
        DeskLamp | FloorLamp => {
            let base_h = if category == FloorLamp { 0.03 } else { hh * 0.08 };
            b.cyl([0.0, -hh + base_h, 0.0], [hw * 0.6, base_h, hd * 0.6], [0.2, 0.2, 0.2], M::Metal);
            let shade_h = hh * 0.28;
            b.cyl([0.0, -hh * 0.1, 0.0], [0.012, hh * 0.75, 0.012], [0.25, 0.25, 0.25], M::Metal);
            b.cone([0.0, hh - shade_h, 0.0], [hw, shade_h, hd], color, M::Emissive);
        }
        Box => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Paper);
            b.boxp([0.0, hh, 0.0], [hw * 1.01, 0.004, 0.03], [0.75, 0.65, 0.45], M::Paper);
        }
        _ => unreachable!("{category:?} is not one of small_item's"),
    }
}

/// Chairs, sofas, tables, the bed, the rug.
fn seat_or_table(b: &mut Builder, category: Category, color: [f32; 3], style: u32) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        Chair => {
            let seat = h * 0.47;
            leg4(b, hw * 0.85, hd * 0.85, seat, 0.02, color, M::Wood);
            b.boxp([0.0, -hh + seat, 0.0], [hw, 0.025, hd], color, M::Wood);
            b.boxp([0.0, -hh + seat + (h - seat) / 2.0, -hd * 0.9], [hw, (h - seat) / 2.0, 0.02], color, M::Wood);
            if style % 2 == 1 {
                b.boxp([0.0, -hh + seat + 0.04, 0.0], [hw * 0.9, 0.02, hd * 0.9], [0.55, 0.15, 0.12], M::Fabric);
            }
        }
        ArmChair | Sofa => {
            let seat = h * 0.48;
            let fabric = color;
            b.boxp([0.0, -hh + seat / 2.0, 0.06 * d], [hw, seat / 2.0, hd * 0.94], fabric, M::Fabric);
            b.boxp([0.0, 0.0, -hd * 0.8], [hw, hh, hd * 0.2], fabric, M::Fabric);
            let arm_h = h * 0.65;
            for s in [-1.0f32, 1.0] {
                b.boxp(
                    [s * hw * 0.9, -hh + arm_h / 2.0, 0.0],
                    [hw * 0.1, arm_h / 2.0, hd],
                    darker(fabric, 0.9),
                    M::Fabric,
                );
            }
            let cushions = if category == Sofa { 2 + style % 2 } else { 1 };
            let cw = w * 0.8 / cushions as f32;
            for k in 0..cushions {
                let x = -w * 0.4 + cw * (k as f32 + 0.5);
                b.boxp([x, -hh + seat + 0.05, 0.1 * d], [cw * 0.48, 0.05, hd * 0.65], lighter(fabric, 1.1), M::Fabric);
            }
        }
        DiningTable | CoffeeTable | SideTable | Desk => {
            let top = 0.025f32.max(h * 0.04);
            b.boxp([0.0, hh - top, 0.0], [hw, top, hd], color, M::Wood);
            if category == SideTable && style % 2 == 1 {
                // a small cabinet
                b.boxp([0.0, -top, 0.0], [hw * 0.95, hh - top, hd * 0.95], darker(color, 0.9), M::Wood);
                b.boxp([0.0, 0.0, hd * 0.96], [hw * 0.1, 0.015, 0.01], [0.7, 0.7, 0.7], M::Metal);
            } else if category == DiningTable && style % 3 == 2 {
                // pedestal
                b.cyl([0.0, -top, 0.0], [0.08, hh - top, 0.08], darker(color, 0.8), M::Wood);
                b.cyl([0.0, -hh + 0.02, 0.0], [hw * 0.35, 0.02, hd * 0.35], darker(color, 0.8), M::Wood);
            } else {
                leg4(b, hw * 0.9, hd * 0.88, h - 2.0 * top, 0.03, darker(color, 0.85), M::Wood);
            }
            if category == Desk {
                b.boxp([hw * 0.55, -top, 0.0], [hw * 0.4, hh - top, hd * 0.95], darker(color, 0.9), M::Wood);
            }
        }
        Bed => {
            let frame_h = h * 0.45;
            b.boxp([0.0, -hh + frame_h / 2.0, 0.0], [hw, frame_h / 2.0, hd], [0.45, 0.3, 0.18], M::Wood);
            b.boxp(
                [0.0, -hh + frame_h + (h - frame_h) / 2.0, 0.05],
                [hw * 0.97, (h - frame_h) / 2.0, hd * 0.95],
                color,
                M::Fabric,
            );
            b.boxp([0.0, 0.15, -hd * 0.97], [hw, hh + 0.15, 0.04], [0.45, 0.3, 0.18], M::Wood);
            for s in [-1.0f32, 1.0] {
                b.boxp([s * hw * 0.45, hh + 0.04, -hd * 0.75], [hw * 0.38, 0.06, 0.16], [0.95, 0.95, 0.95], M::Fabric);
            }
        }
        Rug => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Fabric);
            b.boxp([0.0, 0.001, 0.0], [hw * 0.8, hh, hd * 0.75], lighter(color, 1.3), M::Fabric);
        }
        _ => unreachable!("{category:?} is not one of seat_or_table's"),
    }
}

/// Cabinets, shelves and appliances.
fn cabinet_or_appliance(b: &mut Builder, category: Category, color: [f32; 3], style: u32) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        CounterTop | Dresser | TvStand => {
            let top = 0.03;
            let cab = if category == CounterTop { darker(color, 0.75) } else { color };
            b.boxp([0.0, -top, -0.0], [hw, hh - top, hd * 0.96], cab, M::Wood);
            b.boxp([0.0, hh - top, 0.0], [hw, top, hd], color, if category == CounterTop { M::Tile } else { M::Wood });
            let doors = ((w / 0.45).round() as i32).max(1);
            for k in 0..doors {
                let x = -hw + w / doors as f32 * (k as f32 + 0.5);
                b.boxp([x, 0.0, hd * 0.97], [0.012, 0.05, 0.01], [0.7, 0.7, 0.7], M::Metal);
            }
        }
        Shelf => {
            let t = 0.02;
            for s in [-1.0f32, 1.0] {
                b.boxp([s * (hw - t), 0.0, 0.0], [t, hh, hd], color, M::Wood);
            }
            let boards = 4;
            for k in 0..boards {
                let y = -hh + t + (h - 2.0 * t) * k as f32 / (boards - 1) as f32;
                b.boxp([0.0, y, 0.0], [hw, t, hd], color, M::Wood);
            }
            b.boxp([0.0, 0.0, -hd + 0.005], [hw, hh, 0.005], darker(color, 0.7), M::Wood);
        }
        Fridge => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Metal);
            b.boxp([0.0, hh * 0.35, hd], [hw * 0.98, 0.004, 0.004], darker(color, 0.6), M::Metal);
            b.boxp([hw * 0.8, hh * 0.55, hd + 0.02], [0.015, hh * 0.15, 0.02], [0.3, 0.3, 0.3], M::Metal);
            b.boxp([hw * 0.8, -hh * 0.1, hd + 0.02], [0.015, hh * 0.25, 0.02], [0.3, 0.3, 0.3], M::Metal);
        }
        Stove => {
            b.boxp([0.0, -0.01, 0.0], [hw, hh - 0.01, hd], color, M::Metal);
            b.boxp([0.0, hh - 0.01, 0.0], [hw, 0.01, hd], [0.08, 0.08, 0.08], M::Metal);
            for (x, z) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                b.cyl([x * hw, hh, z * hd], [0.09, 0.006, 0.09], [0.25, 0.25, 0.25], M::Metal);
            }
            b.boxp([0.0, hh * 0.3, hd], [hw * 0.8, hh * 0.35, 0.005], [0.1, 0.1, 0.1], M::Glass);
        }
        Sink => {
            b.boxp([0.0, -0.05, 0.0], [hw, hh - 0.05, hd], [0.55, 0.45, 0.35], M::Wood);
            b.boxp([0.0, hh - 0.05, 0.0], [hw, 0.05, hd], color, M::Tile);
            b.cyl([0.0, hh - 0.02, 0.0], [hw * 0.4, 0.035, hd * 0.5], darker(color, 0.85), M::Metal);
            b.cyl([0.0, hh + 0.1, -hd * 0.75], [0.015, 0.1, 0.015], [0.7, 0.7, 0.72], M::Metal);
        }
        Television => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd * 0.5], color, M::Matte);
            b.boxp([0.0, 0.0, hd * 0.5], [hw * 0.95, hh * 0.92, 0.004], screen_color(style), M::Screen);
            b.boxp([0.0, -hh, -hd * 0.1], [hw * 0.25, 0.015, hd], [0.1, 0.1, 0.1], M::Metal);
        }
        _ => unreachable!("{category:?} is not one of cabinet_or_appliance's"),
    }
}

/// What hangs on a wall, and the door.
fn wall_item(b: &mut Builder, category: Category, color: [f32; 3], style: u32) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        Window => {
            b.boxp([0.0, 0.0, 0.0], [hw * 0.95, hh * 0.95, 0.01], sky_color(style), M::Emissive);
            frame(b, hw, hh, 0.05, hd, [0.92, 0.92, 0.9]);
            b.boxp([0.0, 0.0, hd * 0.5], [0.02, hh, hd * 0.5], [0.92, 0.92, 0.9], M::Matte);
        }
        Poster => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], [0.95, 0.95, 0.93], M::Paper);
            // a simple composition so posters differ
            let c2 = lighter(color, 1.4);
            b.boxp([0.0, hh * 0.2, hd], [hw * 0.8, hh * 0.55, 0.002], color, M::Paper);
            b.ellipsoid(
                [hw * 0.25 * ((style % 3) as f32 - 1.0), hh * 0.3, hd * 1.5],
                [hw * 0.25, hw * 0.25, 0.002],
                c2,
                M::Paper,
            );
            b.boxp([0.0, -hh * 0.7, hd], [hw * 0.6, hh * 0.06, 0.002], [0.1, 0.1, 0.1], M::Paper);
        }
        Mirror => {
            frame(b, hw, hh, 0.03, hd, [0.6, 0.55, 0.4]);
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd * 0.5], color, M::Glass);
        }
        Door => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Wood);
            b.cyl_z([hw * 0.8, -0.05, hd], [0.03, 0.03, 0.03], [0.75, 0.7, 0.4], M::Metal);
        }
        HandTowelHolder | TowelHolder | ToiletPaperHanger => {
            // a bar held off the wall by two posts (or one arm for the paper hanger)
            let posts: &[f32] = if category == ToiletPaperHanger { &[-1.0] } else { &[-1.0, 1.0] };
            for &s in posts {
                b.boxp([s * hw * 0.9, 0.0, -hd * 0.5], [hw * 0.08, hh, hd * 0.5], color, M::Metal);
            }
            if category == HandTowelHolder && style % 2 == 1 {
                b.cyl_z([0.0, -hh * 2.0, hd * 0.3], [hw * 0.8, hw * 0.8, 0.006], color, M::Metal);
            } else {
                b.cyl_x([0.0, 0.0, hd * 0.3], [hh * 0.35, hw, hh * 0.35], color, M::Metal);
            }
        }
        HandTowel | Towel => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Fabric);
            b.boxp([0.0, -hh * 0.8, hd * 1.02], [hw, hh * 0.06, 0.002], darker(color, 0.7), M::Fabric);
        }
        _ => unreachable!("{category:?} is not one of wall_item's"),
    }
}

/// The bathroom's fixtures.
fn bathroom_fixture(b: &mut Builder, category: Category, color: [f32; 3]) {
    let (w, h, d) = (b.size.x, b.size.y, b.size.z);
    let (hw, hh, hd) = (w / 2.0, h / 2.0, d / 2.0);
    use Category::*;
    use Material as M;
    match category {
        Plunger => {
            b.cyl([0.0, hh * 0.15, 0.0], [0.012, hh * 0.85, 0.012], [0.55, 0.38, 0.2], M::Wood);
            b.cone([0.0, -hh * 0.82, 0.0], [hw, hh * 0.18, hd], color, M::Matte);
        }
        ShowerCurtain => {
            b.cyl_x([0.0, hh, 0.0], [0.012, hw, 0.012], [0.7, 0.7, 0.72], M::Metal);
            let folds = 6;
            let fw = w / folds as f32;
            for k in 0..folds {
                let x = -hw + fw * (k as f32 + 0.5);
                let z = if k % 2 == 0 { hd * 0.5 } else { -hd * 0.5 };
                b.boxp([x, -0.05, z], [fw * 0.55, hh - 0.05, 0.01], color, M::Fabric);
            }
        }
        ShowerDoor => {
            frame(b, hw, hh, 0.03, hd, [0.7, 0.7, 0.72]);
            b.boxp([0.0, 0.0, 0.0], [hw, hh, 0.008], color, M::Glass);
            b.boxp([hw * 0.8, 0.0, hd], [0.01, 0.12, 0.015], [0.7, 0.7, 0.72], M::Metal);
        }
        Toilet => {
            b.boxp([0.0, 0.12, -hd * 0.75], [hw * 0.9, hh * 0.55, hd * 0.25], color, M::Matte);
            b.cyl([0.0, -hh * 0.45, hd * 0.1], [hw * 0.5, hh * 0.55, hd * 0.35], color, M::Matte);
            b.cyl([0.0, -hh * 0.45 + hh * 0.55, hd * 0.15], [hw * 0.95, 0.03, hd * 0.6], color, M::Matte);
        }
        Bathtub => {
            b.boxp([0.0, 0.0, 0.0], [hw, hh, hd], color, M::Matte);
            b.boxp([0.0, hh * 0.2, 0.0], [hw * 0.9, hh * 0.82, hd * 0.82], [0.7, 0.8, 0.85], M::Glass);
        }
        _ => unreachable!("{category:?} is not one of bathroom_fixture's"),
    }
}

fn leg4(b: &mut Builder, hx: f32, hz: f32, height: f32, r: f32, color: [f32; 3], m: Material) {
    let y = -b.size.y / 2.0 + height / 2.0;
    for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        b.cyl([sx * (hx - r), y, sz * (hz - r)], [r, height / 2.0, r], color, m);
    }
}

fn frame(b: &mut Builder, hw: f32, hh: f32, t: f32, d: f32, color: [f32; 3]) {
    b.boxp([0.0, hh - t / 2.0, 0.0], [hw, t / 2.0, d / 2.0], color, Material::Matte);
    b.boxp([0.0, -hh + t / 2.0, 0.0], [hw, t / 2.0, d / 2.0], color, Material::Matte);
    b.boxp([-hw + t / 2.0, 0.0, 0.0], [t / 2.0, hh, d / 2.0], color, Material::Matte);
    b.boxp([hw - t / 2.0, 0.0, 0.0], [t / 2.0, hh, d / 2.0], color, Material::Matte);
}

fn darker(c: [f32; 3], f: f32) -> [f32; 3] {
    [c[0] * f, c[1] * f, c[2] * f]
}

fn lighter(c: [f32; 3], f: f32) -> [f32; 3] {
    [(c[0] * f).min(1.0), (c[1] * f).min(1.0), (c[2] * f).min(1.0)]
}

fn screen_color(style: u32) -> [f32; 3] {
    [[0.05, 0.06, 0.08], [0.10, 0.20, 0.35], [0.20, 0.30, 0.20]][(style % 3) as usize]
}

fn sky_color(style: u32) -> [f32; 3] {
    [[0.70, 0.85, 1.00], [0.85, 0.90, 0.95], [0.95, 0.85, 0.70]][(style % 3) as usize]
}

/// Places parts in an object's local frame.
struct Builder {
    pos: Point3<f32>,
    rot: UnitQuaternion<f32>,
    size: Vector3<f32>,
    color: [f32; 3],
    id: u16,
    parts: Vec<Part>,
}

impl Builder {
    fn rotated(
        &mut self,
        shape: Shape,
        c: [f32; 3],
        r: UnitQuaternion<f32>,
        he: [f32; 3],
        color: [f32; 3],
        m: Material,
    ) {
        let center = self.pos + self.rot * Vector3::from(c);
        let _ = self.color;
        self.parts.push(Part {
            shape,
            center,
            rotation: self.rot * r,
            half_extents: Vector3::from(he).map(|v| v.max(1e-4)),
            color,
            material: m,
            id: self.id,
            solid: true,
        });
    }
    fn boxp(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        self.rotated(Shape::Box, c, UnitQuaternion::identity(), he, color, m);
    }
    fn cyl(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        self.rotated(Shape::Cylinder, c, UnitQuaternion::identity(), he, color, m);
    }
    /// A cylinder lying along local x: `he` = (radius, half length, radius).
    fn cyl_x(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_2);
        self.rotated(Shape::Cylinder, c, r, [he[0], he[1], he[2]], color, m);
    }
    /// A cylinder facing along local z (a disc on a wall): `he` = (radius x, radius y, half depth).
    fn cyl_z(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        let r = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::FRAC_PI_2);
        self.rotated(Shape::Cylinder, c, r, [he[0], he[2], he[1]], color, m);
    }
    fn ellipsoid(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        self.rotated(Shape::Sphere, c, UnitQuaternion::identity(), he, color, m);
    }
    fn cone(&mut self, c: [f32; 3], he: [f32; 3], color: [f32; 3], m: Material) {
        self.rotated(Shape::Cone, c, UnitQuaternion::identity(), he, color, m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_count_is_the_wire_constant() {
        assert_eq!(Category::targets().count(), shm_schema::TARGET_CATEGORIES);
    }

    #[test]
    fn t33_has_37_distinct_targets_and_every_one_is_listed() {
        let mut all: Vec<Category> = SceneType::ALL.iter().flat_map(|t| targets_of(*t).iter().copied()).collect();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), 37);
        assert_eq!(Category::targets().count(), 37);
        for c in Category::targets() {
            assert!(all.contains(&c), "{c:?} is a target but in no scene type");
        }
        assert_eq!(targets_of(SceneType::Kitchen).len(), 16);
        assert_eq!(targets_of(SceneType::LivingRoom).len(), 15);
        assert_eq!(targets_of(SceneType::Bedroom).len(), 12);
        assert_eq!(targets_of(SceneType::Bathroom).len(), 13);
    }

    #[test]
    fn break_reads_as_bread() {
        assert_eq!(Category::from_name("Break"), Some(Category::Bread));
        assert_eq!(Category::from_name("chair"), Some(Category::Chair));
    }

    #[test]
    fn every_category_builds_parts_inside_its_box() {
        for &c in Category::ALL {
            let (lo, hi) = c.size_range();
            let size = Vector3::new((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, (lo[2] + hi[2]) / 2.0);
            for style in 0..3 {
                let parts = build_parts(c, Point3::new(0.0, 1.0, 0.0), 30.0, size, c.palette()[0], style, 7);
                assert!(!parts.is_empty(), "{c:?}");
                let r = size.norm() * 0.5 + 0.08;
                for p in &parts {
                    assert!(p.half_extents.iter().all(|v| *v > 0.0));
                    assert!((p.center - Point3::new(0.0, 1.0, 0.0)).norm() <= r, "{c:?} part outside its bounds");
                    assert_eq!(p.id, 7);
                }
            }
        }
    }
}
