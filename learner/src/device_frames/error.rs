//! What can go wrong importing a worker's frame memory.

use shm_schema::DeviceFrameLayout;
use tch::Device;

/// What can go wrong importing a worker's frame memory; each names what was found and expected.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("device frame layout is inconsistent ({0}): {1:?}")]
    Layout(&'static str, DeviceFrameLayout),
    #[error("importing the worker's frame memory through Vulkan: {0}")]
    Vulkan(String),
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

/// A device UUID as the errors print it: 32 lowercase hex digits.
pub(super) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
