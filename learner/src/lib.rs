//! The GesTHOR-RS learner: the dissertation's policy network (§4.3.3) and PPO (§4.3.1–4.3.2,
//! T4.1) on libtorch through tch.
//!
//! The farm calls, per step message of N envs (see [`obs`] for the step protocol):
//! ```text
//! let mut trainer = Trainer::new(&cfg, n_envs, device)?;      // or checkpoint::resume_trainer(..)
//! loop {
//!     let out = trainer.step(&env_batch)?;                     // feedback in, actions out
//!     send(out.actions.actions);
//!     if let Some(m) = out.update { log.append(&m)?; /* every K: checkpoint::save_in_dir */ }
//! }
//! ```
//! Evaluation uses an [`Agent`] alone: `checkpoint::load_agent`, then `act_deterministic`.
//!
//! The farm side: [`serve`] is the policy server (batches the workers' observations, read in
//! place from shared memory through [`transport`] and [`batch`]), and [`policy::Policy`] is
//! what it asks of a policy.
//!
//! Layers, each using only those before it: observations ([`obs`]) → network spec ([`spec`]) →
//! input preparation ([`inputs`]) → layers ([`layers`], [`resnet`]) → network ([`network`]) →
//! acting agent ([`agent`]) → rollout ([`rollout`]) → PPO ([`ppo`]) → checkpoints
//! ([`checkpoint`]) → policies served to the farm ([`policy`], [`ppo_policy`]) → the serve loop
//! ([`serve`], beside it [`integrity`], [`records`] and [`transport`]) → the binary.

pub mod agent;
pub mod batch;
pub mod bench;
pub mod checkpoint;
pub mod device;
pub mod encoder;
pub(crate) mod gesture_memo;
pub mod gesture_table;
pub mod inputs;
pub mod integrity;
pub mod layers;
pub mod metrics;
pub mod network;
pub mod obs;
pub mod optim;
pub mod policy;
pub mod ppo;
pub mod ppo_policy;
pub mod pth;
pub mod records;
pub mod resnet;
pub mod rollout;
pub mod serve;
pub mod smoke;
pub mod spec;
pub use farm::learner_ports as transport;

pub use agent::{ActMode, Actions, Agent};
pub use checkpoint::CheckpointError;
pub use metrics::{MetricsLog, UpdateMetrics};
pub use obs::{EnvBatch, EnvStep, FrameView, GestureKind, GestureView};
pub use ppo::{StepOutput, Trainer};
pub use spec::NetSpec;

/// Everything the learner library can fail with; each names what to fix.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error(transparent)]
    Obs(#[from] obs::ObsError),
    #[error(transparent)]
    Agent(#[from] agent::AgentError),
    #[error(transparent)]
    Checkpoint(#[from] checkpoint::CheckpointError),
    #[error(transparent)]
    Device(#[from] device::NoCuda),
    #[error(transparent)]
    Metrics(#[from] metrics::MetricsError),
}

impl From<checkpoint::RestoreError> for LearnerError {
    fn from(e: checkpoint::RestoreError) -> LearnerError {
        match e {
            checkpoint::RestoreError::Build(e) => LearnerError::Agent(e),
            checkpoint::RestoreError::File(e) => LearnerError::Checkpoint(e),
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
        // six methods and T4.7's two variants × (faithful, tiny), and tiny-e2e
        assert!(seen >= 17, "found only {seen} configs under {}", root.display());
    }
}
