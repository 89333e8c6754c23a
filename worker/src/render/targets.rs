//! The render targets of one chunk of views: a colour, a packed depth+id and a depth-buffer
//! layer per view slot.

use super::config::RenderConfig;

pub(super) const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
pub(super) const INFO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
pub(super) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Info value of a pixel that shows nothing: depth 65535, id 0.
pub(super) const INFO_CLEAR: u32 = 0xFFFF_0000;

/// The per-chunk render targets: one layer per view slot.
pub(super) struct Targets {
    pub color_layers: Vec<wgpu::TextureView>,
    pub info_layers: Vec<wgpu::TextureView>,
    pub depth_layers: Vec<wgpu::TextureView>,
    pub color: wgpu::Texture,
    pub info: wgpu::Texture,
}

impl Targets {
    /// Texture arrays of `layers` slots and a view of every layer.
    pub(super) fn new(device: &wgpu::Device, cfg: &RenderConfig, layers: usize) -> Targets {
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
        // read by the visible-pixel count of frames kept on the device (`visible.rs`)
        let info = texture("depth+id", INFO_FORMAT, out_usage | wgpu::TextureUsages::TEXTURE_BINDING);
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
}
