//! Where the network runs: CPU or CUDA, chosen from the config (`device = "auto" | "cpu" | "cuda"`).
//!
//! The binary links libtorch with `--as-needed`, so only `libtorch_cpu` and `libc10` are loaded at
//! start; torch's CUDA backend registers itself when `libtorch_cuda.so` is loaded. Call
//! [`load_cuda_backend`] first thing in `main`, before any CUDA query: it `dlopen`s the CUDA
//! library from the directory the CPU library was loaded from. On a machine without a GPU (or
//! with a CPU-only libtorch) it fails harmlessly and everything runs on the CPU.

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use farm::config::Device as DeviceChoice;
use tch::Device;

/// What happened when we tried to load torch's CUDA backend.
#[derive(Clone, Debug)]
pub enum CudaBackend {
    /// `libtorch_cuda.so` was loaded from this path.
    Loaded(PathBuf),
    /// It could not be loaded; why, for the device report.
    Unavailable(String),
}

static BACKEND: OnceLock<CudaBackend> = OnceLock::new();

/// Held while torch's one global generator is seeded and drawn from.
static SEEDED: Mutex<()> = Mutex::new(());

/// Runs `init` (building variables) right after `tch::manual_seed(seed)`, with no other thread
/// of the process seeding or initialising through this function in between: torch has one
/// global generator, and without this, networks built at once by two threads (the test
/// harness) would get each other's draws.
pub fn seeded<R>(seed: i64, init: impl FnOnce() -> R) -> R {
    let _held = SEEDED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    tch::manual_seed(seed);
    init()
}

/// Loads `libtorch_cuda.so` (RTLD_GLOBAL) from beside the loaded `libtorch_cpu.so`, once per
/// process. Safe to call many times and on machines without CUDA.
pub fn load_cuda_backend() -> &'static CudaBackend {
    BACKEND.get_or_init(|| {
        // libtorch_cpu is a DT_NEEDED of anything using tch, so it is mapped already; this call
        // touches it without asking torch about CUDA (torch caches its first CUDA answer).
        let _ = tch::get_num_threads();
        let mut tried = Vec::new();
        for dir in candidate_dirs() {
            let lib = dir.join("libtorch_cuda.so");
            if !lib.exists() {
                tried.push(format!("{}: not there", lib.display()));
                continue;
            }
            match dlopen_global(&lib) {
                Ok(()) => return CudaBackend::Loaded(lib),
                Err(e) => tried.push(format!("{}: {e}", lib.display())),
            }
        }
        CudaBackend::Unavailable(if tried.is_empty() { "no libtorch directory found".into() } else { tried.join("; ") })
    })
}

/// Directories that may hold `libtorch_cuda.so`: the one `libtorch_cpu.so` was loaded from
/// (read from /proc/self/maps), then `$LIBTORCH/lib`, then the build-time libtorch.
fn candidate_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    if let Ok(maps) = std::fs::read_to_string("/proc/self/maps") {
        for line in maps.lines() {
            if let Some(path) = line.split_whitespace().nth(5)
                && path.ends_with("/libtorch_cpu.so")
                && let Some(dir) = Path::new(path).parent()
            {
                dirs.push(dir.to_path_buf());
                break;
            }
        }
    }
    if let Ok(root) = std::env::var("LIBTORCH") {
        dirs.push(Path::new(&root).join("lib"));
    }
    let built = env!("GESTHOR_LIBTORCH_LIB");
    if !built.is_empty() {
        dirs.push(PathBuf::from(built));
    }
    dirs.dedup();
    dirs
}

fn dlopen_global(lib: &Path) -> Result<(), String> {
    let c = CString::new(lib.as_os_str().as_encoded_bytes()).map_err(|e| e.to_string())?;
    // SAFETY: dlopen with a valid C string; the handle is deliberately leaked (the library must
    // stay loaded for the life of the process).
    let handle = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) };
    if handle.is_null() {
        // SAFETY: dlerror returns a thread-local C string or null.
        let err = unsafe { libc::dlerror() };
        let msg = if err.is_null() {
            "dlopen failed".to_string()
        } else {
            unsafe { std::ffi::CStr::from_ptr(err) }.to_string_lossy().into_owned()
        };
        return Err(msg);
    }
    Ok(())
}

#[derive(Debug, thiserror::Error)]
#[error("device = \"cuda\" was asked for, but no CUDA device is available ({0})")]
pub struct NoCuda(String);

