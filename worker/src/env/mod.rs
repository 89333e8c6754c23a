//! The environment: composes scene, physics, nav, task, render, humanoid and gesture into
//! episodes, and the pool of environments a worker steps.
//!
//! - `episode`: one [`Env`], a program run in its room;
//! - `schedule`: what the robot perceives when ([`gesture_kind`]);
//! - `rooms`: the room cache envs share ([`Rooms`]);
//! - `pool`: the [`EnvPool`] of E envs and one renderer: program assignment, reset and step,
//!   and the observation written into a payload (shared memory in the worker process).
//!
//! Episode protocol (see `shm_schema`): when an episode ends, the next observation is its
//! final one (terminated/truncated set); the action answered to it is ignored and the env
//! starts a new episode, whose first observation carries `episode_start` and reward 0.

mod episode;
mod pool;
mod rooms;
mod schedule;

pub use episode::Env;
pub use pool::{EnvPool, PoolSpec, ProgramSource, eligible_programs};
pub use rooms::Rooms;
pub use schedule::{gesture_kind, shown};
