//! One device and what it renders with: pipeline, unit meshes, per-view uniforms, the
//! chunk's instance buffer, targets and readback. A renderer has one lane per device and
//! splits each chunk of views between them; lanes run in parallel (on lavapipe each device
//! executes its commands on its own thread).

use wgpu::util::DeviceExt;

use super::adapter::{self, Gpu};
use super::config::RenderConfig;
use super::culling::Draw;
use super::error::RenderError;
use super::export::ExportedFrames;
use super::instances::{Growable, Instance};
use super::mesh::{MESH_COUNT, MeshRange, Vertex};
use super::pipeline::Pipeline;
use super::projection::ViewUniform;
use super::readback::Readback;
use super::targets::{INFO_CLEAR, Targets};
use super::view::ViewOut;
use super::visible::VisibleCount;

/// What a lane draws for a share of a chunk: per view its uniforms and its run of draws
/// into the instance list.
pub(super) struct LaneWork<'a> {
    pub uniforms: &'a [ViewUniform],
    pub instances: &'a [Instance],
    pub draws: &'a [Draw],
    /// Per view, its draws' range in `draws`.
    pub view_draws: &'a [(usize, usize)],
}

pub(super) struct Lane {
    /// Views per submit: the number of target layers.
    pub capacity: usize,
    device: wgpu::Device,
    queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pipeline: wgpu::RenderPipeline,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    ranges: [MeshRange; MESH_COUNT],
    view_buffer: wgpu::Buffer,
    view_stride: u64,
    view_bind_group: wgpu::BindGroup,
    targets: Targets,
    readback: Readback,
    instances: Growable,
    scratch_uniforms: Vec<u8>,
    /// Frames kept on the device ([`Lane::export`]) and the count of their targets' pixels.
    exported: Option<(ExportedFrames, VisibleCount)>,
}