/// The device for a config's choice: `auto` = CUDA when a GPU is usable, else CPU.
pub fn select(choice: DeviceChoice) -> Result<Device, NoCuda> {
    let backend = load_cuda_backend();
    let cuda = tch::Cuda::is_available();
    match choice {
        DeviceChoice::Cpu => Ok(Device::Cpu),
        DeviceChoice::Auto => Ok(if cuda { Device::Cuda(0) } else { Device::Cpu }),
        DeviceChoice::Cuda if cuda => Ok(Device::Cuda(0)),
        DeviceChoice::Cuda => Err(NoCuda(match backend {
            CudaBackend::Loaded(p) => format!("{} loaded but torch sees no GPU", p.display()),
            CudaBackend::Unavailable(why) => why.clone(),
        })),
    }
}

/// torch's CPU threads when the network runs on a GPU, unless `OMP_NUM_THREADS` says otherwise.
/// The host's share of the work is small there, and torch's pool spins between its parallel
/// sections on cores the workers render with, which slows the updates (docs/bench/log.md, "On
/// the H100").
pub const GPU_CPU_THREADS: i32 = 2;

/// Prepares a device for work: on CUDA, cuDNN autotuning (our shapes are fixed per run) and
/// [`GPU_CPU_THREADS`] CPU threads.
pub fn configure(device: Device) {
    if device.is_cuda() {
        tch::Cuda::cudnn_set_benchmark(true);
        if std::env::var_os("OMP_NUM_THREADS").is_none() {
            tch::set_num_threads(GPU_CPU_THREADS);
        }
    }
}

/// Whether bf16 runs of the frozen encoder pay off here: only on CUDA (CPU bf16 convolutions are
/// slower than f32 on the machines we target).
pub fn use_bf16(device: Device, mixed_precision: bool) -> bool {
    mixed_precision && device.is_cuda()
}

/// Flushes denormal floats to zero on this thread's CPU (x86-64 MXCSR FTZ + DAZ), as
/// `torch.set_flush_denormal(True)`. Once a policy becomes nearly deterministic, its gradients and
/// Adam's moments drift into denormals, which run tens of times slower on x86 CPUs. Threads inherit the setting when created, so call it before
/// torch starts its thread pool; harmless elsewhere.
pub fn flush_denormals() {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: reads and writes this thread's SSE control register; only the FTZ (bit 15) and
    // DAZ (bit 6) flags change, which every x86-64 CPU supports.
    unsafe {
        let mut csr: u32 = 0;
        std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
        csr |= (1 << 15) | (1 << 6);
        std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack));
    }
}

/// Keeps freed memory in the process instead of handing it back to the kernel at once. Acting
/// and PPO allocate and free the same megabyte-sized tensors at every step; glibc serves blocks
/// over 128 KiB with their own mapping and unmaps them when freed (its threshold adapts only up
/// to the largest block freed so far), so steps page-fault and zero them in again. Raising the
/// mapping threshold to glibc's maximum (32 MiB) and the trim threshold keeps them in the heap;
/// the learner's resident memory then stays near its peak. (docs/bench/log.md, "Training speed".)
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; called at start, before other threads.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}

/// One-paragraph report: torch build, CUDA backend, devices, threads.
pub fn report(device: Device) -> String {
    let backend = match load_cuda_backend() {
        CudaBackend::Loaded(p) => format!("CUDA backend loaded from {}", p.display()),
        CudaBackend::Unavailable(why) => format!("CUDA backend not loaded ({why})"),
    };
    let gpus = if tch::Cuda::is_available() {
        format!("{} CUDA device(s), cuDNN {}", tch::Cuda::device_count(), tch::Cuda::cudnn_is_available())
    } else {
        "no CUDA device".to_string()
    };
    format!("device {device:?}; {backend}; {gpus}; {} CPU threads for torch", tch::get_num_threads())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_is_always_available_and_auto_falls_back() {
        assert_eq!(select(DeviceChoice::Cpu).unwrap(), Device::Cpu);
        let auto = select(DeviceChoice::Auto).unwrap();
        if tch::Cuda::is_available() {
            assert!(auto.is_cuda());
        } else {
            assert_eq!(auto, Device::Cpu);
            let err = select(DeviceChoice::Cuda).unwrap_err().to_string();
            assert!(err.contains("no CUDA device"), "{err}");
            eprintln!("no GPU here: CUDA selection checked for its error only ({err})");
        }
        assert!(report(auto).contains("device"));
    }
}
