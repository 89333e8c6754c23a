//! Input preparation: an observation batch (`EnvBatch`) becomes the network's input tensors, in
//! the form the rollout stores them ([`Inputs`]).
//!
//! Frames and gestures are read in place from the batch's buffers with `from_blob` (shared memory,
//! in the farm) and copied once: onto the GPU, or into the rollout storage. On the CPU with one
//! frame group no host copy is made at all, so [`Prepared`] carries the batch's lifetime. Frames
//! and gestures bound for a GPU pass through page-locked [`Staging`] buffers instead (one DMA
//! for all groups; `learner bench --faithful` times both ways for the frames).

use std::sync::Mutex;

use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES};
use tch::{Device, Kind, Tensor};

use crate::obs::{EnvBatch, FrameView, GestureKind, GestureView};

/// The network's inputs in the form the rollout keeps them, leading dims `[B]` or `[T, B]`.
#[derive(Debug)]
pub struct Inputs {
    /// Raw u8 `[.., H, W, 3]`, or frozen conv5 features `[.., 512, h, w]`.
    pub rgb: Option<Tensor>,
    /// Raw 16-bit depth patterns in Int16 `[.., H, W]`, or frozen conv5 features.
    pub depth: Option<Tensor>,
    /// Features of the frozen early-fusion RGB-D encoder, f32 `[.., 64, H/8, W/8]` (in place of
    /// `rgb` and `depth` with `model.encoder = "pretrained"`).
    pub visual: Option<Tensor>,
    /// Half `[.., 100, 95]`, zero where no gesture is shown — or, with `gesture_index`, the
    /// distinct gestures `[G, 100, 95]` the rows show.
    pub gesture: Option<Tensor>,
    /// Which row of `gesture` each row shows, i64 `[..]`. A gesture changes only at an episode's
    /// start and when intervention switches, so the rollout stores each distinct one once and a
    /// minibatch of 128 steps × 16 envs encodes a few dozen gestures instead of 2,048.
    pub gesture_index: Option<Tensor>,
    /// Target index, i64 `[..]`.
    pub target: Option<Tensor>,
    /// f32 `[.., 3]`.
    pub pose: Option<Tensor>,
}

impl Inputs {
    /// Applies `f` to every per-row field (the leading dims); a table of distinct gestures is
    /// not per row and stays as it is.
    pub fn map(&self, f: impl Fn(&Tensor) -> Tensor) -> Inputs {
        let indexed = self.gesture_index.is_some();
        Inputs {
            rgb: self.rgb.as_ref().map(&f),
            depth: self.depth.as_ref().map(&f),
            visual: self.visual.as_ref().map(&f),
            gesture: self.gesture.as_ref().map(|g| if indexed { g.shallow_clone() } else { f(g) }),
            gesture_index: self.gesture_index.as_ref().map(&f),
            target: self.target.as_ref().map(&f),
            pose: self.pose.as_ref().map(&f),
        }
    }

    /// The per-row fields (leading dims `[B]` or `[T, B]`), by name.
    pub fn fields(&self) -> [(&'static str, Option<&Tensor>); 7] {
        [
            ("rgb", self.rgb.as_ref()),
            ("depth", self.depth.as_ref()),
            ("visual", self.visual.as_ref()),
            ("gesture", self.gesture.as_ref().filter(|_| self.gesture_index.is_none())),
            ("gesture_index", self.gesture_index.as_ref()),
            ("target", self.target.as_ref()),
            ("pose", self.pose.as_ref()),
        ]
    }

    /// No inputs at all (the Random baseline's).
    pub fn none() -> Inputs {
        Inputs { rgb: None, depth: None, visual: None, gesture: None, gesture_index: None, target: None, pose: None }
    }
}

/// One step's inputs, which on the CPU may read the observation batch's buffers in place (no
/// host copy): they live no longer than those buffers (`'a`). The rollout copies them.
#[derive(Debug)]
pub(crate) struct Prepared<'a> {
    pub inputs: Inputs,
    _buffers: std::marker::PhantomData<&'a [u8]>,
}

