//! Reading a chunk's rendered layers back: one copy of every colour and depth+id layer into a
//! mappable buffer, one map, and rows unpacked straight into the caller's slices.

use std::sync::mpsc;

use super::config::RenderConfig;
use super::error::RenderError;
use super::targets::Targets;
use super::view::ViewOut;

/// The mappable buffer of a chunk: colour layers, then info layers; rows padded to 256 bytes.
pub(super) struct Readback {
    buffer: wgpu::Buffer,
    row_bytes: u32,
    layer_bytes: u64,
    info_offset: u64,
    width: u32,
    height: u32,
}

impl Readback {
    /// Room for `layers` views of `cfg`'s size.
    pub(super) fn new(device: &wgpu::Device, cfg: &RenderConfig, layers: usize) -> Readback {
        let row_bytes = (cfg.width as u64 * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as u64) as u32;
        let layer_bytes = row_bytes as u64 * cfg.height as u64;
        let info_offset = layer_bytes * layers as u64;
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: info_offset * 2,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Readback { buffer, row_bytes, layer_bytes, info_offset, width: cfg.width, height: cfg.height }
    }

    /// Records the copy of the first `views` layers of the colour and info targets.
    pub(super) fn copy(&self, encoder: &mut wgpu::CommandEncoder, targets: &Targets, views: usize) {
        let extent = wgpu::Extent3d { width: self.width, height: self.height, depth_or_array_layers: views as u32 };
        for (texture, offset) in [(&targets.color, 0), (&targets.info, self.info_offset)] {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset,
                        bytes_per_row: Some(self.row_bytes),
                        rows_per_image: Some(self.height),
                    },
                },
                extent,
            );
        }
    }

    /// Waits for the submitted copy, maps the buffer and unpacks one view into each output.
    pub(super) fn read(&self, device: &wgpu::Device, out: &mut [ViewOut<'_>]) -> Result<(), RenderError> {
        let end = self.info_offset + self.layer_bytes * out.len() as u64;
        read_mapped(device, &self.buffer.slice(..end), |data| {
            for (i, o) in out.iter_mut().enumerate() {
                let color = &data[i * self.layer_bytes as usize..];
                let info = &data[(self.info_offset + i as u64 * self.layer_bytes) as usize..];
                unpack_view(color, info, self.row_bytes as usize, self.width as usize, self.height as usize, o);
            }
        })
    }
}

/// Waits for the device's submissions, maps `slice` for reading, hands its bytes to `f` and
/// unmaps it.
pub(super) fn read_mapped<T>(
    device: &wgpu::Device,
    slice: &wgpu::BufferSlice<'_>,
    f: impl FnOnce(&[u8]) -> T,
) -> Result<T, RenderError> {
    let (tx, rx) = mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| RenderError::Readback(e.to_string()))?;
    match rx.try_recv() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(RenderError::Readback(e.to_string())),
        Err(_) => return Err(RenderError::Readback("the map callback did not run".into())),
    }
    let out = {
        let data = slice.get_mapped_range().map_err(|e| RenderError::Readback(e.to_string()))?;
        f(&data)
    };
    slice.buffer().unmap();
    Ok(out)
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
