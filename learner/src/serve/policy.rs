//! What the policy server asks of a policy ([`Policy`]): one action per env of a round's
//! [`WorkerBatch`]. PPO (`crate::serve::ppo_policy`) plugs in here the same way as the two
//! baselines below.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schema::action;

use crate::serve::batch::WorkerBatch;

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
    /// Into how many groups of workers (contiguous blocks, taken in turn) the next rounds may be
    /// split, so that one group renders while the next is inferred; 1: the next round is for
    /// every worker. Only for a policy that wants full batches.
    fn groups_now(&self) -> usize {
        1
    }
    /// Seconds of [`Policy::act`] spent learning rather than acting (PPO updates, checkpoints,
    /// curves), cumulative; the training profile tells the two apart with it.
    fn learning_seconds(&self) -> f64 {
        0.0
    }
    /// Acting and updates by stage, cumulative, when the policy times them (PPO training with
    /// `--profile-stages`).
    fn stage_times(&self) -> Option<farm::profile::StageTimes> {
        None
    }
    /// Sees each progress record the server writes (the farm's counters), e.g. to log them
    /// beside its own metrics.
    fn report(&mut self, _progress: &farm::progress::Progress) -> anyhow::Result<()> {
        Ok(())
    }
    /// The run is ending; `checkpoint` says whether to save state first (Ctrl-C: yes).
    fn finish(&mut self, _checkpoint: bool) -> anyhow::Result<()> {
        Ok(())
    }
}

/// Uniformly random actions (the Random baseline of T4.2), each drawn from the run's seed and
/// its env's place and step, never from a stream shared by the workers: workers answered as
/// they send arrive in an order timing decides, which made one shared stream's evaluations
/// differ between identical runs (0.7% and 0.4% SR at the first stop).
pub struct RandomPolicy {
    seed: u64,
}

impl RandomPolicy {
    pub fn new(seed: u64) -> RandomPolicy {
        RandomPolicy { seed }
    }
}

/// The Random baseline's action for worker `worker`'s env `env` at its `env_step`-th observation.
fn random_action(seed: u64, worker: u32, env: usize, env_step: u64) -> u8 {
    let mut rng: ChaCha8Rng = farm::seed::rng(seed, &[0x5EED_A7C7, worker as u64, env as u64, env_step]);
    rng.random_range(0..action::COUNT as u8)
}

impl Policy for RandomPolicy {
    fn name(&self) -> &str {
        "random"
    }

    fn act(&mut self, batch: &WorkerBatch<'_>) -> anyhow::Result<Vec<u8>> {
        Ok(batch.envs().map(|(w, e, r)| random_action(self.seed, w, e, r.env_step)).collect())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Random's action depends on the env and its step alone (not on which workers share a
    /// batch, or in what order), and is uniform over the actions.
    #[test]
    fn random_actions_are_a_function_of_the_env_and_its_step() {
        let mut counts = [0usize; action::COUNT];
        for w in 0..4u32 {
            for step in 0..500u64 {
                let a = random_action(7, w, 3, step);
                assert_eq!(a, random_action(7, w, 3, step));
                counts[a as usize] += 1;
            }
        }
        let expected = 2000 / action::COUNT;
        assert!(counts.iter().all(|&c| c.abs_diff(expected) < expected / 5), "{counts:?}");
        let other_seed = (0..100).filter(|&s| random_action(7, 0, 0, s) != random_action(8, 0, 0, s)).count();
        assert!(other_seed > 50, "another seed, other actions ({other_seed} of 100 differ)");
    }
}
