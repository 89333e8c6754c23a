//! Headless rendering of the robot's views: RGB, linear depth and instance ids (§3.2.2).
//!
//! One code path for every machine: wgpu on a real GPU where there is one, on Mesa's lavapipe
//! (Vulkan on the CPU) where there is not. Everything visible is a `geometry::Part`, drawn as an
//! instance of a unit mesh (`mesh.rs`: box, and fine or coarse cylinder, sphere, cone).
//!
//! - A scene's parts stay on the CPU, grouped by mesh with their bounding spheres. Per view,
//!   the parts that may show (inside the frustum and covering a pixel centre: conservative,
//!   so no pixel changes) are copied with the person's into the chunk's instance buffer and
//!   drawn as instance-rate vertex attributes. (lavapipe reads a storage buffer one SIMD lane
//!   at a time in a scalar loop: through one, the parts cost more than the whole vertex
//!   shader.)
//! - Level of detail: a round part whose image is small takes its coarse mesh where that
//!   moves its silhouette by at most `mesh::LOD_TOLERANCE_PX` (a quarter pixel): at 64×64
//!   the fine meshes' hundreds of triangles otherwise land on a handful of pixels. This is
//!   the one change to the images (0.06% of pixels at 64×64, 0.001% at 224×224).
//! - Views are rendered in chunks of `max_views_per_submit`, each view into its own layer of
//!   a texture array, so its bytes never depend on which chunk or slot it was rendered in
//!   (a tiled atlas would shift the rasteriser's sub-pixel arithmetic per tile). One copy and
//!   one map per chunk; rows go straight into the caller's slices (which may be shared memory).
//! - Lanes: GESTHOR_RENDER_LANES=N opens N devices and splits each chunk between them. On
//!   lavapipe a device executes its commands on one thread, where a small view's vertex work
//!   dominates, so one lane keeps one core busy; N lanes let one process use N cores (with
//!   LP_NUM_THREADS=0 each lane also rasterises on its own thread). Every lane renders the
//!   same bytes.
//! - Two targets: Rgba8Unorm colour and R32Uint `depth16 << 16 | id` (GL cannot render to
//!   R32Float; a single packed Rg32Uint target measured slower on lavapipe).
//!
//! Outputs per view: `rgb` u8 ×3 (top row first), `depth` u16 (eye-space z, 0..10 m →
//! 0..65535, farther and empty = 65535) and optionally `ids` u16 (the `Part::id` of the
//! visible surface, 0 where nothing is).
//!
//! Files, in the order a frame passes through them: `config` (what is asked for), `adapter`
//! (which device), `pipeline` (shader and fixed-function state), `instances` (parts as the
//! shader reads them), `scenes` (uploaded scenes and their handles), `projection` (the
//! per-view uniforms and the same projection on the CPU), `culling` (per-view culling and
//! level of detail into draws), `targets` (the per-chunk texture arrays), `readback` (copy, map,
//! unpack), `lane` (one device: records, submits and reads back its share of a chunk),
//! `view` (per-view inputs and outputs), `renderer` (the `Renderer` API that ties them
//! together); `mesh` (unit meshes) and `bench` (throughput fixtures). Frames that stay on the
//! device skip the readback: `export` (GPU memory another process imports, each view copied
//! into its env's slot) and `visible` (the one figure the host still needs: target pixels).

pub mod bench;
pub mod mesh;

mod adapter;
mod config;
mod culling;
mod error;
mod export;
mod instances;
mod lane;
mod pipeline;
mod projection;
mod readback;
mod renderer;
mod scenes;
mod targets;
mod view;
mod visible;

pub use bench::{bench_views, benchmark_room, figure_parts, spread_cameras};
pub use config::RenderConfig;
pub use culling::Frustum;
pub use error::RenderError;
pub use export::ExportedFrames;
pub use projection::{ViewUniform, project};
pub use renderer::Renderer;
pub use scenes::SceneHandle;
pub use view::{View, ViewOut, count_id};

/// Mesa's drivers probe Wayland, whose client library prints "error: XDG_RUNTIME_DIR is invalid
/// or not set in the environment." where it is missing (headless machines, CI). Pointing it at
/// a private empty folder keeps that line out of the user's terminal (`RUST_LOG` set: left as
/// is, so a driver problem can be looked into). Call first thing in `main`, before any thread
/// starts: it sets an environment variable, which children inherit.
pub fn quiet_headless_display() {
    let valid = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
    if valid || std::env::var_os("RUST_LOG").is_some() {
        return;
    }
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    let uid = std::fs::metadata("/proc/self").map_or(0, |m| m.uid());
    let dir = std::env::temp_dir().join(format!("gesthor-runtime-{uid}"));
    if std::fs::DirBuilder::new().mode(0o700).create(&dir).is_ok() || dir.is_dir() {
        // SAFETY: called at the start of main, before any other thread exists.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", &dir) };
    }
}

/// Whether this machine must have a wgpu adapter: under CI, or where `scripts/setup.sh`
/// installed Mesa's lavapipe (its env.sh sets `GESTHOR_ADAPTER_REQUIRED=1`). Tests that render
/// skip on a machine without any adapter only when this is false, and fail otherwise.
pub fn adapter_required() -> bool {
    let set = |k: &str| std::env::var(k).is_ok_and(|v| !v.is_empty() && v != "0" && v != "false");
    set("CI") || set("GESTHOR_ADAPTER_REQUIRED")
}

#[cfg(test)]
mod tests;
