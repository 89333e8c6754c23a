//! PPO (§4.3.1–§4.3.2, Algorithm 1, T4.1), lowest layer first:
//!
//! - [`gesture_table`]: the rollout's gestures, each distinct one stored once;
//! - [`rollout`]: the rollout storage, T steps × N envs, filled one step at a time;
//! - [`optim`]: Adam with its state in plain tensors, so checkpoints can carry it;
//! - [`update`]: the PPO update of one full rollout: GAE, the losses, the epochs;
//! - [`overlap`]: that update on a thread beside acting (`ppo.overlap_update`);
//! - [`trainer`]: the [`trainer::Trainer`]: each step's feedback, learning and acting;
//! - [`checkpoint`]: the agent's variables and the trainer's state in one safetensors file.

pub mod checkpoint;
pub mod gesture_table;
pub mod optim;
pub(crate) mod overlap;
pub mod rollout;
pub mod trainer;
pub mod update;
