//! The CUDA driver API side: libcuda is loaded at run time (cudarc's dynamic loading), so the
//! learner builds and runs without it.

use std::ffi::c_int;
use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};
use std::panic::{AssertUnwindSafe, catch_unwind};

use cudarc::driver::sys;
use tch::Device;

use super::error::{ImportError, hex};

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

impl Mapped {
    pub(super) fn import(fd: OwnedFd, size: u64, uuid: [u8; 16], ordinal: usize) -> Result<Mapped, ImportError> {
        // SAFETY: only tries to open the library (and closes it); runs no CUDA code. Without
        // this check cudarc panics at the first call.
        if !unsafe { sys::is_culib_present() } {
            return Err(ImportError::NoCudaDriver(Device::Cuda(ordinal)));
        }
        let ordinal_c = c_int::try_from(ordinal).map_err(|_| ImportError::BadOrdinal(ordinal))?;
        // cudarc panics on a symbol the loaded driver lacks: an error here, not a crash.
        catch_unwind(AssertUnwindSafe(|| import_with_driver(fd, size, uuid, ordinal, ordinal_c))).unwrap_or_else(|p| {
            let msg = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
            Err(ImportError::CudaSymbol(msg.unwrap_or_else(|| "unknown panic".into())))
        })
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
            // the worker allocates its frame memory dedicated to one buffer (render/export.rs),
            // and CUDA must be told so to import it
            flags: sys::CUDA_EXTERNAL_MEMORY_DEDICATED,
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
