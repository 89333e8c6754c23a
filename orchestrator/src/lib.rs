//! The orchestrator of GesTHOR-RS as a library: what its commands draw and compute, run
//! directories, process supervision and the farm (learner + workers), testable apart from the
//! CLI in `main.rs`.
//!
//! A new subcommand is one module here (`pub mod eval;`) and one variant in `main.rs`.

pub mod bench;
pub mod bench_farm;
pub mod bench_remote;
pub mod bench_sim;
pub mod bench_train;
pub mod cli_values;
#[path = "commands/dataset.rs"]
pub mod dataset_cmd;
pub mod encoder_cmd;
pub mod encoder_frames;
pub mod eval;
pub mod program_cmd;
pub mod remote;
pub mod report;
pub mod render_cmd;
pub mod soak;
#[path = "commands/study/mod.rs"]
pub mod study;
#[path = "commands/study/summary.rs"]
pub mod study_report;
#[path = "commands/study/ablations.rs"]
pub mod study_tables;
pub mod supervise;
pub mod up;
pub mod workers_cmd;