impl Lane {
    /// Opens a device (its own wgpu instance, so that on lavapipe it gets its own rasteriser)
    /// with targets for up to `views` views per submit, fewer if the device limits layers.
    pub(super) fn open(
        cfg: &RenderConfig,
        views: usize,
        meshes: &(Vec<Vertex>, Vec<u16>, [MeshRange; MESH_COUNT]),
    ) -> Result<Lane, RenderError> {
        let Gpu { device, queue, info, limits } = adapter::open(cfg)?;
        let capacity = views.min(limits.max_texture_array_layers as usize).max(1);
        let view_stride = (std::mem::size_of::<ViewUniform>() as u64)
            .next_multiple_of(limits.min_uniform_buffer_offset_alignment as u64);
        let Pipeline { pipeline, view_layout } = Pipeline::new(&device);
        let (verts, idx, ranges) = meshes;
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("unit meshes"),
            contents: bytemuck::cast_slice(verts),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("unit mesh indices"),
            contents: bytemuck::cast_slice(idx),
            usage: wgpu::BufferUsages::INDEX,
        });
        let view_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("views"),
            size: view_stride * capacity as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let view_bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("views"),
            layout: &view_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &view_buffer,
                    offset: 0,
                    size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
                }),
            }],
        });
        let targets = Targets::new(&device, cfg, capacity);
        let readback = Readback::new(&device, cfg, capacity);
        Ok(Lane {
            capacity,
            device,
            queue,
            info,
            pipeline,
            vertices,
            indices,
            ranges: *ranges,
            view_buffer,
            view_stride,
            view_bind_group,
            targets,
            readback,
            instances: Growable::new("instances", wgpu::BufferUsages::VERTEX),
            scratch_uniforms: Vec::new(),
            exported: None,
        })
    }

    /// Writes the views' uniforms and instances (one buffer write each), records one render
    /// pass per view into its layer and the copy of every layer, and submits, without
    /// waiting: `read` waits.
    pub(super) fn submit(&mut self, work: &LaneWork<'_>) {
        let mut encoder = self.record(work);
        self.readback.copy(&mut encoder, &self.targets, work.uniforms.len());
        self.queue.submit([encoder.finish()]);
    }

    /// Allocates the exported frame memory for `layout` (once; later calls return it).
    pub(super) fn export(&mut self, layout: shm_schema::DeviceFrameLayout) -> Result<&ExportedFrames, RenderError> {
        if self.exported.as_ref().is_some_and(|(e, _)| e.layout() != layout) {
            return Err(RenderError::Export("the frames were already exported with another layout".into()));
        }
        if self.exported.is_none() {
            let frames = ExportedFrames::new(&self.device, layout)?;
            let count = VisibleCount::new(&self.device, &self.targets, self.capacity);
            self.exported = Some((frames, count));
        }
        Ok(&self.exported.as_ref().expect("just made").0)
    }

    /// As [`Lane::submit`], the views going to their `slots` of the exported frames instead of
    /// the readback, with the count of each view's `target_ids[i]` pixels; `read_visible` waits.
    pub(super) fn submit_exported(
        &mut self,
        work: &LaneWork<'_>,
        slots: &[u32],
        target_ids: &[u16],
    ) -> Result<(), RenderError> {
        if self.exported.is_none() {
            return Err(RenderError::Export("render_exported before export_frames".into()));
        }
        let mut encoder = self.record(work);
        let (frames, count) = self.exported.as_ref().expect("checked");
        // one copy per run of consecutive slots (all of them, when every env is running)
        let mut layer = 0;
        while layer < slots.len() {
            let run = 1 + slots[layer..].windows(2).take_while(|w| w[1] == w[0] + 1).count();
            frames.copy_layers(&mut encoder, &self.targets, layer as u32, slots[layer], run as u32);
            layer += run;
        }
        count.record(&self.queue, &mut encoder, target_ids);
        self.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// The exported memory's bytes, through a mappable copy.
    pub(super) fn read_exported(&self) -> Result<Vec<u8>, RenderError> {
        let (frames, _) = self.exported.as_ref().ok_or_else(|| RenderError::Export("nothing was exported".into()))?;
        let size = frames.layout().size;
        let read = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("exported frames read"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(&frames.buffer, 0, &read, 0, size);
        self.queue.submit([encoder.finish()]);
        super::readback::read_mapped(&self.device, &read.slice(..), |data| data.to_vec())
    }

    /// Slots of the exported frames, once exported.
    pub(super) fn exported_slots(&self) -> Option<usize> {
        self.exported.as_ref().map(|(e, _)| e.layout().slots as usize)
    }

    /// Waits for the last [`Lane::submit_exported`] and returns its views' target pixel counts.
    pub(super) fn read_visible(&self, views: usize) -> Result<Vec<u32>, RenderError> {
        let (_, count) = self.exported.as_ref().ok_or_else(|| RenderError::Export("nothing was exported".into()))?;
        count.read(&self.device, views)
    }

    /// Writes the views' uniforms and instances and records one render pass per view.
    fn record(&mut self, work: &LaneWork<'_>) -> wgpu::CommandEncoder {
        let k = work.uniforms.len();
        debug_assert!(k <= self.capacity && work.view_draws.len() == k);
        let stride = self.view_stride as usize;
        self.scratch_uniforms.clear();
        self.scratch_uniforms.resize(stride * k, 0);
        for (i, u) in work.uniforms.iter().enumerate() {
            self.scratch_uniforms[i * stride..i * stride + std::mem::size_of::<ViewUniform>()]
                .copy_from_slice(bytemuck::bytes_of(u));
        }
        self.queue.write_buffer(&self.view_buffer, 0, &self.scratch_uniforms);
        self.instances.write(&self.device, &self.queue, bytemuck::cast_slice(work.instances));

        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("views") });
        for (i, &(d0, d1)) in work.view_draws.iter().enumerate() {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: None,
                color_attachments: &[
                    Some(wgpu::RenderPassColorAttachment {
                        view: &self.targets.color_layers[i],
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                            store: wgpu::StoreOp::Store,
                        },
                    }),
                    Some(wgpu::RenderPassColorAttachment {
                        view: &self.targets.info_layers[i],
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color { r: INFO_CLEAR as f64, g: 0.0, b: 0.0, a: 0.0 }),
                            store: wgpu::StoreOp::Store,
                        },
                    }),
                ],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.targets.depth_layers[i],
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.view_bind_group, &[(i as u64 * self.view_stride) as u32]);
            pass.set_vertex_buffer(0, self.vertices.slice(..));
            pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint16);
            if d1 > d0 {
                pass.set_vertex_buffer(1, self.instances.buffer.as_ref().expect("instances were written").slice(..));
            }
            for d in &work.draws[d0..d1] {
                let r = self.ranges[d.mesh];
                pass.draw_indexed(
                    r.first_index..r.first_index + r.index_count,
                    r.base_vertex,
                    d.first..d.first + d.count,
                );
            }
        }
        encoder
    }

    /// Waits for the last submission and unpacks its views into `out`.
    pub(super) fn read(&self, out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        self.readback.read(&self.device, out)
    }
}
