//! The `Renderer`: opens the device, keeps uploaded scenes, and renders views in chunks, one
//! submission and one readback per chunk.

use wgpu::util::DeviceExt;

use super::adapter::{self, Gpu, describe};
use super::config::RenderConfig;
use super::culling::{Draw, Frustum, cull};
use super::error::RenderError;
use super::instances::{Grouped, Growable, Instance};
use super::mesh::{self, MESH_COUNT, MeshRange};
use super::pipeline::Pipeline;
use super::projection::ViewUniform;
use super::readback::Readback;
use super::scenes::{SceneHandle, Scenes};
use super::targets::{INFO_CLEAR, Targets};
use super::view::{View, ViewOut};
use crate::geometry::Part;

/// Renders views of uploaded scenes; owns the wgpu device and every buffer it reuses.
pub struct Renderer {
    cfg: RenderConfig,
    /// Views per submit after clamping to the device's texture-array limit.
    capacity: usize,
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    pipeline: wgpu::RenderPipeline,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    ranges: [MeshRange; MESH_COUNT],
    view_buffer: wgpu::Buffer,
    view_stride: u64,
    view_bind_group: wgpu::BindGroup,
    targets: Targets,
    readback: Readback,
    /// Per view, the instances (the person's, then the scene's) that survive frustum culling.
    instances: Growable,
    /// Skip parts outside each view's frustum (on by default; off only to measure it).
    culling: bool,
    scenes: Scenes,
    scratch_dynamic: Grouped,
    scratch_instances: Vec<Instance>,
    scratch_draws: Vec<Draw>,
    scratch_view_draws: Vec<(usize, usize)>,
    scratch_uniforms: Vec<u8>,
}

impl Renderer {
    /// Opens the best adapter (GESTHOR_WGPU_BACKEND=vulkan|gl restricts the choice) and
    /// builds the pipeline, meshes and per-chunk targets.
    pub fn new(cfg: &RenderConfig) -> Result<Renderer, RenderError> {
        cfg.validate()?;
        let Gpu { device, queue, info, limits } = adapter::open(cfg)?;

        let capacity = cfg.max_views_per_submit.min(limits.max_texture_array_layers as usize).max(1);
        let view_stride = (std::mem::size_of::<ViewUniform>() as u64)
            .next_multiple_of(limits.min_uniform_buffer_offset_alignment as u64);

        let Pipeline { pipeline, view_layout } = Pipeline::new(&device);

        let (verts, idx, ranges) = mesh::all_unit_meshes();
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("unit meshes"),
            contents: bytemuck::cast_slice(&verts),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("unit mesh indices"),
            contents: bytemuck::cast_slice(&idx),
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

        Ok(Renderer {
            cfg: cfg.clone(),
            capacity,
            device,
            queue,
            info,
            pipeline,
            vertices,
            indices,
            ranges,
            view_buffer,
            view_stride,
            view_bind_group,
            targets,
            readback,
            instances: Growable::new("instances", wgpu::BufferUsages::VERTEX),
            culling: true,
            scenes: Scenes::default(),
            scratch_dynamic: Grouped::default(),
            scratch_instances: Vec::new(),
            scratch_draws: Vec::new(),
            scratch_view_draws: Vec::new(),
            scratch_uniforms: Vec::new(),
        })
    }

    /// "name (backend, device type)" of the adapter in use, for logs and benchmark records.
    pub fn adapter_info(&self) -> String {
        describe(&self.info)
    }