impl<'a> Prepared<'a> {
    /// `inputs` made from `batch`: they may borrow its buffers, so they take its lifetime.
    pub(crate) fn new(inputs: Inputs, _batch: &EnvBatch<'a>) -> Prepared<'a> {
        Prepared { inputs, _buffers: std::marker::PhantomData }
    }
}

impl std::ops::Deref for Prepared<'_> {
    type Target = Inputs;
    fn deref(&self) -> &Inputs {
        &self.inputs
    }
}

/// RGB u8 `[B, H, W, 3]` → f32 `[B, 3, H, W]` in 0..1.
pub fn rgb_unit(raw: &Tensor) -> Tensor {
    raw.permute([0, 3, 1, 2]).to_kind(Kind::Float) / 255.0
}

/// Depth as Int16 bit patterns `[B, H, W]` → f32 `[B, 1, H, W]` in 0..1 (0..10 m).
pub fn depth_unit(raw: &Tensor) -> Tensor {
    (raw.to_kind(Kind::Int).bitwise_and(0xFFFF).to_kind(Kind::Float) / 65535.0).unsqueeze(1)
}

/// Page-locked host buffers for the frames and gestures on their way to a GPU, one per field,
/// kept from batch to batch at the largest batch seen (allocated again when a frame's shape
/// changes). A copy from pageable memory — the workers' shared memory — goes through the
/// driver's own small bounce buffer piece by piece; from pinned memory it is one DMA per field,
/// after one host copy into it (several threads, [`copy_rows`]).
#[derive(Debug, Default)]
pub(crate) struct Staging {
    rgb: Mutex<Option<Tensor>>,
    depth: Mutex<Option<Tensor>>,
    gesture: Mutex<Option<Tensor>>,
}

impl Staging {
    /// The batch's RGB on `device`: through the pinned buffer on a GPU, else as [`rgb_tensor`].
    pub(crate) fn rgb(&self, obs: &EnvBatch, device: Device) -> Tensor {
        rgb_gather(obs, device, Some(&self.rgb))
    }

    /// The batch's depth on `device`, as [`Staging::rgb`].
    pub(crate) fn depth(&self, obs: &EnvBatch, device: Device) -> Tensor {
        depth_gather(obs, device, Some(&self.depth))
    }

    /// The batch's gestures on `device`, as [`Staging::rgb`].
    pub(crate) fn gesture(&self, obs: &EnvBatch, device: Device) -> Tensor {
        gesture_gather(obs, device, Some(&self.gesture))
    }
}

/// RGB as one u8 tensor `[N, H, W, 3]` on `device` (see `gather` for when it is a copy).
pub(crate) fn rgb_tensor(obs: &EnvBatch, device: Device) -> Tensor {
    rgb_gather(obs, device, None)
}

fn rgb_gather(obs: &EnvBatch, device: Device, pinned: Option<&Mutex<Option<Tensor>>>) -> Tensor {
    // (may alias the batch's buffer, see `gather`)
    let (h, w) = (obs.height as i64, obs.width as i64);
    gather(obs, device, pinned, |f| match f.device.filter(|d| d.rgb) {
        Some(d) => d.frames.rgb(&slots(f.envs)),
        // SAFETY: `EnvBatch::validate` checked the slice holds E*H*W*3 bytes; the tensor lives no longer
        // than the batch's buffers (`Prepared<'a>`), or is copied (`to_device`, `cat`).
        None => unsafe { Tensor::from_blob(f.rgb.as_ptr(), &[f.envs as i64, h, w, 3], &[], Kind::Uint8, Device::Cpu) },
    })
}

/// Depth as raw 16-bit patterns in an Int16 tensor `[N, H, W]` (torch has no u16; the model
/// reinterprets the bits).
pub(crate) fn depth_tensor(obs: &EnvBatch, device: Device) -> Tensor {
    depth_gather(obs, device, None)
}

fn depth_gather(obs: &EnvBatch, device: Device, pinned: Option<&Mutex<Option<Tensor>>>) -> Tensor {
    let (h, w) = (obs.height as i64, obs.width as i64);
    gather(obs, device, pinned, |f| match f.device.filter(|d| d.depth) {
        Some(d) => d.frames.depth(&slots(f.envs)),
        // SAFETY: as for rgb; u16 and i16 have the same size and alignment.
        None => unsafe {
            Tensor::from_blob(f.depth.as_ptr() as *const u8, &[f.envs as i64, h, w], &[], Kind::Int16, Device::Cpu)
        },
    })
}

