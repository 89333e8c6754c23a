//! Where a run keeps its checkpoints and how their files are named: the learner writes them,
//! the orchestrator (eval, resume) finds them. A checkpoint is renamed into place when complete,
//! so a file with the final name is whole; one being written is a hidden temporary file.

use std::path::{Path, PathBuf};

/// The checkpoints' folder inside a run directory.
pub const DIR: &str = "checkpoints";

/// `RUN/checkpoints`.
pub fn dir_of(run_dir: &Path) -> PathBuf {
    run_dir.join(DIR)
}

/// `dir/ckpt-00000042.safetensors`.
pub fn path(dir: &Path, update: u64) -> PathBuf {
    dir.join(format!("ckpt-{update:08}.safetensors"))
}

/// The update count in a checkpoint's file name; `None` for any other file (temporary ones too).
pub fn update_of(path: &Path) -> Option<u64> {
    let name = path.file_name()?.to_str()?;
    name.strip_prefix("ckpt-")?.strip_suffix(".safetensors")?.parse().ok()
}

/// The newest complete checkpoint of the run directory `run_dir`.
pub fn latest_in_run(run_dir: &Path) -> Option<PathBuf> {
    latest(&dir_of(run_dir))
}

/// Complete checkpoints in `dir`, oldest first.
pub fn list(dir: &Path) -> Vec<(u64, PathBuf)> {
    let mut found: Vec<(u64, PathBuf)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter_map(|p| update_of(&p).map(|u| (u, p)))
        .collect();
    found.sort();
    found
}

/// The newest complete checkpoint in `dir`.
pub fn latest(dir: &Path) -> Option<PathBuf> {
    list(dir).pop().map(|(_, p)| p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_final_names_count() {
        let d = tempfile::tempdir().unwrap();
        for f in [
            "ckpt-00000010.safetensors",
            "ckpt-00000020.safetensors",
            ".ckpt-00000030.safetensors.tmp123",
            "ckpt-00000040.safetensors.partial",
        ] {
            std::fs::write(d.path().join(f), b"x").unwrap();
        }
        assert_eq!(list(d.path()).iter().map(|(u, _)| *u).collect::<Vec<_>>(), vec![10, 20]);
        assert_eq!(latest(d.path()), Some(path(d.path(), 20)));
        assert_eq!(update_of(&path(d.path(), 7)), Some(7));
    }
}
