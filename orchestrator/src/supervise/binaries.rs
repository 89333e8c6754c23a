//! Where the farm's other programs are: next to the orchestrator's own executable (cargo puts
//! `orchestrator`, `worker` and `learner` in the same `target/<profile>/` folder), unless
//! `GESTHOR_BIN_DIR` names another folder.

use std::path::{Path, PathBuf};

/// Overrides the folder the `worker` and `learner` executables are taken from.
pub const BIN_DIR_ENV: &str = "GESTHOR_BIN_DIR";

/// The path of sibling program `name` (`worker`, `learner`), checked to exist.
pub fn sibling(name: &str) -> anyhow::Result<PathBuf> {
    sibling_in(None, name)
}

/// Like [`sibling`], but from folder `dir` when one is given.
pub fn sibling_in(dir: Option<&Path>, name: &str) -> anyhow::Result<PathBuf> {
    let (dir, how) = match dir.map(Path::to_path_buf).or_else(|| std::env::var_os(BIN_DIR_ENV).map(PathBuf::from)) {
        Some(d) => (d, format!("{BIN_DIR_ENV} or the caller's folder")),
        None => {
            let exe = std::env::current_exe()?;
            let dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
            (dir, "the orchestrator's folder".to_string())
        }
    };
    let p = dir.join(name);
    anyhow::ensure!(
        p.is_file(),
        "cannot find the `{name}` program at {} ({how}); build it with `cargo build --release --workspace` or set {BIN_DIR_ENV}",
        p.display()
    );
    Ok(p)
}
