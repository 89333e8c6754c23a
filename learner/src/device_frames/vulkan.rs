//! A worker's exported frame memory imported through Vulkan and mapped for the host: how the
//! learner reads frames kept "on the device" when the device is a CPU rasteriser (lavapipe, in
//! CI), where CUDA cannot import them. The import follows the rules for an opaque fd: the same
//! physical device (its UUID), the exporter's allocation size and memory type, dedicated to a
//! buffer like the exporter's.

use std::os::fd::{IntoRawFd, OwnedFd};

use ash::vk;

use super::error::hex;

const HANDLE: vk::ExternalMemoryHandleTypeFlags = vk::ExternalMemoryHandleTypeFlags::OPAQUE_FD;
const HOST: vk::MemoryPropertyFlags = vk::MemoryPropertyFlags::from_raw(
    vk::MemoryPropertyFlags::HOST_VISIBLE.as_raw() | vk::MemoryPropertyFlags::HOST_COHERENT.as_raw(),
);

/// The imported memory, mapped; unmapped and freed on drop.
pub(crate) struct VulkanMapping {
    vk: Vk,
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    ptr: *const u8,
}

// SAFETY: the mapping is read through `ptr` only (by torch, into copies); the handles are used
// again only on drop.
unsafe impl Send for VulkanMapping {}
unsafe impl Sync for VulkanMapping {}

impl VulkanMapping {
    /// Imports `fd` (`size` bytes of memory type `memory_type`, exported by the device with
    /// `device_uuid`) and maps it. Vulkan owns `fd` from a successful import on.
    pub(crate) fn import(
        fd: OwnedFd,
        size: u64,
        memory_type: u32,
        device_uuid: [u8; 16],
    ) -> Result<VulkanMapping, String> {
        let vk = Vk::open(Some(device_uuid))?;
        let flags = vk.memory_flags(memory_type);
        if !flags.is_some_and(|f| f.contains(HOST)) {
            return Err(format!(
                "memory type {memory_type} of the frames is not mapped coherently for the host ({flags:?}): a GPU's frames are imported with CUDA"
            ));
        }
        let mut mapping =
            VulkanMapping { buffer: vk::Buffer::null(), memory: vk::DeviceMemory::null(), ptr: std::ptr::null(), vk };
        // from here `mapping`'s drop releases whatever was made
        mapping.buffer = mapping.vk.buffer(size)?;
        let raw_fd = fd.into_raw_fd();
        let mut import = vk::ImportMemoryFdInfoKHR::default().handle_type(HANDLE).fd(raw_fd);
        let mut dedicated = vk::MemoryDedicatedAllocateInfo::default().buffer(mapping.buffer);
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(size)
            .memory_type_index(memory_type)
            .push_next(&mut import)
            .push_next(&mut dedicated);
        // SAFETY: valid chained info for this device; on failure the fd is still ours to close.
        mapping.memory = match unsafe { mapping.vk.device.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                unsafe { libc::close(raw_fd) };
                return Err(format!(
                    "importing the frames' fd (vkAllocateMemory, {size} bytes, type {memory_type}): {e}"
                ));
            }
        };
        mapping.ptr = mapping.vk.bind_and_map(mapping.buffer, mapping.memory)?;
        Ok(mapping)
    }

    /// The mapped memory's first byte; valid while `self` lives.
    pub(crate) fn ptr(&self) -> *const u8 {
        self.ptr
    }
}

impl Drop for VulkanMapping {
    fn drop(&mut self) {
        self.vk.release(self.buffer, self.memory, !self.ptr.is_null());
    }
}

/// A Vulkan instance and a device with `VK_KHR_external_memory_fd`; destroyed on drop.
struct Vk {
    _entry: ash::Entry,
    instance: ash::Instance,
    physical: vk::PhysicalDevice,
    device: ash::Device,
}

