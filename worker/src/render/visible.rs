//! What the worker still needs on the host of frames that stay on the device: how many pixels of
//! each view show its target (the task's visibility, `count_id` of the read-back path). One
//! compute pass over the chunk's depth+id layers counts them; four bytes a view come back.

use super::error::RenderError;
use super::readback::read_mapped;
use super::targets::Targets;

const SHADER: &str = r"
@group(0) @binding(0) var info: texture_2d_array<u32>;
@group(0) @binding(1) var<storage, read> target_ids: array<u32>;
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;

@compute @workgroup_size(8, 8, 1)
fn count(@builtin(global_invocation_id) g: vec3<u32>) {
    let size = textureDimensions(info);
    if (g.x >= size.x || g.y >= size.y) {
        return;
    }
    let v = textureLoad(info, vec2<u32>(g.xy), g.z, 0).r;
    if ((v & 0xFFFFu) == target_ids[g.z]) {
        atomicAdd(&counts[g.z], 1u);
    }
}
";

/// The counting pass of one lane, for up to `capacity` views a chunk.
pub(super) struct VisibleCount {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    target_ids: wgpu::Buffer,
    counts: wgpu::Buffer,
    read: wgpu::Buffer,
    width: u32,
    height: u32,
}

impl VisibleCount {
    pub(super) fn new(device: &wgpu::Device, targets: &Targets, capacity: usize) -> VisibleCount {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("visible pixels"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("visible pixels"),
            layout: None,
            module: &module,
            entry_point: Some("count"),
            compilation_options: Default::default(),
            cache: None,
        });
        let bytes = (capacity * 4) as u64;
        let buffer = |label, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let target_ids = buffer("target ids", U::STORAGE | U::COPY_DST);
        let counts = buffer("visible counts", U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let read = buffer("visible counts read", U::MAP_READ | U::COPY_DST);
        let info = targets.info.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("visible pixels"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&info) },
                wgpu::BindGroupEntry { binding: 1, resource: target_ids.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: counts.as_entire_binding() },
            ],
        });
        let size = targets.info.size();
        VisibleCount { pipeline, bind_group, target_ids, counts, read, width: size.width, height: size.height }
    }

    /// Records the count of `target_ids[i]`'s pixels in layer `i`, for the first
    /// `target_ids.len()` layers, and the copy of the counts to the host.
    pub(super) fn record(&self, queue: &wgpu::Queue, encoder: &mut wgpu::CommandEncoder, target_ids: &[u16]) {
        let ids: Vec<u32> = target_ids.iter().map(|&i| i as u32).collect();
        queue.write_buffer(&self.target_ids, 0, bytemuck::cast_slice(&ids));
        encoder.clear_buffer(&self.counts, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups(self.width.div_ceil(8), self.height.div_ceil(8), ids.len() as u32);
        }
        encoder.copy_buffer_to_buffer(&self.counts, 0, &self.read, 0, (ids.len() * 4) as u64);
    }

    /// Waits for the submission and returns the first `views` counts.
    pub(super) fn read(&self, device: &wgpu::Device, views: usize) -> Result<Vec<u32>, RenderError> {
        let slice = self.read.slice(..(views * 4) as u64);
        read_mapped(device, &slice, |data| bytemuck::cast_slice::<u8, u32>(data).to_vec())
    }
}
