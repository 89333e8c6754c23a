//! What a run logs in its directory, for people and the orchestrator to read, lowest layer first:
//!
//! - [`records`]: the serve loop's records: `farm.jsonl`, `episodes.jsonl`, `trajectories.jsonl`,
//!   `farm_summary.json`;
//! - [`metrics`]: the training metrics: `metrics.jsonl`, TensorBoard's `tb/`, `curves.png`.
//!
//! Checkpoints are PPO's: `crate::ppo::checkpoint`.

pub mod metrics;
pub mod records;