impl Vk {
    /// The device whose UUID is `uuid` (any device without one).
    fn open(uuid: Option<[u8; 16]>) -> Result<Vk, String> {
        // SAFETY: loading the system's Vulkan loader; the instance and device are destroyed on
        // drop, or below on the error paths that follow them.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| format!("no Vulkan loader: {e}"))?;
        let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_1);
        let instance =
            unsafe { entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None) }
                .map_err(|e| format!("vkCreateInstance: {e}"))?;
        let physical = match find_device(&instance, uuid) {
            Ok(p) => p,
            Err(e) => {
                unsafe { instance.destroy_instance(None) };
                return Err(e);
            }
        };
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(0).queue_priorities(&priorities)];
        let extensions = [ash::khr::external_memory_fd::NAME.as_ptr()];
        let create = vk::DeviceCreateInfo::default().queue_create_infos(&queues).enabled_extension_names(&extensions);
        match unsafe { instance.create_device(physical, &create, None) } {
            Ok(device) => Ok(Vk { _entry: entry, instance, physical, device }),
            Err(e) => {
                unsafe { instance.destroy_instance(None) };
                Err(format!("vkCreateDevice with VK_KHR_external_memory_fd: {e}"))
            }
        }
    }

    fn memory_flags(&self, memory_type: u32) -> Option<vk::MemoryPropertyFlags> {
        let types = unsafe { self.instance.get_physical_device_memory_properties(self.physical) };
        (memory_type < types.memory_type_count).then(|| types.memory_types[memory_type as usize].property_flags)
    }

    /// A buffer of `size` bytes whose memory may be external (an opaque fd).
    fn buffer(&self, size: u64) -> Result<vk::Buffer, String> {
        let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE);
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC)
            .push_next(&mut external);
        unsafe { self.device.create_buffer(&info, None) }.map_err(|e| format!("vkCreateBuffer: {e}"))
    }

    fn bind_and_map(&self, buffer: vk::Buffer, memory: vk::DeviceMemory) -> Result<*const u8, String> {
        // SAFETY: both were made on this device; the memory is host visible (checked by callers).
        unsafe { self.device.bind_buffer_memory(buffer, memory, 0) }.map_err(|e| format!("vkBindBufferMemory: {e}"))?;
        let ptr = unsafe { self.device.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty()) }
            .map_err(|e| format!("vkMapMemory: {e}"))?;
        Ok(ptr as *const u8)
    }

    /// Unmaps and frees what a mapping made (null handles are skipped).
    fn release(&self, buffer: vk::Buffer, memory: vk::DeviceMemory, mapped: bool) {
        // SAFETY: each handle was made on this device and nothing reads through the map any more.
        unsafe {
            if mapped {
                self.device.unmap_memory(memory);
            }
            if buffer != vk::Buffer::null() {
                self.device.destroy_buffer(buffer, None);
            }
            if memory != vk::DeviceMemory::null() {
                self.device.free_memory(memory, None);
            }
        }
    }
}

impl Drop for Vk {
    fn drop(&mut self) {
        // SAFETY: everything made on the device was released by its owner's drop first.
        unsafe {
            self.device.destroy_device(None);
            self.instance.destroy_instance(None);
        }
    }
}

/// The physical device whose UUID is `uuid`, or the first one.
fn find_device(instance: &ash::Instance, uuid: Option<[u8; 16]>) -> Result<vk::PhysicalDevice, String> {
    let devices =
        unsafe { instance.enumerate_physical_devices() }.map_err(|e| format!("vkEnumeratePhysicalDevices: {e}"))?;
    let mut seen = Vec::new();
    for d in devices {
        let mut id = vk::PhysicalDeviceIDProperties::default();
        let mut props = vk::PhysicalDeviceProperties2::default().push_next(&mut id);
        unsafe { instance.get_physical_device_properties2(d, &mut props) };
        if uuid.is_none_or(|u| u == id.device_uuid) {
            return Ok(d);
        }
        seen.push(hex(&id.device_uuid));
    }
    let wanted = uuid.map_or("any".into(), |u| hex(&u));
    Err(format!("no Vulkan device has the frames' device UUID {wanted} (seen: {})", seen.join(", ")))
}

