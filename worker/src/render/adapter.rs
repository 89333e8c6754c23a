//! Which adapter renders (a GPU where there is one, lavapipe on the CPU where there is not)
//! and the device opened on it.

use super::config::RenderConfig;
use super::error::RenderError;

/// An opened device and what the renderer needs to know of its adapter.
pub(super) struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
}

/// Opens the best adapter (GESTHOR_WGPU_BACKEND=vulkan|gl restricts the choice) with its full
/// limits, after checking that it can run the renderer at `cfg`'s image size.
pub(super) fn open(cfg: &RenderConfig) -> Result<Gpu, RenderError> {
    let (_instance, adapter) = pick_adapter(&backends_from_env()?)?;
    let info = adapter.get_info();
    let limits = adapter.limits();
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
    Ok(Gpu { device, queue, info, limits })
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

/// How many devices render in parallel, from GESTHOR_RENDER_LANES (unset: 1). On lavapipe,
/// where a device executes its commands on one thread and most of a small view's cost is
/// that thread's vertex work, two lanes let one process use two cores.
pub(super) fn lanes_from_env() -> Result<usize, RenderError> {
    match std::env::var("GESTHOR_RENDER_LANES") {
        Err(_) => Ok(1),
        Ok(s) => match s.trim().parse::<usize>() {
            Ok(n) if (1..=MAX_LANES).contains(&n) => Ok(n),
            _ => Err(RenderError::BadLanes(s)),
        },
    }
}

/// The most lanes a renderer opens.
pub(super) const MAX_LANES: usize = 16;

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

/// "name (backend, device type, driver)" of an adapter, for logs and benchmark records.
pub(super) fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?}, driver {} {})", info.name, info.backend, info.device_type, info.driver, info.driver_info)
}
