//! Frames kept in GPU memory that another process imports (`env.frames = "device"`): one Vulkan
//! buffer per worker whose memory is exportable as an opaque file descriptor.
//! The renderer copies each view's colour and depth+id layers into the env's slot of it (the
//! layout is [`DeviceFrameLayout`]); the learner imports the descriptor once — CUDA on a GPU,
//! a plain mapping on lavapipe, whose exported memory is a memfd it maps itself — and reads
//! the frames in place, so no frame crosses the host.
//!
//! wgpu has no external-memory API: the buffer is made with ash on wgpu's own Vulkan device
//! (which enables `VK_KHR_external_memory_fd` where the driver has it) and handed to wgpu as
//! a hal buffer, which from then on owns it and its memory.

use std::os::fd::{AsFd, BorrowedFd, FromRawFd, OwnedFd};

use ash::vk;
use shm_schema::DeviceFrameLayout;
use wgpu::hal::api::Vulkan;

use super::error::RenderError;

const HANDLE: vk::ExternalMemoryHandleTypeFlags = vk::ExternalMemoryHandleTypeFlags::OPAQUE_FD;

/// A worker's exported frame memory.
pub struct ExportedFrames {
    pub(super) buffer: wgpu::Buffer,
    fd: OwnedFd,
    layout: DeviceFrameLayout,
    device_uuid: [u8; 16],
    memory_type: u32,
}

impl std::fmt::Debug for ExportedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExportedFrames").field("fd", &self.fd).field("layout", &self.layout).finish()
    }
}

impl ExportedFrames {
    /// Allocates memory for `layout` on `device` (Vulkan only), exportable as an opaque fd;
    /// `layout.size` becomes the allocation's size (an importer must give exactly that).
    pub(super) fn new(device: &wgpu::Device, mut layout: DeviceFrameLayout) -> Result<ExportedFrames, RenderError> {
        let fail = |m: String| RenderError::Export(m);
        // SAFETY: the hal device is only used to create and describe one buffer, which is handed
        // back to wgpu before this function returns; nothing is destroyed behind wgpu's back.
        let hal = unsafe { device.as_hal::<Vulkan>() }
            .ok_or_else(|| fail("frames on the device need the Vulkan backend".into()))?;
        if !hal.enabled_device_extensions().contains(&ash::khr::external_memory_fd::NAME) {
            return Err(fail("the Vulkan driver has no VK_KHR_external_memory_fd".into()));
        }
        let raw = hal.raw_device();
        let instance = hal.shared_instance().raw_instance();
        let physical = hal.raw_physical_device();
        let usage = vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC;

        let info = vk::PhysicalDeviceExternalBufferInfo::default().usage(usage).handle_type(HANDLE);
        let mut props = vk::ExternalBufferProperties::default();
        // SAFETY: plain queries on the device's own physical device.
        unsafe { instance.get_physical_device_external_buffer_properties(physical, &info, &mut props) };
        let features = props.external_memory_properties.external_memory_features;
        if !features.contains(vk::ExternalMemoryFeatureFlags::EXPORTABLE) {
            return Err(fail("the driver cannot export a buffer's memory as an opaque fd".into()));
        }
        let mut id = vk::PhysicalDeviceIDProperties::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut id);
        unsafe { instance.get_physical_device_properties2(physical, &mut props2) };
        let device_uuid = id.device_uuid;
        let memory_types = unsafe { instance.get_physical_device_memory_properties(physical) };

