//! The orchestrator's library side: what its commands draw and compute, testable apart from
//! the CLI in `main.rs`.

pub mod map;
