//! Frames read in place from a worker's exported memory (`env.frames = "device"`).
//!
//! A worker renders its envs' frames into memory it exports once as a file descriptor
//! ([`farm::frame_socket`]); the learner imports it here and reads the slots a batch needs. On a
//! GPU the import goes through the CUDA driver API (`cuda`: the memory never leaves the card); on
//! the CPU (Mesa's lavapipe, in CI) through Vulkan, mapped for the host (`vulkan`). Either way
//! [`ImportedFrames::rgb`], [`ImportedFrames::depth`] and [`ImportedFrames::ids`] return copies
//! owned by the learner, so that the worker may overwrite its slots once they are made (on a GPU:
//! once [`ImportedFrames::finish_copies`] returns, the copies being queued on torch's stream).
//!
//! The layout is [`DeviceFrameLayout`]'s: slot `s`'s RGBA8 colour at `s × layer_bytes` (rows of
//! `row_bytes`), its `depth16 << 16 | id` u32 words at `info_offset + s × layer_bytes`.

use std::os::fd::OwnedFd;

use shm_schema::DeviceFrameLayout;
use tch::{Device, Kind, Tensor};

/// One worker's imported frame memory; it unmaps (or frees its CUDA mapping) when dropped.
pub struct ImportedFrames {
    memory: Memory,
    layout: DeviceFrameLayout,
    device: Device,
}

enum Memory {
    // boxed: a Vulkan device's function tables are large
    Host(Box<vulkan::VulkanMapping>),
    Cuda(cuda::Mapped),
}

impl std::fmt::Debug for ImportedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImportedFrames").field("layout", &self.layout).field("device", &self.device).finish()
    }
}

impl ImportedFrames {
    /// Imports the memory behind `fd`, laid out as `layout` (`layout.size`: the exporter's
    /// allocation), for reading on `device`. `device_uuid` (the worker's Vulkan device) must be
    /// the CUDA device's UUID, or on the CPU a Vulkan device's whose memory type `memory_type`
    /// the host can map (lavapipe's); on success CUDA or Vulkan owns the descriptor.
    pub fn import(
        fd: OwnedFd,
        layout: DeviceFrameLayout,
        device_uuid: [u8; 16],
        memory_type: u32,
        device: Device,
    ) -> Result<ImportedFrames, ImportError> {
        check_layout(&layout)?;
        let memory = match device {
            Device::Cpu => {
                let mapping = vulkan::VulkanMapping::import(fd, layout.size, memory_type, device_uuid);
                Memory::Host(Box::new(mapping.map_err(ImportError::Vulkan)?))
            }
            Device::Cuda(ordinal) => Memory::Cuda(cuda::Mapped::import(fd, layout.size, device_uuid, ordinal)?),
            other => return Err(ImportError::UnsupportedDevice(other)),
        };
        Ok(ImportedFrames { memory, layout, device })
    }

    pub fn layout(&self) -> &DeviceFrameLayout {
        &self.layout
    }

    pub fn device(&self) -> Device {
        self.device
    }

    /// RGB u8 `[N, H, W, 3]` of `slots`, in that order, on the import's device (alpha dropped).
    ///
    /// Panics if a slot is out of range (a bad index would be a device-side assert on a GPU,
    /// which poisons the whole CUDA context).
    pub fn rgb(&self, slots: &[i64]) -> Tensor {
        let l = &self.layout;
        let (h, w) = (l.height as i64, l.width as i64);
        // SAFETY: `check_layout` and the import checked that `slots × layer_bytes` bytes from the
        // base lie inside the mapping (every row ends within its layer). The mapping lives as
        // long as `self`, and the view does not outlive this call: `index_select` makes the copy
        // that is returned. torch only reads the view (the host mapping is read-only).
        let all = unsafe {
            Tensor::from_blob(
                self.base(),
                &[l.slots as i64, h, w, 3],
                &[l.layer_bytes as i64, l.row_bytes as i64, 4, 1],
                Kind::Uint8,
                self.device,
            )
        };
        all.index_select(0, &self.index(slots)).contiguous()
    }

