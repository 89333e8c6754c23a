//! The subcommands of `orchestrator`, one module each (a subcommand with parts of its own is a
//! folder: `bench`, `encoder`, `eval`, `gesture`, `live`, `study`). Each holds its clap arguments and a `run` that
//! `main.rs` dispatches to; `values` checks the command-line values they share.

pub mod bench;
pub mod dataset;
pub mod encoder;
pub mod eval;
pub mod follow;
pub mod gesture;
pub mod hosts;
pub mod live;
pub mod model;
pub mod program;
pub mod render;
pub mod robot;
pub mod soak;
pub mod study;
pub mod up;
pub mod values;
pub mod workers;
