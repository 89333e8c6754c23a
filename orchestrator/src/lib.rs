//! The orchestrator's library side: what its commands draw and compute, testable apart from
//! the CLI in `main.rs`.

pub mod bench_sim;
pub mod dataset_cmd;
pub mod fonts;
pub mod map;
pub mod plot;
pub mod program_cmd;
pub mod render_cmd;
pub mod tables;