/// The slots of a group's envs in its worker's exported frames.
fn slots(envs: usize) -> Vec<i64> {
    (0..envs as i64).collect()
}

/// Gestures `[N, 100, 95]` in half precision on `device`.
fn gesture_gather(obs: &EnvBatch, device: Device, pinned: Option<&Mutex<Option<Tensor>>>) -> Tensor {
    let shape = |e: usize| [e as i64, GESTURE_FRAMES as i64, GESTURE_DIMS as i64];
    let t = gather(obs, device, pinned, |f| match f.gesture {
        // SAFETY: as for rgb.
        GestureView::F16(s) => unsafe {
            Tensor::from_blob(s.as_ptr() as *const u8, &shape(f.envs), &[], Kind::Half, Device::Cpu)
        },
        GestureView::F32(s) => {
            unsafe { Tensor::from_blob(s.as_ptr() as *const u8, &shape(f.envs), &[], Kind::Float, Device::Cpu) }
                .to_kind(Kind::Half)
        }
    });
    t.to_kind(Kind::Half)
}

/// Per-env gesture mask (1 where a gesture is shown), `[N]` f32.
pub(crate) fn gesture_mask(obs: &EnvBatch, device: Device) -> Tensor {
    let m: Vec<f32> =
        obs.envs.iter().map(|e| if e.gesture == GestureKind::None || e.lost { 0.0 } else { 1.0 }).collect();
    Tensor::from_slice(&m).to_device(device)
}

pub(crate) fn target_tensor(obs: &EnvBatch, device: Device) -> Tensor {
    let t: Vec<i64> = obs.envs.iter().map(|e| if e.lost { 0 } else { e.target }).collect();
    Tensor::from_slice(&t).to_device(device)
}

pub(crate) fn pose_tensor(obs: &EnvBatch, device: Device) -> Tensor {
    let p: Vec<f32> = obs.envs.iter().flat_map(|e| e.person_pose).collect();
    Tensor::from_slice(&p).view([obs.n() as i64, 3]).to_device(device)
}

/// Values a frame of the per-frame gesture network reads of the person's pose ([`frame_pose`]).
pub(crate) const FRAME_POSE_DIMS: i64 = 4;

/// The person's pose ([`pose_tensor`], `[B, 3]`) as the per-frame gesture network reads it
/// beside every frame, `[B, FRAME_POSE_DIMS]`: right, forward, and the cosine and sine of their facing relative
/// to the robot (the pose input's yaw / 360 is a fraction of a turn) — rounded to half precision,
/// as the gestures are stored.
pub(crate) fn frame_pose(p: &Tensor) -> Tensor {
    let turn = p.select(1, 2) * std::f64::consts::TAU;
    let pose = Tensor::stack(&[p.select(1, 0), p.select(1, 1), turn.cos(), turn.sin()], 1);
    pose.to_kind(Kind::Half).to_kind(Kind::Float)
}

/// One tensor for all groups: on the GPU a copy (through `pinned` when given); on the CPU with
/// one group, the caller's buffer itself (no host copy) — hence [`Prepared`] carries the batch's
/// lifetime.
fn gather(
    obs: &EnvBatch,
    device: Device,
    pinned: Option<&Mutex<Option<Tensor>>>,
    view: impl Fn(&FrameView) -> Tensor,
) -> Tensor {
    let parts: Vec<Tensor> = obs.frames.iter().filter(|f| f.envs > 0).map(view).collect();
    // frames imported from the workers' GPU memory are on the device already
    let on_host = parts.iter().all(|p| p.device() == Device::Cpu);
    match pinned {
        Some(slot) if device.is_cuda() && on_host => {
            let mut shape = parts[0].size();
            shape[0] = parts.iter().map(|p| p.size()[0]).sum();
            let kind = parts[0].kind();
            let mut slot = slot.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            // kept at the largest batch seen: rounds of one group of envs and of all alternate
            let fits = slot
                .as_ref()
                .is_some_and(|b| b.size()[1..] == shape[1..] && b.kind() == kind && b.size()[0] >= shape[0]);
            if !fits {
                *slot = Some(Tensor::empty(shape.as_slice(), (kind, Device::Cpu)).pin_memory(device));
            }
            let buffer = slot.as_ref().expect("allocated above").narrow(0, 0, shape[0]);
            copy_rows(&parts, &buffer);
            // a blocking copy: the buffer is free again for the next batch when this returns
            buffer.to_device(device)
        }
        _ => {
            let mut parts: Vec<Tensor> = parts.into_iter().map(|t| t.to_device(device)).collect();
            if parts.len() == 1 { parts.pop().unwrap() } else { Tensor::cat(&parts, 0) }
        }
    }
}

