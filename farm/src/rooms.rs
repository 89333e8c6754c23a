//! The 120 rooms by name and fold: four scene types of 30 rooms (FloorPlan1–30, 201–230, 301–330,
//! 401–430), split 20 train / 5 val / 5 test per type. What is *in* a room is the simulator's
//! business (`worker::scene`); every role needs the names.

use serde::{Deserialize, Serialize};

/// The four room types of AI2-THOR / GesTHOR.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum SceneType {
    Kitchen,
    LivingRoom,
    Bedroom,
    Bathroom,
}

impl SceneType {
    pub const ALL: [SceneType; 4] =
        [SceneType::Kitchen, SceneType::LivingRoom, SceneType::Bedroom, SceneType::Bathroom];

    /// FloorPlan numbers are `base + 1 ..= base + 30` (1–30, 201–230, 301–330, 401–430).
    pub const fn floorplan_base(self) -> u32 {
        match self {
            SceneType::Kitchen => 0,
            SceneType::LivingRoom => 200,
            SceneType::Bedroom => 300,
            SceneType::Bathroom => 400,
        }
    }

    /// Name as the original metadata writes it (`sceneType`).
    pub const fn name(self) -> &'static str {
        match self {
            SceneType::Kitchen => "Kitchen",
            SceneType::LivingRoom => "LivingRoom",
            SceneType::Bedroom => "Bedroom",
            SceneType::Bathroom => "Bathroom",
        }
    }

    pub fn from_name(s: &str) -> Option<SceneType> {
        let k = s.replace([' ', '_'], "").to_ascii_lowercase();
        SceneType::ALL.into_iter().find(|t| t.name().to_ascii_lowercase() == k)
    }
}

/// Train/val/test fold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    pub const fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    pub fn from_name(s: &str) -> Option<Split> {
        Split::ALL.into_iter().find(|x| x.name() == s)
    }

    /// Room indices (1..=30 within a type) of this fold: 20 train, 5 val, 5 test per type.
    pub fn room_indices(self) -> std::ops::RangeInclusive<u32> {
        match self {
            Split::Train => 1..=20,
            Split::Val => 21..=25,
            Split::Test => 26..=30,
        }
    }
}

/// One of the 120 rooms: a scene type and an index 1..=30 within it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct SceneId {
    pub scene_type: SceneType,
    pub index: u32,
}

impl SceneId {
    pub fn new(scene_type: SceneType, index: u32) -> Self {
        assert!((1..=30).contains(&index), "room index {index} outside 1..=30");
        SceneId { scene_type, index }
    }

    /// All 120 rooms in a fixed order.
    pub fn all() -> impl Iterator<Item = SceneId> {
        SceneType::ALL.into_iter().flat_map(|t| (1..=30).map(move |i| SceneId::new(t, i)))
    }

    pub fn of_split(split: Split) -> impl Iterator<Item = SceneId> {
        SceneType::ALL.into_iter().flat_map(move |t| split.room_indices().map(move |i| SceneId::new(t, i)))
    }

    pub fn floorplan(self) -> u32 {
        self.scene_type.floorplan_base() + self.index
    }

    /// "FloorPlan201" and so on.
    pub fn name(self) -> String {
        format!("FloorPlan{}", self.floorplan())
    }

    pub fn split(self) -> Split {
        Split::ALL.into_iter().find(|s| s.room_indices().contains(&self.index)).expect("index 1..=30")
    }

    /// Parses "FloorPlan201" (also "201").
    pub fn parse(s: &str) -> Option<SceneId> {
        let n: u32 = s.strip_prefix("FloorPlan").unwrap_or(s).parse().ok()?;
        let (t, i) = match n {
            1..=30 => (SceneType::Kitchen, n),
            201..=230 => (SceneType::LivingRoom, n - 200),
            301..=330 => (SceneType::Bedroom, n - 300),
            401..=430 => (SceneType::Bathroom, n - 400),
            _ => return None,
        };
        Some(SceneId::new(t, i))
    }
}
