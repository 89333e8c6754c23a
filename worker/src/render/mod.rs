//! Headless rendering of the robot's views: RGB, linear depth and instance ids (§3.2.2).
//!
//! One code path for every machine: wgpu on a real GPU where there is one, on Mesa's lavapipe
//! (Vulkan on the CPU) where there is not. Everything visible is a `geometry::Part`, drawn as an
//! instance of a unit mesh (`mesh.rs`: box, and fine or coarse cylinder, sphere, cone).
//!
//! - A scene's parts are uploaded once into a static storage buffer and reused by every view
//!   of it; the person's parts change per frame and go into a per-chunk dynamic buffer.
//! - Per view, parts outside the camera's frustum are skipped on the CPU (conservatively, so
//!   no pixel changes): the view draws an instance-rate list of indices into those buffers.
//!   On lavapipe, where vertex work runs on the submitting thread, this saves about a third
//!   of the time per view.
//! - Views are rendered in chunks of `max_views_per_submit`, each view into its own layer of
//!   a texture array, so its bytes never depend on which chunk or slot it was rendered in
//!   (a tiled atlas would shift the rasteriser's sub-pixel arithmetic per tile). One copy and
//!   one map per chunk; rows go straight into the caller's slices (which may be shared memory).
//! - Two targets: Rgba8Unorm colour and R32Uint `depth16 << 16 | id` (GL cannot render to
//!   R32Float; a single packed Rg32Uint target measured slower on lavapipe).
//!
//! Outputs per view: `rgb` u8 ×3 (top row first), `depth` u16 (eye-space z, 0..10 m →
//! 0..65535, farther and empty = 65535) and optionally `ids` u16 (the `Part::id` of the
//! visible surface, 0 where nothing is).

pub mod bench;
mod camera;
pub mod mesh;

use std::sync::mpsc;

use wgpu::util::DeviceExt;

pub use bench::{bench_views, benchmark_room, figure_parts, spread_cameras};
pub use camera::{Camera, FAR, Frustum, MAX_DEPTH_M, NEAR, ViewUniform, decode_depth, encode_depth, project};
use mesh::{MESH_COUNT, MeshRange, mesh_index};

use crate::geometry::{ID_STRUCTURE, Part};

/// Image size, field of view and how many views go into one GPU submission.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderConfig {
    pub width: u32,
    pub height: u32,
    /// Vertical field of view in degrees; the horizontal one follows from the aspect ratio
    /// (equal for the square 224×224 images of §3.2.2).
    pub fov_deg: f32,
    /// Views rendered per submit and read back with one map. More amortises the fixed cost
    /// of a submission (large on a GPU); each slot holds a colour, an info and a depth layer.
    pub max_views_per_submit: usize,
}

impl Default for RenderConfig {
    /// The robot's camera of §3.2.2: 224×224, 90° field of view.
    fn default() -> Self {
        RenderConfig { width: 224, height: 224, fov_deg: 90.0, max_views_per_submit: 16 }
    }
}

impl RenderConfig {
    /// Image size and field of view, as the camera module speaks of them.
    pub fn intrinsics(&self) -> crate::camera::Intrinsics {
        crate::camera::Intrinsics { width: self.width, height: self.height, fov_deg: self.fov_deg }
    }

    fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::Config(m));
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return bad(format!("image size {}×{} must be between 1 and 8192 pixels", self.width, self.height));
        }
        if !(self.fov_deg.is_finite() && self.fov_deg > 1.0 && self.fov_deg < 179.0) {
            return bad(format!("fov_deg {} must be between 1 and 179 degrees", self.fov_deg));
        }
        if self.max_views_per_submit == 0 {
            return bad("max_views_per_submit must be at least 1".into());
        }
        Ok(())
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// What can go wrong while setting up or rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no wgpu adapter found on backends {0}: install a Vulkan driver (Mesa lavapipe: `apt-get install mesa-vulkan-drivers`) or an OpenGL ES driver"
    )]
    NoAdapter(String),
    #[error("GESTHOR_WGPU_BACKEND={0:?}: expected `vulkan` or `gl`")]
    BadBackend(String),
    #[error("cannot open a device on adapter {adapter}: {message}")]
    Device { adapter: String, message: String },
    #[error("render config: {0}")]
    Config(String),
    #[error("{views} views but {outputs} outputs: give one output per view")]
    OutputCount { views: usize, outputs: usize },
    #[error("output {index}: `{field}` holds {got} values, expected {expected}")]
    OutputSize { index: usize, field: &'static str, got: usize, expected: usize },
    #[error("view {index}: the scene handle was released or never uploaded")]
    UnknownScene { index: usize },
    #[error("reading the rendered frames back failed: {0}")]
    Readback(String),
}