/// Copies `parts` (contiguous, on the host) one after another into the rows of `buffer`, several
/// threads at once: one thread's memcpy moves a fraction of what the memory bus can, and a round
/// of 512 envs at 224² is 128 MB.
fn copy_rows(parts: &[Tensor], buffer: &Tensor) {
    let size = buffer.kind().elt_size_in_bytes();
    let mut at = buffer.data_ptr() as usize;
    let mut jobs = Vec::with_capacity(parts.len());
    for p in parts {
        assert!(p.is_contiguous() && p.kind() == buffer.kind(), "a frame group is contiguous and of the buffer's kind");
        let bytes = p.numel() * size;
        jobs.push((p.data_ptr() as usize, at, bytes));
        at += bytes;
    }
    assert!(at <= buffer.data_ptr() as usize + buffer.numel() * size, "the buffer holds every part");
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(8).min(jobs.len()).max(1);
    std::thread::scope(|s| {
        for chunk in jobs.chunks(jobs.len().div_ceil(threads)) {
            s.spawn(move || {
                for &(src, dst, bytes) in chunk {
                    // SAFETY: each source is a live contiguous tensor of `bytes` bytes (`parts`
                    // outlives the scope); the destinations are disjoint ranges inside `buffer`,
                    // checked above, and nothing else touches the buffer meanwhile (its slot's
                    // lock is held).
                    unsafe { std::ptr::copy_nonoverlapping(src as *const u8, dst as *mut u8, bytes) };
                }
            });
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::obs::OwnedObs;
    use half::f16;

    #[test]
    fn groups_gather_to_the_same_tensors_and_depth_bits_survive() {
        let mut o = OwnedObs::new(5, 4, 6);
        for (i, v) in o.rgb.iter_mut().enumerate() {
            *v = (i % 251) as u8;
        }
        for (i, v) in o.depth.iter_mut().enumerate() {
            *v = (i as u16).wrapping_mul(1031).wrapping_add(40000);
        }
        for (i, v) in o.gesture.iter_mut().enumerate() {
            *v = f16::from_f32((i % 7) as f32 * 0.25);
        }
        let one = o.batch();
        let many = o.batch_grouped(2);
        one.validate(5, (4, 6)).unwrap();
        many.validate(5, (4, 6)).unwrap();
        assert!(rgb_tensor(&one, Device::Cpu).equal(&rgb_tensor(&many, Device::Cpu)));
        let staging = Staging::default();
        assert!(staging.gesture(&one, Device::Cpu).equal(&staging.gesture(&many, Device::Cpu)));
        // the pinned staging's host copy, on a plain buffer: groups land one after another
        let parts = [rgb_tensor(&o.batch_of(0..2), Device::Cpu), rgb_tensor(&o.batch_of(2..5), Device::Cpu)];
        let buffer = Tensor::zeros([6, 4, 6, 3], (Kind::Uint8, Device::Cpu));
        copy_rows(&parts, &buffer);
        assert!(buffer.narrow(0, 0, 5).equal(&rgb_tensor(&one, Device::Cpu)));
        assert_eq!(buffer.get(5).count_nonzero(None).int64_value(&[]), 0, "a row past the batch was written");
        let d = depth_tensor(&many, Device::Cpu);
        assert_eq!(d.size(), vec![5, 4, 6]);
        // u16 patterns come back from the Int16 view
        let back = depth_unit(&d).view([-1]);
        let got = back.double_value(&[7]);
        assert!((got - o.depth[7] as f64 / 65535.0).abs() < 1e-6, "{got}");
    }
}
