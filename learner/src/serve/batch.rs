//! One round of the farm ([`WorkerBatch`]): the observation messages of every worker that answered,
//! in worker order, read in place from the workers' shared-memory samples. What a served
//! `crate::serve::policy::Policy` answers; PPO turns it into the agent's per-env
//! `crate::obs::EnvBatch`.
//!
//! Nothing here copies a frame. The slices handed out point into the samples the learner holds
//! borrowed while the policy runs; **the one copy of a frame happens when a policy turns these
//! slices into its input tensor** (e.g. `Tensor::from_slice`, or `from_blob` followed by
//! `to_device`/`copy_` into rollout storage). The random and expert policies read only the
//! per-env records, so with them no frame byte is copied at all.

use half::f16;
use shm_schema::{EnvRecord, ObsHeader, ObsView};

/// The observation of one worker (E envs), borrowed from its sample.
#[derive(Clone, Copy, Debug)]
pub struct WorkerObs<'a> {
    pub worker: u32,
    pub generation: u32,
    /// This is the first observation of a new worker process (a restart): its envs start fresh,
    /// so any recurrent state kept for them must be reset.
    pub new_generation: bool,
    pub header: &'a ObsHeader,
    pub view: ObsView<'a>,
}

impl<'a> WorkerObs<'a> {
    pub fn num_envs(&self) -> usize {
        self.view.shape().num_envs
    }

    pub fn records(&self) -> &'a [EnvRecord] {
        self.view.records()
    }

    /// `[E, H, W, 3]` u8.
    pub fn rgb(&self) -> &'a [u8] {
        self.view.rgb_all()
    }

    /// `[E, H, W]` u16, linear 0..10 m → 0..65535.
    pub fn depth(&self) -> &'a [u16] {
        self.view.depth_all()
    }

    /// `[E, 100, 95]` half floats.
    pub fn gesture(&self) -> &'a [f16] {
        as_f16(self.view.gesture_bits_all())
    }
}

/// Half floats read in place from their bit patterns (the payload's gesture section).
pub fn as_f16(bits: &[u16]) -> &[f16] {
    // SAFETY: `f16` is a transparent wrapper of its u16 bit pattern (same size, alignment,
    // and every bit pattern is a valid f16).
    unsafe { std::slice::from_raw_parts(bits.as_ptr() as *const f16, bits.len()) }
}

/// Every worker that answered this round, in worker order.
#[derive(Debug)]
pub struct WorkerBatch<'a> {
    pub width: usize,
    pub height: usize,
    /// The workers this round is for: all of them, or one group (`ppo.env_groups`).
    pub workers: std::ops::Range<usize>,
    pub parts: Vec<WorkerObs<'a>>,
    /// Workers that have been seen but did not answer in time (dead, restarting or slow); their
    /// envs are not in this batch.
    pub missing: Vec<u32>,
}

impl<'a> WorkerBatch<'a> {
    /// Envs in the batch (the length of the action vector a policy returns).
    pub fn num_envs(&self) -> usize {
        self.parts.iter().map(|p| p.num_envs()).sum()
    }

    /// `(worker, env, record)` for every env of the batch, in action order.
    pub fn envs(&self) -> impl Iterator<Item = (u32, usize, &'a EnvRecord)> + '_ {
        self.parts.iter().flat_map(|p| p.records().iter().enumerate().map(move |(e, r)| (p.worker, e, r)))
    }
}