    /// Depth `[N, H, W]` as Int16 bit patterns (depth 0..10 m → 0..65535, values from 32768 on
    /// negative), exactly as the shared-memory path hands its u16 depth to
    /// [`crate::inputs::depth_unit`].
    pub fn depth(&self, slots: &[i64]) -> Tensor {
        // An arithmetic shift of the word read as i32 gives the high half sign-extended: the very
        // Int16 value of those 16 bits, so the conversion below never has to wrap.
        self.info(slots).bitwise_right_shift_tensor_scalar(16).to_kind(Kind::Int16)
    }

    /// Object ids `[N, H, W]` Int32 (the low 16 bits of each info word), for tests and checks.
    pub fn ids(&self, slots: &[i64]) -> Tensor {
        self.info(slots).bitwise_and(0xFFFF)
    }

    /// Blocks until the copies queued so far (by [`ImportedFrames::rgb`] and the others) are
    /// done, after which the worker may overwrite the slots they read. On the CPU they are done
    /// when made.
    pub fn finish_copies(&self) {
        if let Device::Cuda(i) = self.device {
            tch::Cuda::synchronize(i as i64);
        }
    }

    /// The info words of `slots`, Int32 `[N, H, W]`, a copy.
    fn info(&self, slots: &[i64]) -> Tensor {
        let l = &self.layout;
        let (h, w) = (l.height as i64, l.width as i64);
        // SAFETY: as in `rgb`; the info layers start `info_offset` in, which `check_layout` keeps
        // 4-byte aligned (as layer_bytes and row_bytes, so every word is aligned; the mapping's
        // base is page aligned) with `slots × layer_bytes` bytes after it inside the mapping.
        let all = unsafe {
            Tensor::from_blob(
                self.base().add(l.info_offset as usize),
                &[l.slots as i64, h, w],
                &[l.layer_bytes as i64 / 4, l.row_bytes as i64 / 4, 1],
                Kind::Int,
                self.device,
            )
        };
        all.index_select(0, &self.index(slots))
    }

    fn base(&self) -> *const u8 {
        match &self.memory {
            Memory::Host(map) => map.ptr(),
            Memory::Cuda(mapped) => mapped.ptr as *const u8,
        }
    }

    fn index(&self, slots: &[i64]) -> Tensor {
        let n = self.layout.slots as i64;
        if let Some(bad) = slots.iter().find(|&&s| !(0..n).contains(&s)) {
            panic!("device frames: slot {bad} asked for, the worker's memory holds slots 0..{n}");
        }
        Tensor::from_slice(slots).to_device(self.device)
    }
}

/// Every view `rgb` and `info` make must lie inside `size` bytes and be aligned for its kind: the
/// layout comes from another process, and a wrong one must be an error, not a stray read.
fn check_layout(l: &DeviceFrameLayout) -> Result<(), ImportError> {
    let bad = |why| Err(ImportError::Layout(why, *l));
    let (slots, width, height) = (l.slots as u128, l.width as u128, l.height as u128);
    let (row, layer, info, size) = (l.row_bytes as u128, l.layer_bytes as u128, l.info_offset as u128, l.size as u128);
    if slots == 0 || width == 0 || height == 0 {
        return bad("no pixels");
    }
    if row < width * 4 || row % 4 != 0 {
        return bad("row_bytes must hold width × 4 bytes and be a multiple of 4");
    }
    if layer < row * height || layer % 4 != 0 {
        return bad("layer_bytes must hold height rows and be a multiple of 4");
    }
    if info < layer * slots || info % 4 != 0 {
        return bad("info_offset must follow the colour layers and be a multiple of 4");
    }
    if size < info + layer * slots {
        return bad("size must hold the info layers");
    }
    if size > isize::MAX as u128 {
        return bad("size is beyond this machine's address space");
    }
    Ok(())
}

mod cuda;
mod error;
mod vulkan;

pub use error::ImportError;
#[cfg(test)]
pub(crate) use vulkan::TestExport;

