//! The farm's policy server, lowest layer first:
//!
//! - [`batch`]: one round of the workers' messages, read in place ([`batch::WorkerBatch`]);
//! - [`integrity`]: the checks every arriving observation passes (a pure function);
//! - [`policy`]: what the server asks of a policy ([`policy::Policy`]), and the random and expert
//!   baselines;
//! - [`frames`]: the frames workers keep in GPU memory, handed over and imported (`env.frames =
//!   "device"`);
//! - [`ppo_policy`]: PPO served to the farm, training or evaluating;
//! - [`server`]: the serve loop ([`server::serve`]);
//! - [`pipe`]: one env's policy over a pipe, for a person watching (`learner act`).

pub mod batch;
pub mod frames;
pub mod integrity;
pub mod pipe;
pub mod policy;
pub mod ppo_policy;
pub mod server;
