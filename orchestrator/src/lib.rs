//! The orchestrator of GesTHOR-RS as a library: run directories, process supervision, the farm
//! (learner + workers) and the commands built on it. `main.rs` maps subcommands onto these.
//!
//! A new subcommand is one module here (`pub mod eval;`) and one variant in `main.rs`.

pub mod bench;
pub mod bench_farm;
pub mod binaries;
pub mod farm;
pub mod run_dir;
pub mod supervise;
pub mod up;
