//! The `Renderer`: opens its lanes (devices), keeps uploaded scenes, and renders views in
//! chunks: per chunk it culls every view's parts on the CPU and hands each lane its share,
//! one submission and one readback per lane, the lanes running in parallel.

use super::adapter::{MAX_LANES, describe, lanes_from_env};
use super::config::RenderConfig;
use super::culling::{Draw, Frustum, cull};
use super::error::RenderError;
use super::export::ExportedFrames;
use super::instances::{Grouped, Instance};
use super::lane::{Lane, LaneWork};
use super::mesh;
use super::projection::ViewUniform;
use super::scenes::{SceneHandle, Scenes};
use super::view::{View, ViewOut};
use crate::geometry::Part;

/// Renders views of uploaded scenes; owns the wgpu devices and every buffer it reuses.
pub struct Renderer {
    cfg: RenderConfig,
    /// Views per chunk: the configured number, limited by what the lanes' targets hold.
    capacity: usize,
    lanes: Vec<Lane>,
    /// Skip parts outside each view's frustum (on by default; off only to measure it).
    culling: bool,
    scenes: Scenes,
    /// One per lane.
    scratch: Vec<Scratch>,
    /// With several lanes, one thread per lane that culls, submits and reads back its share.
    threads: Option<rayon::ThreadPool>,
}

/// A lane's share of a chunk as the CPU prepares it.
#[derive(Default)]
struct Scratch {
    dynamic: Grouped,
    uniforms: Vec<ViewUniform>,
    instances: Vec<Instance>,
    draws: Vec<Draw>,
    view_draws: Vec<(usize, usize)>,
}

impl Renderer {
    /// Opens the best adapter (GESTHOR_WGPU_BACKEND=vulkan|gl restricts the choice), once per
    /// lane (GESTHOR_RENDER_LANES, default 1), and builds the pipelines, meshes and targets.
    pub fn new(cfg: &RenderConfig) -> Result<Renderer, RenderError> {
        Renderer::with_lanes(cfg, lanes_from_env()?)
    }