/// A scene uploaded with `Renderer::upload_scene`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SceneHandle {
    slot: u32,
    generation: u32,
}

/// One view to render: a scene, a camera and the parts that move this frame (the person).
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    pub scene: SceneHandle,
    pub camera: Camera,
    pub dynamic: &'a [Part],
}

/// Where one view's images go. Sizes: `rgb` width·height·3, `depth` and `ids` width·height.
#[derive(Debug)]
pub struct ViewOut<'a> {
    /// Row-major, top row first, RGB.
    pub rgb: &'a mut [u8],
    /// Eye-space depth, 0..10 m → 0..65535 (saturating; nothing = 65535).
    pub depth: &'a mut [u16],
    /// `Part::id` of the visible surface, 0 where nothing is.
    pub ids: Option<&'a mut [u16]>,
}

impl<'a> ViewOut<'a> {
    /// Cuts buffers holding several views back to back (`pixels` each) into one output per view.
    pub fn split(rgb: &'a mut [u8], depth: &'a mut [u16], ids: &'a mut [u16], pixels: usize) -> Vec<ViewOut<'a>> {
        rgb.chunks_exact_mut(pixels * 3)
            .zip(depth.chunks_exact_mut(pixels))
            .zip(ids.chunks_exact_mut(pixels))
            .map(|((rgb, depth), ids)| ViewOut { rgb, depth, ids: Some(ids) })
            .collect()
    }
}

/// Number of pixels showing instance `id`.
pub fn count_id(ids: &[u16], id: u16) -> u32 {
    ids.iter().filter(|&&v| v == id).count() as u32
}

/// One part as the vertex shader reads it from a storage buffer: the columns of rotation ×
/// half extents with the centre in their w, the colour, and `id | material << 16`.
/// Matches `struct Instance` in scene.wgsl (64 bytes, std430).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct Instance {
    col0: [f32; 4],
    col1: [f32; 4],
    col2: [f32; 4],
    color: [f32; 3],
    tag: u32,
}

impl Instance {
    fn from_part(p: &Part) -> Instance {
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
struct Group {
    mesh: usize,
    first: u32,
    count: u32,
}

/// Parts as instances sorted into groups by unit mesh, with their bounding spheres.
#[derive(Default)]
struct Grouped {
    instances: Vec<Instance>,
    bounds: Vec<[f32; 4]>,
    groups: Vec<Group>,
}

impl Grouped {
    fn clear(&mut self) {
        self.instances.clear();
        self.bounds.clear();
        self.groups.clear();
    }

    /// Appends `parts` grouped by unit mesh (stable within a group). With `structure_last`,
    /// floor, walls and ceiling go after everything else: they lie behind all furniture, so
    /// drawing them last lets the depth test skip their hidden pixels.
    fn push(&mut self, parts: &[Part], structure_last: bool) {
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
        for p in parts {
            let b = bucket(p);
            self.instances[next[b] as usize] = Instance::from_part(p);
            self.bounds[next[b] as usize] = bounding_sphere(p);
            next[b] += 1;
        }
    }
}

/// One draw call: `count` instance references from `first` in the chunk's reference list,
/// resolved in the scene's or the chunk's dynamic instance buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Draw {
    mesh: usize,
    first: u32,
    count: u32,
    dynamic: bool,
}

use bytemuck::Zeroable;

struct GpuScene {
    /// None for a scene without parts.
    bind_group: Option<wgpu::BindGroup>,
    bounds: Vec<[f32; 4]>,
    groups: Vec<Group>,
}

struct SceneSlot {
    generation: u32,
    scene: Option<GpuScene>,
}

/// The per-chunk render targets: one layer per view slot.
struct Targets {
    color_layers: Vec<wgpu::TextureView>,
    info_layers: Vec<wgpu::TextureView>,
    depth_layers: Vec<wgpu::TextureView>,
    color: wgpu::Texture,
    info: wgpu::Texture,
}

/// A buffer that grows (to the next power of two) when a chunk needs more room.
struct Growable {
    buffer: Option<wgpu::Buffer>,
    capacity: u64,
    usage: wgpu::BufferUsages,
    label: &'static str,
}

impl Growable {
    fn new(label: &'static str, usage: wgpu::BufferUsages) -> Growable {
        Growable { buffer: None, capacity: 0, usage: usage | wgpu::BufferUsages::COPY_DST, label }
    }

