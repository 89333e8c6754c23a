//! What the policy server asks of a policy ([`Policy`]): one action per env of a round's
//! [`WorkerBatch`]. PPO (`crate::ppo_policy`) plugs in here the same way as the two baselines below.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schema::action;

use crate::batch::WorkerBatch;

/// A policy served to the farm.
pub trait Policy {
    /// Short name for logs.
    fn name(&self) -> &str;
    /// One action per env of `batch` (an index of [`shm_schema::action`], §4.2), in the order of
    /// [`WorkerBatch::envs`].
    fn act(&mut self, batch: &WorkerBatch<'_>) -> anyhow::Result<Vec<u8>>;
    /// Whether the server should gather every live worker into one batch before acting (a
    /// network amortises its forward pass over the batch, and PPO's rollout wants every env at
    /// every step). A policy that decides env by env answers each worker as soon as it sends,
    /// so no worker waits for a slower one.
    fn wants_full_batches(&self) -> bool {
        true
    }
    /// Seconds of [`Policy::act`] spent learning rather than acting (PPO updates, checkpoints,
    /// curves), cumulative; the training profile tells the two apart with it.
    fn learning_seconds(&self) -> f64 {
        0.0
    }
    /// Sees each progress record the server writes (the farm's counters), e.g. to log them
    /// beside its own metrics.
    fn report(&mut self, _progress: &crate::records::Progress) -> anyhow::Result<()> {
        Ok(())
    }
    /// The run is ending; `checkpoint` says whether to save state first (Ctrl-C: yes).
    fn finish(&mut self, _checkpoint: bool) -> anyhow::Result<()> {
        Ok(())
    }
}

/// Uniformly random actions from a seeded stream (the Random baseline of T4.2).
pub struct RandomPolicy {
    rng: ChaCha8Rng,
}

impl RandomPolicy {
    pub fn new(seed: u64) -> RandomPolicy {
        RandomPolicy { rng: farm::seed::rng(seed, &[0x5EED_A7C7]) }
    }
}

impl Policy for RandomPolicy {
    fn name(&self) -> &str {
        "random"
    }

    fn act(&mut self, batch: &WorkerBatch<'_>) -> anyhow::Result<Vec<u8>> {
        Ok((0..batch.num_envs()).map(|_| self.rng.random_range(0..action::COUNT as u8)).collect())
    }

    fn wants_full_batches(&self) -> bool {
        false
    }
}

/// Echoes the shortest-path expert's action the workers compute (`worker --expert-hints`):
/// an upper reference for navigation, and a check that actions reach the right env.
pub struct ExpertPolicy;

impl Policy for ExpertPolicy {
    fn name(&self) -> &str {
        "expert"
    }

    fn wants_full_batches(&self) -> bool {
        false
    }

    fn act(&mut self, batch: &WorkerBatch<'_>) -> anyhow::Result<Vec<u8>> {
        batch
            .envs()
            .map(|(w, e, r)| match r.expert_action {
                a if (a as usize) < action::COUNT => Ok(a),
                // No expert from a final observation or an idle env: the worker ignores the
                // action answered to those.
                _ if r.idle != 0 || r.terminated != 0 || r.truncated != 0 => Ok(0),
                a => anyhow::bail!(
                    "worker {w} env {e}: no expert action ({a}); the workers must run with --expert-hints"
                ),
            })
            .collect()
    }
}