    /// A renderer with `lanes` devices (at most one per view of a chunk). Every lane renders
    /// the same bytes, so how a chunk is split does not show in the images.
    pub fn with_lanes(cfg: &RenderConfig, lanes: usize) -> Result<Renderer, RenderError> {
        cfg.validate()?;
        if !(1..=MAX_LANES).contains(&lanes) {
            return Err(RenderError::BadLanes(lanes.to_string()));
        }
        let lanes = lanes.min(cfg.max_views_per_submit);
        let share = cfg.max_views_per_submit.div_ceil(lanes);
        let meshes = mesh::all_unit_meshes();
        let lanes = (0..lanes).map(|_| Lane::open(cfg, share, &meshes)).collect::<Result<Vec<_>, _>>()?;
        let capacity = lanes.iter().map(|l| l.capacity).sum::<usize>().min(cfg.max_views_per_submit);
        let threads = (lanes.len() > 1)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(lanes.len())
                    .thread_name(|i| format!("render-lane-{i}"))
                    .build()
                    .map_err(|e| RenderError::Device { adapter: describe(&lanes[0].info), message: e.to_string() })
            })
            .transpose()?;
        Ok(Renderer {
            threads,
            cfg: cfg.clone(),
            capacity,
            scratch: lanes.iter().map(|_| Scratch::default()).collect(),
            lanes,
            culling: true,
            scenes: Scenes::default(),
        })
    }

    /// "name (backend, device type)" of the adapter in use, for logs and benchmark records.
    pub fn adapter_info(&self) -> String {
        describe(&self.lanes[0].info)
    }

    /// Whether the adapter is a CPU rasteriser (lavapipe, llvmpipe).
    pub fn is_cpu(&self) -> bool {
        self.lanes[0].info.device_type == wgpu::DeviceType::Cpu
    }

    pub fn config(&self) -> &RenderConfig {
        &self.cfg
    }

    /// Views rendered per chunk, one submission per lane (the configured number, limited by
    /// the devices).
    pub fn views_per_submit(&self) -> usize {
        self.capacity
    }

    /// Devices rendering each chunk in parallel.
    pub fn lanes(&self) -> usize {
        self.lanes.len()
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

    /// Allocates GPU memory for `slots` frames that another process can import (see `export`:
    /// Vulkan with `VK_KHR_external_memory_fd`, one lane), once; `render_exported` draws into it.
    pub fn export_frames(&mut self, slots: usize) -> Result<&ExportedFrames, RenderError> {
        if self.lanes.len() != 1 {
            return Err(RenderError::Export(format!(
                "frames on the device need one lane (GESTHOR_RENDER_LANES={})",
                self.lanes.len()
            )));
        }
        let layout = shm_schema::DeviceFrameLayout::new(slots as u32, self.cfg.width, self.cfg.height);
        self.lanes[0].export(layout)
    }

    /// Renders view `i` into slot `slots[i]` of the exported frames (nothing is read back) and
    /// returns how many of its pixels show part `targets[i]` (`count_id` of the read-back
    /// path). When it returns, the frames are in the exported memory.
    pub fn render_exported(
        &mut self,
        views: &[View<'_>],
        slots: &[u32],
        targets: &[u16],
    ) -> Result<Vec<u32>, RenderError> {
        if views.len() != slots.len() || views.len() != targets.len() {
            return Err(RenderError::OutputCount { views: views.len(), outputs: slots.len().min(targets.len()) });
        }
        let capacity = self.lanes[0]
            .exported_slots()
            .ok_or_else(|| RenderError::Export("render_exported before export_frames".into()))?;
        for (index, (v, &slot)) in views.iter().zip(slots).enumerate() {
            if self.scenes.get(v.scene).is_none() {
                return Err(RenderError::UnknownScene { index });
            }
            if slot as usize >= capacity {
                return Err(RenderError::Export(format!("view {index}: slot {slot} of {capacity}")));
            }
        }
        let mut counts = Vec::with_capacity(views.len());
        let cap = self.capacity;
        let (lane, s) = (&mut self.lanes[0], &mut self.scratch[0]);
        for ((vs, ss), ts) in views.chunks(cap).zip(slots.chunks(cap)).zip(targets.chunks(cap)) {
            s.prepare(vs, &self.scenes, &self.cfg, self.culling);
            lane.submit_exported(&s.work(), ss, ts)?;
            counts.extend(lane.read_visible(vs.len())?);
        }
        Ok(counts)
    }

    /// The exported frame memory's bytes, copied back through the device (for checks: the
    /// learner reads them in place).
    pub fn read_exported(&self) -> Result<Vec<u8>, RenderError> {
        self.lanes[0].read_exported()
    }

    /// Splits the chunk between the lanes. One lane works on this thread; several each have a
    /// thread that culls its share, submits it, waits for it and unpacks it.
    fn render_chunk(&mut self, views: &[View<'_>], out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        debug_assert!(views.len() <= self.capacity);
        let share = views.len().div_ceil(self.lanes.len());
        let (scenes, cfg, culling, one) = (&self.scenes, &self.cfg, self.culling, self.lanes.len() == 1);
        let shares =
            self.lanes.iter_mut().zip(self.scratch.iter_mut()).zip(views.chunks(share).zip(out.chunks_mut(share)));
        if one {
            for ((lane, s), (vs, os)) in shares {
                s.prepare(vs, scenes, cfg, culling);
                lane.submit(&s.work());
                lane.read(os)?;
            }
            return Ok(());
        }
        let threads = self.threads.as_ref().expect("several lanes have threads");
        let mut results: Vec<Result<(), RenderError>> = Vec::new();
        results.resize_with(views.len().div_ceil(share), || Ok(()));
        threads.scope(|scope| {
            for (((lane, s), (vs, os)), result) in shares.zip(results.iter_mut()) {
                scope.spawn(move |_| {
                    s.prepare(vs, scenes, cfg, culling);
                    lane.submit(&s.work());
                    *result = lane.read(os);
                });
            }
        });
        results.into_iter().collect()
    }
}

impl Scratch {
    fn work(&self) -> LaneWork<'_> {
        LaneWork {
            uniforms: &self.uniforms,
            instances: &self.instances,
            draws: &self.draws,
            view_draws: &self.view_draws,
        }
    }

    /// Every view's camera uniforms and the instances that survive culling (the person's,
    /// then the scene's), with the draws.
    fn prepare(&mut self, views: &[View<'_>], scenes: &Scenes, cfg: &RenderConfig, culling: bool) {
        self.uniforms.clear();
        self.instances.clear();
        self.draws.clear();
        self.view_draws.clear();
        for v in views {
            self.uniforms.push(ViewUniform::new(&v.camera, cfg));
            let frustum = Frustum::new(&v.camera, cfg);
            let start = self.draws.len();
            // the person first, then the scene: draw order decides depth ties
            self.dynamic.clear();
            self.dynamic.push(v.dynamic, false);
            cull(&frustum, culling, &self.dynamic, &mut self.instances, &mut self.draws);
            let scene = scenes.get(v.scene).expect("checked in render()");
            cull(&frustum, culling, scene, &mut self.instances, &mut self.draws);
            self.view_draws.push((start, self.draws.len()));
        }
    }
}
