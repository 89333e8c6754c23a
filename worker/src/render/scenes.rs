//! Uploaded scenes, kept in slots and named by generation-checked handles. A scene stays on
//! the CPU as instances grouped by mesh: each chunk copies the ones its views can see into
//! its instance buffer.

use super::instances::Grouped;

/// A scene uploaded with `Renderer::upload_scene`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SceneHandle {
    slot: u32,
    generation: u32,
}

struct SceneSlot {
    generation: u32,
    scene: Option<Grouped>,
}

/// The uploaded scenes. A released slot is reused by the next upload under a new generation,
/// so an old handle never reaches the new scene.
#[derive(Default)]
pub(super) struct Scenes {
    slots: Vec<SceneSlot>,
}

impl Scenes {
    pub(super) fn insert(&mut self, scene: Grouped) -> SceneHandle {
        let slot = match self.slots.iter().position(|s| s.scene.is_none()) {
            Some(i) => i,
            None => {
                self.slots.push(SceneSlot { generation: 0, scene: None });
                self.slots.len() - 1
            }
        };
        let s = &mut self.slots[slot];
        s.generation = s.generation.wrapping_add(1);
        s.scene = Some(scene);
        SceneHandle { slot: slot as u32, generation: s.generation }
    }

    /// Frees a scene; the handle becomes invalid.
    pub(super) fn release(&mut self, h: SceneHandle) {
        if let Some(s) = self.slots.get_mut(h.slot as usize)
            && s.generation == h.generation
        {
            s.scene = None;
        }
    }

    pub(super) fn get(&self, h: SceneHandle) -> Option<&Grouped> {
        self.slots.get(h.slot as usize).filter(|s| s.generation == h.generation).and_then(|s| s.scene.as_ref())
    }
}
