//! Every workspace-level integration test, as modules of one test binary (`cargo test -p
//! gesthor-tests`; one module's tests: `cargo test -p gesthor-tests farm_runs::`). The heavy,
//! multi-process tests take `gesthor_tests::serial()`, so they run one at a time across modules.

mod capture;
mod cli;
mod dataset;
mod encoder;
// `farm` is the crate of the same name
#[path = "farm.rs"]
mod farm_runs;
mod gpu_settings;
mod live;
mod live_program;
mod models;
mod multihost;
mod observability;
mod python_package;
mod robot;
mod study;