#[cfg(test)]
mod tests {
    use super::vulkan::TestExport;
    use super::*;

    /// 40 × 24 (rows of 160 bytes padded to 256), 3 slots, in memory of `size` bytes.
    fn layout(size: u64) -> DeviceFrameLayout {
        let mut l = DeviceFrameLayout::new(3, 40, 24);
        assert_eq!(l.row_bytes, 256);
        l.size = size;
        l
    }

    fn colour(s: usize, y: usize, x: usize) -> [u8; 4] {
        [(s * 50 + x) as u8, (y * 3 + s) as u8, ((x + y) * 5) as u8, 255]
    }

    /// Slot 2 holds depths from 40000 on: negative as Int16.
    fn depth16(s: usize, y: usize, x: usize) -> u16 {
        (s * 20000 + y * 100 + x) as u16
    }

    fn id(s: usize, y: usize, x: usize) -> u16 {
        (s * 1000 + y * 40 + x) as u16
    }

    /// Memory exported through Vulkan as a worker's (lavapipe here) and laid out as `layout()`,
    /// padding bytes 0xEE (they must never show); None, said, on a machine without Vulkan.
    fn frames() -> Option<TestExport> {
        let l = DeviceFrameLayout::new(3, 40, 24);
        let export = TestExport::new_or_skip(l.size)?;
        let mut bytes = vec![0xEEu8; export.size as usize];
        for s in 0..3 {
            for y in 0..24 {
                for x in 0..40 {
                    let at = s * l.layer_bytes as usize + y * l.row_bytes as usize + x * 4;
                    bytes[at..at + 4].copy_from_slice(&colour(s, y, x));
                    let word = (depth16(s, y, x) as u32) << 16 | id(s, y, x) as u32;
                    let at = l.info_offset as usize + at;
                    bytes[at..at + 4].copy_from_slice(&word.to_le_bytes());
                }
            }
        }
        export.write(0, &bytes);
        Some(export)
    }

    fn import(e: &TestExport, device: Device) -> Result<ImportedFrames, ImportError> {
        ImportedFrames::import(e.fd(), layout(e.size), e.uuid, e.memory_type, device)
    }

    #[test]
    fn slots_read_back_exactly_in_the_order_asked() {
        let Some(export) = frames() else { return };
        let frames = import(&export, Device::Cpu).unwrap();
        let slots = [2i64, 0];
        let rgb = frames.rgb(&slots);
        let (depth, ids) = (frames.depth(&slots), frames.ids(&slots));
        assert_eq!(rgb.size(), [2, 24, 40, 3]);
        assert_eq!((rgb.kind(), depth.kind(), ids.kind()), (Kind::Uint8, Kind::Int16, Kind::Int));
        assert_eq!(depth.size(), [2, 24, 40]);
        assert!(rgb.is_contiguous());

        let pixels = || slots.iter().flat_map(|&s| (0..24).flat_map(move |y| (0..40).map(move |x| (s as usize, y, x))));
        let want_rgb: Vec<u8> = pixels().flat_map(|(s, y, x)| colour(s, y, x)[..3].to_vec()).collect();
        let want_ids: Vec<i32> = pixels().map(|(s, y, x)| id(s, y, x) as i32).collect();
        assert_eq!(Vec::<u8>::try_from(&rgb.flatten(0, -1)).unwrap(), want_rgb);
        assert_eq!(Vec::<i32>::try_from(&ids.flatten(0, -1)).unwrap(), want_ids);

        // The shared-memory path's depth: u16 words seen as Int16 (`inputs::depth_tensor`).
        let want_depth: Vec<u16> = pixels().map(|(s, y, x)| depth16(s, y, x)).collect();
        // SAFETY: `want_depth` outlives the tensor; u16 and i16 have one size and alignment.
        let shm =
            unsafe { Tensor::from_blob(want_depth.as_ptr() as *const u8, &[2, 24, 40], &[], Kind::Int16, Device::Cpu) };
        assert!(depth.equal(&shm));
        let corner = i16::try_from(&depth.get(0).get(23).get(39)).unwrap();
        assert_eq!(corner as u16, depth16(2, 23, 39));
        assert!(corner < 0, "depth {} must arrive as a negative Int16", depth16(2, 23, 39));
        let unit = f64::try_from(crate::inputs::depth_unit(&depth).get(0).get(0).get(23).get(39)).unwrap();
        assert!((unit - depth16(2, 23, 39) as f64 / 65535.0).abs() < 1e-6, "{unit}");

        // What was returned is the learner's copy; the memory itself is shared with the
        // exporter: the worker's next frame shows at the next read.
        let before = rgb.copy();
        export.write(2 * DeviceFrameLayout::new(3, 40, 24).layer_bytes, &[0u8; 64]);
        assert!(rgb.equal(&before));
        assert_eq!(u8::try_from(&frames.rgb(&[2]).get(0).get(0).get(0).get(0)).unwrap(), 0);
    }

