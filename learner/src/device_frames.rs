//! Frames read in place from a worker's exported memory (`env.frames = "device"`, issue 52).
//!
//! A worker renders its envs' frames into memory it exports once as a file descriptor
//! ([`farm::frame_socket`]); the learner imports it here and reads the slots a batch needs. On a
//! GPU the import goes through the CUDA driver API (the memory never leaves the card); on the CPU
//! (Mesa's lavapipe exports a memfd it maps itself) the descriptor is simply mapped. Either way
//! [`ImportedFrames::rgb`], [`ImportedFrames::depth`] and [`ImportedFrames::ids`] return copies
//! owned by the learner, so that the worker may overwrite its slots once they are made (on a GPU:
//! once [`ImportedFrames::finish_copies`] returns, the copies being queued on torch's stream).
//!
//! The layout is [`DeviceFrameLayout`]'s: slot `s`'s RGBA8 colour at `s × layer_bytes` (rows of
//! `row_bytes`), its `depth16 << 16 | id` u32 words at `info_offset + s × layer_bytes`.

use std::fs::File;
use std::os::fd::OwnedFd;

use memmap2::{Mmap, MmapOptions};
use shm_schema::DeviceFrameLayout;
use tch::{Device, Kind, Tensor};

/// What can go wrong importing a worker's frame memory; each names what was found and expected.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("device frame layout is inconsistent ({0}): {1:?}")]
    Layout(&'static str, DeviceFrameLayout),
    #[error("reading the size of the worker's frame memory (fstat): {0}")]
    Stat(std::io::Error),
    #[error("the worker's frame memory holds {have} bytes, its layout needs {need}")]
    TooShort { have: u64, need: u64 },
    #[error("mapping the worker's frame memory ({size} bytes): {source}")]
    Map { size: u64, source: std::io::Error },
    #[error("device frames can be imported on the CPU or a CUDA device, not on {0:?}")]
    UnsupportedDevice(Device),
    #[error(
        "device frames on {0:?} need the CUDA driver library (libcuda.so.1), which could not be loaded: is the NVIDIA driver installed and on the loader path?"
    )]
    NoCudaDriver(Device),
    #[error("CUDA device index {0} is out of range")]
    BadOrdinal(usize),
    #[error("{call} failed: {code}")]
    Cuda { call: &'static str, code: String },
    #[error("the CUDA driver library lacks a call this build uses (driver too old?): {0}")]
    CudaSymbol(String),
    #[error(
        "the worker rendered on GPU {worker} but CUDA device {ordinal} is GPU {cuda}: the learner and the worker must use the same card"
    )]
    UuidMismatch { ordinal: usize, cuda: String, worker: String },
}

/// One worker's imported frame memory; it unmaps (or frees its CUDA mapping) when dropped.
pub struct ImportedFrames {
    memory: Memory,
    layout: DeviceFrameLayout,
    device: Device,
}

enum Memory {
    Host(Mmap),
    Cuda(cuda::Mapped),
}

impl std::fmt::Debug for ImportedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImportedFrames").field("layout", &self.layout).field("device", &self.device).finish()
    }
}