    /// Writes `data` at offset 0; true if the buffer was replaced.
    fn write(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, data: &[u8]) -> bool {
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

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const INFO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Info value of a pixel that shows nothing: depth 65535, id 0.
const INFO_CLEAR: u32 = 0xFFFF_0000;

/// Renders views of uploaded scenes; owns the wgpu device and every buffer it reuses.
pub struct Renderer {
    cfg: RenderConfig,
    /// Views per submit after clamping to the device's texture-array limit.
    capacity: usize,
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    pipeline: wgpu::RenderPipeline,
    instance_layout: wgpu::BindGroupLayout,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    ranges: [MeshRange; MESH_COUNT],
    view_buffer: wgpu::Buffer,
    view_stride: u64,
    view_bind_group: wgpu::BindGroup,
    targets: Targets,
    /// Colour layers of a chunk, then info layers; rows padded to 256 bytes.
    readback: wgpu::Buffer,
    row_bytes: u32,
    layer_bytes: u64,
    info_offset: u64,
    /// The person's (and any other moving) parts of every view of the chunk.
    dynamic: Growable,
    dynamic_bind_group: Option<wgpu::BindGroup>,
    /// Per view, the indices of the instances that survive frustum culling (instance-rate
    /// vertex attribute), so a static scene buffer serves every camera.
    refs: Growable,
    /// Skip parts outside each view's frustum (on by default; off only to measure it).
    culling: bool,
    scenes: Vec<SceneSlot>,
    scratch_dynamic: Grouped,
    scratch_refs: Vec<u32>,
    scratch_draws: Vec<Draw>,
    scratch_view_draws: Vec<(usize, usize)>,
    scratch_uniforms: Vec<u8>,
}

/// Which backends to look at, from GESTHOR_WGPU_BACKEND (unset: Vulkan, then GL).
fn backends_from_env() -> Result<Vec<wgpu::Backends>, RenderError> {
    match std::env::var("GESTHOR_WGPU_BACKEND") {
        Err(_) => Ok(vec![wgpu::Backends::VULKAN, wgpu::Backends::GL]),
        Ok(s) => match s.trim().to_ascii_lowercase().as_str() {
            "" => Ok(vec![wgpu::Backends::VULKAN, wgpu::Backends::GL]),
            "vulkan" | "vk" => Ok(vec![wgpu::Backends::VULKAN]),
            "gl" | "gles" | "opengl" => Ok(vec![wgpu::Backends::GL]),
            _ => Err(RenderError::BadBackend(s)),
        },
    }
}

fn device_rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// Picks the adapter: the best device (GPU before CPU) of the first backend in the list that
/// has any. GL is probed only when Vulkan has nothing (probing it can print display-server
/// noise) or when GESTHOR_WGPU_BACKEND=gl asks for it.
fn pick_adapter(backend_order: &[wgpu::Backends]) -> Result<(wgpu::Instance, wgpu::Adapter), RenderError> {
    for &backends in backend_order {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends,
            flags: wgpu::InstanceFlags::from_build_config().with_env(),
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let mut adapters = pollster::block_on(instance.enumerate_adapters(backends));
        // stable: equal ranks keep the driver's order
        adapters.sort_by_key(|a| device_rank(a.get_info().device_type));
        if let Some(best) = adapters.into_iter().next() {
            return Ok((instance, best));
        }
    }
    let names: Vec<String> = backend_order.iter().map(|b| format!("{b:?}")).collect();
    Err(RenderError::NoAdapter(names.join(", ")))
}

fn align_up(v: u64, a: u64) -> u64 {
    v.div_ceil(a) * a
}

impl Renderer {
    /// Opens the best adapter (GESTHOR_WGPU_BACKEND=vulkan|gl restricts the choice) and
    /// builds the pipeline, meshes and per-chunk targets.
    pub fn new(cfg: &RenderConfig) -> Result<Renderer, RenderError> {
        cfg.validate()?;
        let (_instance, adapter) = pick_adapter(&backends_from_env()?)?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        if !adapter.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::VERTEX_STORAGE) {
            return Err(RenderError::Device {
                adapter: describe(&info),
                message: "vertex shaders cannot read storage buffers on this adapter".into(),
            });
        }
        if cfg.width > limits.max_texture_dimension_2d || cfg.height > limits.max_texture_dimension_2d {
            return Err(RenderError::Config(format!(
                "image size {}×{} exceeds the adapter's limit of {} pixels",
                cfg.width, cfg.height, limits.max_texture_dimension_2d
            )));
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("gesthor-render"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::Device { adapter: describe(&info), message: e.to_string() })?;

        let capacity = cfg.max_views_per_submit.min(limits.max_texture_array_layers as usize).max(1);
        let view_stride =
            align_up(std::mem::size_of::<ViewUniform>() as u64, limits.min_uniform_buffer_offset_alignment as u64);

        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scene.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("scene.wgsl").into()),
        });
        let view_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
                },
                count: None,
            }],
        });
        let instance_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("instances"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<Instance>() as u64),
                },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("scene"),
            bind_group_layouts: &[Some(&view_layout), Some(&instance_layout)],
            immediate_size: 0,
        });
        let vertex_attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3];
        let instance_attrs = wgpu::vertex_attr_array![2 => Uint32];
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("scene"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[
                    Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<mesh::Vertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &vertex_attrs,
                    }),
                    Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<u32>() as u64,
                        step_mode: wgpu::VertexStepMode::Instance,
                        attributes: &instance_attrs,
                    }),
                ],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                // meshes wind outward-CCW in a right-handed sense; through the left-handed
                // camera that is clockwise on screen (see mesh.rs)
                front_face: wgpu::FrontFace::Cw,
                cull_mode: Some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater), // reversed Z
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[
                    Some(wgpu::ColorTargetState {
                        format: COLOR_FORMAT,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    }),
                    Some(wgpu::ColorTargetState {
                        format: INFO_FORMAT,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    }),
                ],
            }),
            multiview_mask: None,
            cache: None,
        });

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

        let targets = make_targets(&device, cfg, capacity);
        let row_bytes = align_up(cfg.width as u64 * 4, wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as u64) as u32;
        let layer_bytes = row_bytes as u64 * cfg.height as u64;
        let info_offset = layer_bytes * capacity as u64;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: info_offset * 2,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        Ok(Renderer {
            cfg: cfg.clone(),
            capacity,
            device,
            queue,
            info,
            pipeline,
            instance_layout,
            vertices,
            indices,
            ranges,
            view_buffer,
            view_stride,
            view_bind_group,
            targets,
            readback,
            row_bytes,
            layer_bytes,
            info_offset,
            dynamic: Growable::new("dynamic instances", wgpu::BufferUsages::STORAGE),
            dynamic_bind_group: None,
            refs: Growable::new("instance references", wgpu::BufferUsages::VERTEX),
            culling: true,
            scenes: Vec::new(),
            scratch_dynamic: Grouped::default(),
            scratch_refs: Vec::new(),
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
    /// (the test is conservative); culling only saves vertex work. For measurements.
    pub fn set_frustum_culling(&mut self, on: bool) {
        self.culling = on;
    }

    /// Uploads a scene's static parts once; views then refer to it by handle.
    pub fn upload_scene(&mut self, parts: &[Part]) -> SceneHandle {
        let mut g = Grouped::default();
        g.push(parts, true);
        let bind_group = (!g.instances.is_empty()).then(|| {
            let buffer = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("scene instances"),
                contents: bytemuck::cast_slice(&g.instances),
                usage: wgpu::BufferUsages::STORAGE,
            });
            self.instance_bind_group(&buffer)
        });
        let scene = GpuScene { bind_group, bounds: g.bounds, groups: g.groups };
        let slot = match self.scenes.iter().position(|s| s.scene.is_none()) {
            Some(i) => i,
            None => {
                self.scenes.push(SceneSlot { generation: 0, scene: None });
                self.scenes.len() - 1
            }
        };
        let s = &mut self.scenes[slot];
        s.generation = s.generation.wrapping_add(1);
        s.scene = Some(scene);
        SceneHandle { slot: slot as u32, generation: s.generation }
    }

    fn instance_bind_group(&self, buffer: &wgpu::Buffer) -> wgpu::BindGroup {
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("instances"),
            layout: &self.instance_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() }],
        })
    }

    /// Frees a scene's GPU buffers; the handle becomes invalid.
    pub fn release_scene(&mut self, h: SceneHandle) {
        if let Some(s) = self.scenes.get_mut(h.slot as usize)
            && s.generation == h.generation
        {
            s.scene = None;
        }
    }

    fn scene(&self, h: SceneHandle) -> Option<&GpuScene> {
        self.scenes.get(h.slot as usize).filter(|s| s.generation == h.generation).and_then(|s| s.scene.as_ref())
    }

    /// Renders every view into its output, `views_per_submit` views per GPU submission.
    pub fn render(&mut self, views: &[View<'_>], out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        if views.len() != out.len() {
            return Err(RenderError::OutputCount { views: views.len(), outputs: out.len() });
        }
        let n = self.cfg.pixels();
        for (index, (v, o)) in views.iter().zip(out.iter()).enumerate() {
            if self.scene(v.scene).is_none() {
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

    /// Writes the chunk's camera uniforms, dynamic instances and per-view instance
    /// references (frustum-culled), one buffer write each, and records the draws.
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
        dynamic.clear();
        self.scratch_refs.clear();
        self.scratch_draws.clear();
        self.scratch_view_draws.clear();
        for v in views {
            let frustum = self.culling.then(|| Frustum::new(&v.camera, &self.cfg));
            let frustum = frustum.as_ref();
            let start = self.scratch_draws.len();
            let first_group = dynamic.groups.len();
            dynamic.push(v.dynamic, false);
            cull(
                frustum,
                &dynamic.bounds,
                &dynamic.groups[first_group..],
                true,
                &mut self.scratch_refs,
                &mut self.scratch_draws,
            );
            let scene = self.scenes[v.scene.slot as usize].scene.as_ref().expect("checked in render()");
            cull(frustum, &scene.bounds, &scene.groups, false, &mut self.scratch_refs, &mut self.scratch_draws);
            self.scratch_view_draws.push((start, self.scratch_draws.len()));
        }
        if !dynamic.instances.is_empty() {
            let grown = self.dynamic.write(&self.device, &self.queue, bytemuck::cast_slice(&dynamic.instances));
            if grown || self.dynamic_bind_group.is_none() {
                let buffer = self.dynamic.buffer.as_ref().expect("written above");
                self.dynamic_bind_group = Some(self.instance_bind_group(buffer));
            }
        }
        self.refs.write(&self.device, &self.queue, bytemuck::cast_slice(&self.scratch_refs));
    }

    fn render_chunk(&mut self, views: &[View<'_>], out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        let k = views.len();
        debug_assert!(k <= self.capacity);
        self.upload_chunk(views);

        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("views") });
        for (i, v) in views.iter().enumerate() {
            let scene = self.scene(v.scene).expect("checked in render()");
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
                pass.set_vertex_buffer(1, self.refs.buffer.as_ref().expect("references were written").slice(..));
            }
            let mut bound_dynamic = None;
            for d in &self.scratch_draws[d0..d1] {
                if bound_dynamic != Some(d.dynamic) {
                    let group = if d.dynamic { self.dynamic_bind_group.as_ref() } else { scene.bind_group.as_ref() };
                    pass.set_bind_group(1, group.expect("a draw implies instances"), &[]);
                    bound_dynamic = Some(d.dynamic);
                }
                let r = self.ranges[d.mesh];
                pass.draw_indexed(
                    r.first_index..r.first_index + r.index_count,
                    r.base_vertex,
                    d.first..d.first + d.count,
                );
            }
        }
        let extent = wgpu::Extent3d { width: self.cfg.width, height: self.cfg.height, depth_or_array_layers: k as u32 };
        for (texture, offset) in [(&self.targets.color, 0), (&self.targets.info, self.info_offset)] {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset,
                        bytes_per_row: Some(self.row_bytes),
                        rows_per_image: Some(self.cfg.height),
                    },
                },
                extent,
            );
        }
        self.queue.submit([encoder.finish()]);

        let end = self.info_offset + self.layer_bytes * k as u64;
        let slice = self.readback.slice(..end);
        let (tx, rx) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| RenderError::Readback(e.to_string()))?;
        match rx.try_recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(RenderError::Readback(e.to_string())),
            Err(_) => return Err(RenderError::Readback("the map callback did not run".into())),
        }
        {
            let data = slice.get_mapped_range().map_err(|e| RenderError::Readback(e.to_string()))?;
            for (i, o) in out.iter_mut().enumerate() {
                let color = &data[i * self.layer_bytes as usize..];
                let info = &data[(self.info_offset + i as u64 * self.layer_bytes) as usize..];
                unpack_view(color, info, self.row_bytes as usize, self.cfg.width as usize, self.cfg.height as usize, o);
            }
        }
        self.readback.unmap();
        Ok(())
    }
}