/// Memory exported the way a worker exports its frames, written through its own mapping: what
/// the learner's tests import.
#[cfg(test)]
pub(crate) struct TestExport {
    vk: Vk,
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    ptr: *mut u8,
    pub size: u64,
    pub memory_type: u32,
    pub uuid: [u8; 16],
}

#[cfg(test)]
impl TestExport {
    /// Exportable host-visible memory of at least `size` bytes on the first Vulkan device.
    pub(crate) fn new(size: u64) -> Result<TestExport, String> {
        let vk = Vk::open(None)?;
        let mut id = vk::PhysicalDeviceIDProperties::default();
        let mut props = vk::PhysicalDeviceProperties2::default().push_next(&mut id);
        unsafe { vk.instance.get_physical_device_properties2(vk.physical, &mut props) };
        let uuid = id.device_uuid;
        let buffer = vk.buffer(size)?;
        let req = unsafe { vk.device.get_buffer_memory_requirements(buffer) };
        let Some(memory_type) = (0..32)
            .find(|&t| req.memory_type_bits & (1 << t) != 0 && vk.memory_flags(t).is_some_and(|f| f.contains(HOST)))
        else {
            vk.release(buffer, vk::DeviceMemory::null(), false);
            return Err("no host-visible memory type".into());
        };
        let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE);
        let mut dedicated = vk::MemoryDedicatedAllocateInfo::default().buffer(buffer);
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(memory_type)
            .push_next(&mut export)
            .push_next(&mut dedicated);
        let memory =
            unsafe { vk.device.allocate_memory(&alloc, None) }.map_err(|e| format!("vkAllocateMemory: {e}"))?;
        let ptr = vk.bind_and_map(buffer, memory)? as *mut u8;
        Ok(TestExport { vk, buffer, memory, ptr, size: req.size, memory_type, uuid })
    }

    /// As [`TestExport::new`], or None (said) on a machine without Vulkan — a failure where CI or
    /// scripts/setup.sh says an adapter must be there (`CI`, `GESTHOR_ADAPTER_REQUIRED`).
    pub(crate) fn new_or_skip(size: u64) -> Option<TestExport> {
        match TestExport::new(size) {
            Ok(e) => Some(e),
            Err(e) => {
                let required = ["CI", "GESTHOR_ADAPTER_REQUIRED"]
                    .iter()
                    .any(|k| std::env::var(k).is_ok_and(|v| !v.is_empty() && v != "0" && v != "false"));
                assert!(!required, "{e}, but CI or scripts/setup.sh installs lavapipe");
                eprintln!("skipped: {e}");
                None
            }
        }
    }

    /// A new descriptor of the memory, as a worker hands it over.
    pub(crate) fn fd(&self) -> OwnedFd {
        use std::os::fd::FromRawFd;
        let info = vk::MemoryGetFdInfoKHR::default().memory(self.memory).handle_type(HANDLE);
        let loader = ash::khr::external_memory_fd::Device::new(&self.vk.instance, &self.vk.device);
        let fd = unsafe { loader.get_memory_fd(&info) }.expect("vkGetMemoryFdKHR");
        unsafe { OwnedFd::from_raw_fd(fd) }
    }

    /// Writes `bytes` at `offset`, as the worker's device would.
    pub(crate) fn write(&self, offset: u64, bytes: &[u8]) {
        assert!(offset + bytes.len() as u64 <= self.size);
        // SAFETY: inside the mapping (checked); the importer only reads.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), self.ptr.add(offset as usize), bytes.len()) };
    }
}

#[cfg(test)]
impl Drop for TestExport {
    fn drop(&mut self) {
        self.vk.release(self.buffer, self.memory, true);
    }
}