        let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE);
        let create = vk::BufferCreateInfo::default()
            .size(layout.size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .push_next(&mut external);
        // SAFETY: valid create info; the buffer is destroyed below on every error path, and
        // owned by wgpu (with its memory) once wrapped.
        let buffer = unsafe { raw.create_buffer(&create, None) }.map_err(|e| fail(format!("vkCreateBuffer: {e}")))?;
        let req = unsafe { raw.get_buffer_memory_requirements(buffer) };
        let Some(type_index) = memory_type(&memory_types, req.memory_type_bits) else {
            unsafe { raw.destroy_buffer(buffer, None) };
            return Err(fail("no memory type can hold the frames".into()));
        };
        let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE);
        // a dedicated allocation: some drivers export only those (the importer says so: CUDA_EXTERNAL_MEMORY_DEDICATED)
        let mut dedicated = vk::MemoryDedicatedAllocateInfo::default().buffer(buffer);
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(type_index)
            .push_next(&mut export)
            .push_next(&mut dedicated);
        let memory = match unsafe { raw.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                unsafe { raw.destroy_buffer(buffer, None) };
                return Err(fail(format!("vkAllocateMemory of {} bytes: {e}", req.size)));
            }
        };
        let bound = unsafe { raw.bind_buffer_memory(buffer, memory, 0) };
        let fd = bound.and_then(|()| {
            let get = vk::MemoryGetFdInfoKHR::default().memory(memory).handle_type(HANDLE);
            unsafe { ash::khr::external_memory_fd::Device::new(instance, raw).get_memory_fd(&get) }
        });
        let fd = match fd {
            // SAFETY: vkGetMemoryFdKHR hands the caller a new descriptor it owns.
            Ok(fd) => unsafe { OwnedFd::from_raw_fd(fd) },
            Err(e) => {
                unsafe {
                    raw.destroy_buffer(buffer, None);
                    raw.free_memory(memory, None);
                }
                return Err(fail(format!("exporting the frame memory: {e}")));
            }
        };
        // SAFETY: buffer and memory were made on this device, bound, and cover `layout.size`;
        // from here wgpu owns both (it destroys the buffer and frees the memory on drop).
        let hal_buffer = unsafe { wgpu::hal::vulkan::Buffer::from_raw_managed(buffer, memory, 0, req.size) };
        drop(hal);
        layout.size = req.size;
        let buffer = unsafe {
            device.create_buffer_from_hal::<Vulkan>(
                hal_buffer,
                &wgpu::BufferDescriptor {
                    label: Some("exported frames"),
                    size: layout.size,
                    usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                },
            )
        };
        Ok(ExportedFrames { buffer, fd, layout, device_uuid, memory_type: type_index })
    }

    /// The memory's file descriptor, to pass to the importing process (which gets its own).
    pub fn fd(&self) -> BorrowedFd<'_> {
        self.fd.as_fd()
    }

    pub fn layout(&self) -> DeviceFrameLayout {
        self.layout
    }

    /// The Vulkan device's UUID: CUDA's device must have the same one to import the memory.
    pub fn device_uuid(&self) -> [u8; 16] {
        self.device_uuid
    }

    /// The Vulkan memory type the memory was allocated from: a Vulkan importer must use the same.
    pub fn memory_type(&self) -> u32 {
        self.memory_type
    }

    /// Records the copies of target layers `layer..layer + count` into slots `slot..slot +
    /// count` (consecutive slots are consecutive in memory: one copy per target).
    pub(super) fn copy_layers(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        targets: &super::targets::Targets,
        layer: u32,
        slot: u32,
        count: u32,
    ) {
        let l = &self.layout;
        let extent = wgpu::Extent3d { width: l.width, height: l.height, depth_or_array_layers: count };
        let colour = slot as u64 * l.layer_bytes;
        for (texture, offset) in [(&targets.color, colour), (&targets.info, l.info_offset + colour)] {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: layer },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset,
                        bytes_per_row: Some(l.row_bytes),
                        rows_per_image: Some(l.height),
                    },
                },
                extent,
            );
        }
    }
}

/// The memory type for the frames: device-local where the driver offers it (on a GPU that is
/// what CUDA reads fastest; lavapipe's one type is both).
fn memory_type(props: &vk::PhysicalDeviceMemoryProperties, bits: u32) -> Option<u32> {
    let types = &props.memory_types[..props.memory_type_count as usize];
    let allowed = |i: usize| bits & (1 << i) != 0;
    let local = vk::MemoryPropertyFlags::DEVICE_LOCAL;
    (0..types.len())
        .find(|&i| allowed(i) && types[i].property_flags.contains(local))
        .or_else(|| (0..types.len()).find(|&i| allowed(i)))
        .map(|i| i as u32)
}
