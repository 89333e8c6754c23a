//! What every process of the rollout farm shares — the worker, the learner and the orchestrator
//! all link this crate, and only the worker (and the orchestrator's in-process commands) link
//! the simulator:
//!
//! - [`config`]: the run configuration (one TOML file read by every role)
//! - [`rooms`]: the 120 rooms by name, scene type and split
//! - [`seed`]: seeded random streams keyed by what they are for
//! - [`process`]: signals and parent-death plumbing of a role's process
//! - [`transport`]: iceoryx2 nodes, services and the worker's serving loop; [`learner_ports`]:
//!   the learner's side of them
//! - [`stepper`]: what a worker drives ([`stepper::Stepper`]) and a synthetic one for tests
//! - [`frame_set`]: labelled RGB-D frames for pretraining the visual encoder
//! - [`frame_socket`]: a worker's exported frame memory handed to the learner (device frames)
//! - [`checkpoints`]: where a run's checkpoints live and how they are named; [`models`]: the
//!   trained policies the repository ships, each in a folder with its card
//! - [`metrics`]: SR, SPL, DTS at k stops, episode results and trajectories
//! - [`progress`]: a run's progress records (`farm.jsonl`), written by the learner
//! - [`profile`]: where a training run's time goes (learner timeline, worker loops)
//! - [`serve_args`]: the learner's command line, typed, for the learner and its starter alike
//! - [`tensorboard`]: TensorBoard event files (scalars, images, text) of a run
//! - [`files`], [`font`]: atomic writes and the one compiled-in font

pub mod checkpoints;
pub mod config;
pub mod files;
pub mod font;
pub mod frame_set;
pub mod frame_socket;
pub mod learner_ports;
pub mod metrics;
pub mod models;
pub mod process;
pub mod profile;
pub mod progress;
pub mod rooms;
pub mod seed;
pub mod serve_args;
pub mod stepper;
pub mod tensorboard;
pub mod transport;