    #[test]
    fn memory_of_another_device_is_refused_with_its_uuid() {
        let Some(export) = frames() else { return };
        let e = ImportedFrames::import(export.fd(), layout(export.size), [0xab; 16], export.memory_type, Device::Cpu)
            .unwrap_err();
        assert!(e.to_string().contains(&"ab".repeat(16)), "{e}");
        let e = ImportedFrames::import(export.fd(), layout(export.size), export.uuid, 99, Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("memory type 99"), "{e}");
    }

    #[test]
    fn an_inconsistent_layout_is_refused() {
        let Some(export) = frames() else { return };
        let mut l = layout(export.size);
        l.row_bytes = 100;
        let e = ImportedFrames::import(export.fd(), l, export.uuid, export.memory_type, Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("row_bytes"), "{e}");
        let mut l = layout(export.size);
        l.size = 2 * l.info_offset - 4;
        let e = ImportedFrames::import(export.fd(), l, export.uuid, export.memory_type, Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("info layers"), "{e}");
    }

    #[test]
    fn a_slot_out_of_range_panics_with_its_number() {
        // skipped (said) only where no Vulkan is installed; CI requires one
        let Some(export) = frames() else { return };
        let frames = import(&export, Device::Cpu).unwrap();
        let panic = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| frames.rgb(&[0, 3]))).unwrap_err();
        let said = panic.downcast_ref::<String>().map(String::as_str).or(panic.downcast_ref::<&str>().copied());
        assert!(said.is_some_and(|m| m.contains("slot 3 asked for")), "{said:?}");
    }

    /// On CUDA, memory exported by the same card reads back as it does on the CPU; memory of
    /// another device (lavapipe's, on a GPU machine) is refused by its UUID; where CUDA cannot
    /// run, asking for it is an error, never a panic. (`scripts/gpu_bench.sh` also trains with
    /// `env.frames = "device"` and fails without the import.)
    #[test]
    fn cuda_reads_its_own_cards_frames_and_refuses_others() {
        crate::device::load_cuda_backend();
        let Some(export) = frames() else { return };
        let cuda = tch::Cuda::is_available();
        match import(&export, Device::Cuda(0)) {
            Ok(on_gpu) => {
                assert!(cuda, "imported on CUDA without CUDA");
                let on_cpu = import(&export, Device::Cpu).unwrap();
                let slots = [2i64, 0];
                assert!(on_gpu.rgb(&slots).to_device(Device::Cpu).equal(&on_cpu.rgb(&slots)));
                assert!(on_gpu.depth(&slots).to_device(Device::Cpu).equal(&on_cpu.depth(&slots)));
                assert!(on_gpu.ids(&slots).to_device(Device::Cpu).equal(&on_cpu.ids(&slots)));
            }
            Err(e) if cuda => assert!(matches!(e, ImportError::UuidMismatch { .. }), "{e}"),
            Err(e) => assert!(matches!(e, ImportError::NoCudaDriver(_) | ImportError::Cuda { .. }), "{e}"),
        }
    }
}
