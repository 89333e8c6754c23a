//! The GesTHOR-RS learner: the dissertation's policy network (§4.3.3) and PPO (§4.3.1–4.3.2,
//! T4.1) on libtorch through tch.
//!
//! The farm calls, per step message of N envs (see [`obs`] for the step protocol):
//! ```text
//! let mut trainer = Trainer::new(&cfg, n_envs, device)?; // or ppo::checkpoint::resume_trainer(..)
//! loop {
//!     let out = trainer.step(&env_batch)?;                // feedback in, actions out
//!     send(out.actions.actions);
//!     if let Some(m) = out.update { log.append(&m)?; /* every K: ppo::checkpoint::save_in_dir */ }
//! }
//! ```
//! Evaluation uses an [`Agent`] alone: `ppo::checkpoint::load_agent`, then `act` with `ActMode::Greedy`.
//!
//! The farm side: [`serve::server`] is the policy server (batches the workers' observations, read
//! in place from shared memory through [`transport`] and [`serve::batch`]), and
//! [`serve::policy::Policy`] is what it asks of a policy.
//!
//! Layers, each using only those before it (a folder's own are listed in its `mod.rs`):
//! observations ([`obs`]) → input preparation ([`inputs`]) → the pretrained encoder
//! ([`encoder`]) → the network ([`net`]: spec, layers, ResNet, network, acting agent) → what a
//! run logs ([`logs`]: records, metrics) → PPO ([`ppo`]: rollout, Adam, trainer, checkpoints) →
//! the policy server ([`serve`]: worker batches, integrity, policies, the serve loop; beside it
//! [`transport`]) → the binary. Under them all, [`device`] (and [`device_frames`], frames read in
//! place from a worker's exported GPU memory) and [`stages`] (acting and updates timed stage by
//! stage); over net, logs and PPO, the throughput figures ([`bench`]) and the synthetic
//! in-process run ([`smoke`]).

pub mod bench;
pub mod device;
pub mod device_frames;
pub mod encoder;
pub mod inputs;
pub mod logs;
pub mod net;
pub mod obs;
pub mod ppo;
pub mod serve;
pub mod smoke;
pub mod stages;
pub use farm::learner_ports as transport;

pub use logs::metrics::{MetricsLog, UpdateMetrics};
pub use net::agent::{ActMode, Actions, Agent};
pub use net::spec::NetSpec;
pub use obs::{EnvBatch, EnvStep, FrameView, GestureKind, GestureView};
pub use ppo::checkpoint::CheckpointError;
pub use ppo::trainer::{StepOutput, Trainer};

/// Everything the learner library can fail with; each names what to fix.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error(transparent)]
    Obs(#[from] obs::ObsError),
    #[error(transparent)]
    Agent(#[from] net::agent::AgentError),
    #[error(transparent)]
    Checkpoint(#[from] ppo::checkpoint::CheckpointError),
    #[error(transparent)]
    Device(#[from] device::NoCuda),
    #[error(transparent)]
    Metrics(#[from] logs::metrics::MetricsError),
}

impl From<ppo::checkpoint::RestoreError> for LearnerError {
    fn from(e: ppo::checkpoint::RestoreError) -> LearnerError {
        match e {
            ppo::checkpoint::RestoreError::Build(e) => LearnerError::Agent(e),
            ppo::checkpoint::RestoreError::File(e) => LearnerError::Checkpoint(e),
        }
    }
}

#[cfg(test)]
mod config_files {
    use farm::config::RunConfig;

    /// Every TOML file under `configs/` parses and builds a network description.
    #[test]
    fn every_config_file_parses() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let mut stack = vec![root.clone()];
        let mut seen = 0;
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
                let p = entry.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.extension().is_some_and(|e| e == "toml") {
                    let cfg = RunConfig::load(&p).unwrap_or_else(|e| panic!("{e}"));
                    let spec = crate::NetSpec::from_config(&cfg);
                    assert!(spec.input_width() > 0, "{}", p.display());
                    seen += 1;
                }
            }
        }
        // six methods and T4.7's two variants × (faithful, tiny), tiny-e2e, faithful-gpu's three
        assert!(seen >= 20, "found only {seen} configs under {}", root.display());
    }
}