    /// Whether the adapter is a CPU rasteriser (lavapipe, llvmpipe).
    pub fn is_cpu(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    pub fn config(&self) -> &RenderConfig {
        &self.cfg
    }

    /// Views rendered per submission (the configured number, limited by the device).
    pub fn views_per_submit(&self) -> usize {
        self.capacity
    }

    /// Turns per-view frustum culling of parts on or off. The images are identical either way
    /// (the test is conservative; the level of detail does not depend on it); culling only
    /// saves vertex work. For measurements.
    pub fn set_frustum_culling(&mut self, on: bool) {
        self.culling = on;
    }

    /// Takes a scene's static parts once (grouped by mesh, with their bounds); views then
    /// refer to it by handle.
    pub fn upload_scene(&mut self, parts: &[Part]) -> SceneHandle {
        let mut g = Grouped::default();
        g.push(parts, true);
        self.scenes.insert(g)
    }

    /// Frees a scene; the handle becomes invalid.
    pub fn release_scene(&mut self, h: SceneHandle) {
        self.scenes.release(h);
    }

    /// Renders every view into its output, `views_per_submit` views per GPU submission.
    pub fn render(&mut self, views: &[View<'_>], out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        if views.len() != out.len() {
            return Err(RenderError::OutputCount { views: views.len(), outputs: out.len() });
        }
        let n = self.cfg.pixels();
        for (index, (v, o)) in views.iter().zip(out.iter()).enumerate() {
            if self.scenes.get(v.scene).is_none() {
                return Err(RenderError::UnknownScene { index });
            }
            let check = |field: &'static str, got: usize, expected: usize| {
                if got == expected { Ok(()) } else { Err(RenderError::OutputSize { index, field, got, expected }) }
            };
            check("rgb", o.rgb.len(), n * 3)?;
            check("depth", o.depth.len(), n)?;
            if let Some(ids) = &o.ids {
                check("ids", ids.len(), n)?;
            }
        }
        let cap = self.capacity;
        for (vs, os) in views.chunks(cap).zip(out.chunks_mut(cap)) {
            self.render_chunk(vs, os)?;
        }
        Ok(())
    }

    /// Writes the chunk's camera uniforms and every view's frustum-culled instances (the
    /// person's, then the scene's), one buffer write each, and records the draws.
    fn upload_chunk(&mut self, views: &[View<'_>]) {
        let stride = self.view_stride as usize;
        self.scratch_uniforms.clear();
        self.scratch_uniforms.resize(stride * views.len(), 0);
        for (i, v) in views.iter().enumerate() {
            let u = ViewUniform::new(&v.camera, &self.cfg);
            self.scratch_uniforms[i * stride..i * stride + std::mem::size_of::<ViewUniform>()]
                .copy_from_slice(bytemuck::bytes_of(&u));
        }
        self.queue.write_buffer(&self.view_buffer, 0, &self.scratch_uniforms);

        let dynamic = &mut self.scratch_dynamic;
        self.scratch_instances.clear();
        self.scratch_draws.clear();
        self.scratch_view_draws.clear();
        for v in views {
            let frustum = Frustum::new(&v.camera, &self.cfg);
            let start = self.scratch_draws.len();
            // the person first, then the scene: draw order decides depth ties
            dynamic.clear();
            dynamic.push(v.dynamic, false);
            cull(&frustum, self.culling, dynamic, &mut self.scratch_instances, &mut self.scratch_draws);
            let scene = self.scenes.get(v.scene).expect("checked in render()");
            cull(&frustum, self.culling, scene, &mut self.scratch_instances, &mut self.scratch_draws);
            self.scratch_view_draws.push((start, self.scratch_draws.len()));
        }
        self.instances.write(&self.device, &self.queue, bytemuck::cast_slice(&self.scratch_instances));
    }

    fn render_chunk(&mut self, views: &[View<'_>], out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        let k = views.len();
        debug_assert!(k <= self.capacity);
        self.upload_chunk(views);

        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("views") });
        for i in 0..k {
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
            let (d0, d1) = self.scratch_view_draws[i];
            if d1 > d0 {
                pass.set_vertex_buffer(1, self.instances.buffer.as_ref().expect("instances were written").slice(..));
            }
            for d in &self.scratch_draws[d0..d1] {
                let r = self.ranges[d.mesh];
                pass.draw_indexed(
                    r.first_index..r.first_index + r.index_count,
                    r.base_vertex,
                    d.first..d.first + d.count,
                );
            }
        }
        self.readback.copy(&mut encoder, &self.targets, k);
        self.queue.submit([encoder.finish()]);

        self.readback.read(&self.device, out)
    }
}