impl ImportedFrames {
    /// Imports the memory behind `fd`, laid out as `layout`, for reading on `device`. On a CUDA
    /// device, `device_uuid` (the worker's Vulkan device) must be that device's UUID; on success
    /// CUDA owns the descriptor. On the CPU the memory is mapped read-only and the UUID is not
    /// checked (the CPU driver's memory is host memory).
    pub fn import(
        fd: OwnedFd,
        layout: DeviceFrameLayout,
        device_uuid: [u8; 16],
        device: Device,
    ) -> Result<ImportedFrames, ImportError> {
        check_layout(&layout)?;
        let memory = match device {
            Device::Cpu => Memory::Host(map_host(fd, layout.size)?),
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
            Memory::Host(map) => map.as_ptr(),
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

/// Maps `fd` read-only and shared, after checking that it holds `size` bytes (mapping past a
/// file's end would give SIGBUS on the first read, not an error).
fn map_host(fd: OwnedFd, size: u64) -> Result<Mmap, ImportError> {
    let file = File::from(fd);
    let have = file.metadata().map_err(ImportError::Stat)?.len();
    if have < size {
        return Err(ImportError::TooShort { have, need: size });
    }
    // SAFETY: the worker writes this memory while it is mapped, so no Rust reference to its
    // bytes is ever made: only torch reads them, through the raw base pointer, into copies. The
    // file's length was checked above; the mapping keeps the memory after `file` closes.
    unsafe { MmapOptions::new().len(size as usize).map(&file) }.map_err(|source| ImportError::Map { size, source })
}

/// The CUDA driver API side: libcuda is loaded at run time (cudarc's dynamic loading), so the
/// learner builds and runs without it.
mod cuda {
    use std::ffi::c_int;
    use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};
    use std::panic::{AssertUnwindSafe, catch_unwind};

    use cudarc::driver::sys;
    use tch::Device;

    use super::ImportError;

    /// An imported external memory, mapped as one buffer at `ptr`, holding a reference on its
    /// device's primary context (the one libtorch's runtime API uses, so torch can read `ptr`).
    pub(super) struct Mapped {
        dev: sys::CUdevice,
        ctx: sys::CUcontext,
        ext: sys::CUexternalMemory,
        pub(super) ptr: sys::CUdeviceptr,
    }

    // SAFETY: driver handles are valid on any thread of the process; `drop` makes the context
    // current on its own thread before freeing.
    unsafe impl Send for Mapped {}
    // SAFETY: nothing mutates through `&Mapped`; readers only launch torch kernels on `ptr`.
    unsafe impl Sync for Mapped {}

    fn check(call: &'static str, r: sys::CUresult) -> Result<(), ImportError> {
        match r {
            sys::CUresult::CUDA_SUCCESS => Ok(()),
            _ => Err(ImportError::Cuda { call, code: format!("{r:?} ({})", r as u32) }),
        }
    }

    fn hex(b: &[u8; 16]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    impl Mapped {
        pub(super) fn import(fd: OwnedFd, size: u64, uuid: [u8; 16], ordinal: usize) -> Result<Mapped, ImportError> {
            // SAFETY: only tries to open the library (and closes it); runs no CUDA code. Without
            // this check cudarc panics at the first call.
            if !unsafe { sys::is_culib_present() } {
                return Err(ImportError::NoCudaDriver(Device::Cuda(ordinal)));
            }
            let ordinal_c = c_int::try_from(ordinal).map_err(|_| ImportError::BadOrdinal(ordinal))?;
            // cudarc panics on a symbol the loaded driver lacks: an error here, not a crash.
            catch_unwind(AssertUnwindSafe(|| import_with_driver(fd, size, uuid, ordinal, ordinal_c))).unwrap_or_else(
                |p| {
                    let msg =
                        p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
                    Err(ImportError::CudaSymbol(msg.unwrap_or_else(|| "unknown panic".into())))
                },
            )
        }
    }

    fn import_with_driver(
        fd: OwnedFd,
        size: u64,
        want: [u8; 16],
        ordinal: usize,
        ordinal_c: c_int,
    ) -> Result<Mapped, ImportError> {
        // SAFETY (the whole block): plain driver API calls with out-pointers to locals; every
        // handle is stored in `m` right after it is made, so `Mapped::drop` releases whatever
        // was made when a later step fails.
        unsafe {
            check("cuInit", sys::cuInit(0))?;
            let mut dev: sys::CUdevice = 0;
            check("cuDeviceGet", sys::cuDeviceGet(&mut dev, ordinal_c))?;
            let mut ctx: sys::CUcontext = std::ptr::null_mut();
            check("cuDevicePrimaryCtxRetain", sys::cuDevicePrimaryCtxRetain(&mut ctx, dev))?;
            let mut m = Mapped { dev, ctx, ext: std::ptr::null_mut(), ptr: 0 };
            check("cuCtxSetCurrent", sys::cuCtxSetCurrent(ctx))?;

            let mut id = sys::CUuuid_st { bytes: [0; 16] };
            check("cuDeviceGetUuid_v2", sys::cuDeviceGetUuid_v2(&mut id, dev))?;
            let have: [u8; 16] = id.bytes.map(|b| b as u8);
            if have != want {
                return Err(ImportError::UuidMismatch { ordinal, cuda: hex(&have), worker: hex(&want) });
            }

            let desc = sys::CUDA_EXTERNAL_MEMORY_HANDLE_DESC {
                type_: sys::CUexternalMemoryHandleType::CU_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD,
                handle: sys::CUDA_EXTERNAL_MEMORY_HANDLE_DESC_st__bindgen_ty_1 { fd: fd.as_raw_fd() },
                size,
                flags: 0,
                reserved: [0; 16],
            };
            let mut ext: sys::CUexternalMemory = std::ptr::null_mut();
            // On failure `fd` is dropped, closing it; on success the driver owns it.
            check("cuImportExternalMemory", sys::cuImportExternalMemory(&mut ext, &desc))?;
            let _owned_by_cuda = fd.into_raw_fd();
            m.ext = ext;

            let buf = sys::CUDA_EXTERNAL_MEMORY_BUFFER_DESC { offset: 0, size, flags: 0, reserved: [0; 16] };
            let mut ptr: sys::CUdeviceptr = 0;
            check("cuExternalMemoryGetMappedBuffer", sys::cuExternalMemoryGetMappedBuffer(&mut ptr, ext, &buf))?;
            m.ptr = ptr;
            Ok(m)
        }
    }

    impl Drop for Mapped {
        fn drop(&mut self) {
            // SAFETY: the handles were made by `import_with_driver` and are released once, in the
            // order the driver asks (mapped buffer, external memory, context reference). The
            // synchronize lets copies still queued from `ptr` finish first.
            let steps = unsafe {
                let mut steps = vec![("cuCtxSetCurrent", sys::cuCtxSetCurrent(self.ctx))];
                if self.ptr != 0 {
                    steps.push(("cuCtxSynchronize", sys::cuCtxSynchronize()));
                    steps.push(("cuMemFree_v2", sys::cuMemFree_v2(self.ptr)));
                }
                if !self.ext.is_null() {
                    steps.push(("cuDestroyExternalMemory", sys::cuDestroyExternalMemory(self.ext)));
                }
                steps.push(("cuDevicePrimaryCtxRelease_v2", sys::cuDevicePrimaryCtxRelease_v2(self.dev)));
                steps
            };
            for (call, r) in steps {
                if let Err(e) = check(call, r) {
                    tracing::warn!("releasing imported device frames: {e}");
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::os::fd::AsFd;
    use std::os::unix::fs::FileExt;

    use nix::sys::memfd::{MFdFlags, memfd_create};

    use super::*;

    /// 40 × 24 (rows of 160 bytes padded to 256), 3 slots.
    fn layout() -> DeviceFrameLayout {
        let l = DeviceFrameLayout::new(3, 40, 24);
        assert_eq!(l.row_bytes, 256);
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

    /// A memfd laid out as `layout()`, padding bytes 0xEE (they must never show).
    fn frames_fd(len: u64) -> File {
        let l = layout();
        let mut bytes = vec![0xEEu8; l.size as usize];
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
        let f = File::from(memfd_create("device-frames-test", MFdFlags::MFD_CLOEXEC).unwrap());
        f.set_len(len).unwrap();
        f.write_all_at(&bytes[..len.min(l.size) as usize], 0).unwrap();
        f
    }

    fn import(f: &File, device: Device) -> Result<ImportedFrames, ImportError> {
        ImportedFrames::import(f.as_fd().try_clone_to_owned().unwrap(), layout(), [0; 16], device)
    }

    #[test]
    fn slots_read_back_exactly_in_the_order_asked() {
        let f = frames_fd(layout().size);
        let frames = import(&f, Device::Cpu).unwrap();
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

        // What was returned is the learner's copy: the worker may write its slot again.
        let before = rgb.copy();
        f.write_all_at(&[0u8; 64], 2 * layout().layer_bytes).unwrap();
        assert!(rgb.equal(&before));
        assert_eq!(u8::try_from(&frames.rgb(&[2]).get(0).get(0).get(0).get(0)).unwrap(), 0);
    }

    #[test]
    fn memory_shorter_than_its_layout_is_refused() {
        let need = layout().size;
        let e = import(&frames_fd(need - 1), Device::Cpu).unwrap_err();
        assert!(matches!(e, ImportError::TooShort { .. }), "{e}");
        let text = e.to_string();
        assert!(text.contains(&(need - 1).to_string()) && text.contains(&need.to_string()), "{text}");
    }

    #[test]
    fn an_inconsistent_layout_is_refused() {
        let f = frames_fd(layout().size);
        let mut l = layout();
        l.row_bytes = 100;
        let e = ImportedFrames::import(f.as_fd().try_clone_to_owned().unwrap(), l, [0; 16], Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("row_bytes"), "{e}");
        let mut l = layout();
        l.size -= 4;
        let e = ImportedFrames::import(f.as_fd().try_clone_to_owned().unwrap(), l, [0; 16], Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("info layers"), "{e}");
    }

    #[test]
    #[should_panic(expected = "slot 3 asked for")]
    fn a_slot_out_of_range_panics_with_its_number() {
        let f = frames_fd(layout().size);
        let _ = import(&f, Device::Cpu).unwrap().rgb(&[0, 3]);
    }

    /// Where CUDA cannot run, asking for it is an error, never a panic. (The CUDA import itself
    /// is tested on a GPU machine: CUDA cannot import a memfd.)
    #[test]
    fn cuda_without_a_usable_gpu_is_an_error() {
        crate::device::load_cuda_backend();
        if tch::Cuda::is_available() {
            return;
        }
        let f = frames_fd(layout().size);
        let e = import(&f, Device::Cuda(0)).unwrap_err();
        assert!(matches!(e, ImportError::NoCudaDriver(_) | ImportError::Cuda { .. }), "{e}");
    }
}
