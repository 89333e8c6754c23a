//! Supervision of the processes of a run: where the programs are (`binaries`), one child process
//! (`child`), the run directory and its lock (`run_dir`), what a command does before it starts a
//! crew (`launch`), and the crew itself, a learner and N workers kept alive (`crew`).
//!
//! Lowest layer first: `binaries`, `child`, `run_dir` → `crew` → `launch`.

pub mod binaries;
pub mod child;
pub mod crew;
pub mod launch;
pub mod run_dir;
