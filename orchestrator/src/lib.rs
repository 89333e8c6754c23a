//! The orchestrator of GesTHOR-RS as a library: what its commands draw and compute, run
//! directories, process supervision and the farm (learner + workers), testable apart from the
//! CLI in `main.rs`.
//!
//! A folder per job: `commands` (one module per subcommand), `supervise` (the processes of a
//! run), `report` (tables, charts, maps, progress), `remote` (worker hosts over Zenoh). A new
//! subcommand is one module in `commands` and one variant in `main.rs`.

pub mod commands;
pub mod remote;
pub mod report;
pub mod supervise;
