//! Parts as the shader reads them: instances of unit meshes, grouped by mesh with their
//! bounding spheres, and the growable GPU buffer that carries a chunk's visible ones.

use bytemuck::Zeroable;

use super::mesh::{MESH_COUNT, mesh_index, round_radius};
use crate::geometry::{ID_STRUCTURE, Part};

/// One part as the vertex shader reads it, as instance-rate vertex attributes 2–6: the columns
/// of rotation × half extents with the centre in their w, the colour, and `id | material << 16`.
/// Matches `struct Instance` in scene.wgsl (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct Instance {
    col0: [f32; 4],
    col1: [f32; 4],
    col2: [f32; 4],
    color: [f32; 3],
    tag: u32,
}

impl Instance {
    pub(super) fn from_part(p: &Part) -> Instance {
        let r = p.rotation.to_rotation_matrix();
        let m = r.matrix();
        let h = p.half_extents;
        let c = p.center;
        let col = |j: usize, t: f32| [m[(0, j)] * h[j], m[(1, j)] * h[j], m[(2, j)] * h[j], t];
        Instance {
            col0: col(0, c.x),
            col1: col(1, c.y),
            col2: col(2, c.z),
            color: p.color,
            tag: p.id as u32 | (p.material.index() << 16),
        }
    }
}

/// A bounding sphere (centre, radius) of a part: every unit mesh lies inside [−1, 1]³, so the
/// length of the half extents bounds it whatever the rotation.
fn bounding_sphere(p: &Part) -> [f32; 4] {
    [p.center.x, p.center.y, p.center.z, p.half_extents.norm()]
}

/// Consecutive instances that use one unit mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Group {
    pub mesh: usize,
    pub first: u32,
    pub count: u32,
}

/// Parts as instances sorted into groups by unit mesh, with their bounding spheres and the
/// radii of round ones (for the level of detail).
#[derive(Default)]
pub(super) struct Grouped {
    pub instances: Vec<Instance>,
    pub bounds: Vec<[f32; 4]>,
    pub round: Vec<f32>,
    pub groups: Vec<Group>,
}

impl Grouped {
    pub(super) fn clear(&mut self) {
        self.instances.clear();
        self.bounds.clear();
        self.round.clear();
        self.groups.clear();
    }

    /// Appends `parts` grouped by unit mesh (stable within a group). With `structure_last`,
    /// floor, walls and ceiling go after everything else: they lie behind all furniture, so
    /// drawing them last lets the depth test skip their hidden pixels.
    pub(super) fn push(&mut self, parts: &[Part], structure_last: bool) {
        let bucket = |p: &Part| mesh_index(p) + if structure_last && p.id == ID_STRUCTURE { MESH_COUNT } else { 0 };
        let mut counts = [0u32; 2 * MESH_COUNT];
        for p in parts {
            counts[bucket(p)] += 1;
        }
        let mut next = [0u32; 2 * MESH_COUNT];
        let mut acc = self.instances.len() as u32;
        for b in 0..2 * MESH_COUNT {
            next[b] = acc;
            if counts[b] > 0 {
                self.groups.push(Group { mesh: b % MESH_COUNT, first: acc, count: counts[b] });
            }
            acc += counts[b];
        }
        self.instances.resize(acc as usize, Instance::zeroed());
        self.bounds.resize(acc as usize, [0.0; 4]);
        self.round.resize(acc as usize, 0.0);
        for p in parts {
            let b = bucket(p);
            self.instances[next[b] as usize] = Instance::from_part(p);
            self.bounds[next[b] as usize] = bounding_sphere(p);
            self.round[next[b] as usize] = round_radius(p);
            next[b] += 1;
        }
    }
}

/// A buffer that grows (to the next power of two) when a chunk needs more room.
pub(super) struct Growable {
    pub buffer: Option<wgpu::Buffer>,
    capacity: u64,
    usage: wgpu::BufferUsages,
    label: &'static str,
}

impl Growable {
    pub(super) fn new(label: &'static str, usage: wgpu::BufferUsages) -> Growable {
        Growable { buffer: None, capacity: 0, usage: usage | wgpu::BufferUsages::COPY_DST, label }
    }

    /// Writes `data` at offset 0; true if the buffer was replaced.
    pub(super) fn write(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, data: &[u8]) -> bool {
        let need = data.len() as u64;
        let mut grown = false;
        if need > self.capacity || self.buffer.is_none() {
            self.capacity = need.next_power_of_two().max(4096);
            self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size: self.capacity,
                usage: self.usage,
                mapped_at_creation: false,
            }));
            grown = true;
        }
        if need > 0 {
            queue.write_buffer(self.buffer.as_ref().expect("allocated above"), 0, data);
        }
        grown
    }
}