/// Appends, for each group, the indices of its instances whose bounding sphere may show in
/// the frustum, and one draw for the survivors.
fn cull(
    frustum: Option<&Frustum>,
    bounds: &[[f32; 4]],
    groups: &[Group],
    dynamic: bool,
    refs: &mut Vec<u32>,
    draws: &mut Vec<Draw>,
) {
    for g in groups {
        let first = refs.len() as u32;
        for i in g.first..g.first + g.count {
            let b = bounds[i as usize];
            if frustum.is_none_or(|f| f.may_see_sphere([b[0], b[1], b[2]], b[3])) {
                refs.push(i);
            }
        }
        let count = refs.len() as u32 - first;
        if count > 0 {
            draws.push(Draw { mesh: g.mesh, first, count, dynamic });
        }
    }
}

/// Copies one view from the padded readback rows into the caller's slices: RGBA → RGB and
/// `depth << 16 | id` → depth, id.
fn unpack_view(color: &[u8], info: &[u8], row_bytes: usize, w: usize, h: usize, o: &mut ViewOut<'_>) {
    for y in 0..h {
        let src = &color[y * row_bytes..y * row_bytes + w * 4];
        let dst = &mut o.rgb[y * w * 3..(y + 1) * w * 3];
        for (d, s) in dst.chunks_exact_mut(3).zip(src.chunks_exact(4)) {
            d.copy_from_slice(&s[..3]);
        }
        let src = &info[y * row_bytes..y * row_bytes + w * 4];
        let depth = &mut o.depth[y * w..(y + 1) * w];
        match o.ids.as_deref_mut() {
            Some(ids) => {
                let ids = &mut ids[y * w..(y + 1) * w];
                for ((d, id), s) in depth.iter_mut().zip(ids.iter_mut()).zip(src.chunks_exact(4)) {
                    let v = u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *d = (v >> 16) as u16;
                    *id = v as u16;
                }
            }
            None => {
                for (d, s) in depth.iter_mut().zip(src.chunks_exact(4)) {
                    *d = u16::from_le_bytes([s[2], s[3]]);
                }
            }
        }
    }
}

fn make_targets(device: &wgpu::Device, cfg: &RenderConfig, layers: usize) -> Targets {
    let size = wgpu::Extent3d { width: cfg.width, height: cfg.height, depth_or_array_layers: layers as u32 };
    let texture = |label, format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let out_usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
    let color = texture("colour", COLOR_FORMAT, out_usage);
    let info = texture("depth+id", INFO_FORMAT, out_usage);
    let depth = texture("depth buffer", DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT);
    let layer_views = |t: &wgpu::Texture| -> Vec<wgpu::TextureView> {
        (0..layers as u32)
            .map(|i| {
                t.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: i,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect()
    };
    Targets {
        color_layers: layer_views(&color),
        info_layers: layer_views(&info),
        depth_layers: layer_views(&depth),
        color,
        info,
    }
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?}, driver {} {})", info.name, info.backend, info.device_type, info.driver, info.driver_info)
}

#[cfg(test)]
mod tests;
