//! Where a run keeps its checkpoints and how their files are named: the learner writes them,
//! the orchestrator (eval, resume) finds them. A checkpoint is renamed into place when complete,
//! so a file with the final name is whole; one being written is a hidden temporary file.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

/// The `format` tag in a learner checkpoint's metadata.
pub const FORMAT: &str = "gesthor-rs learner checkpoint v1";

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

/// SHA-256 over (name, bytes) pairs in the order given (name order in a checkpoint): what a
/// checkpoint's `sha256` metadata holds.
pub fn digest<'a>(items: impl Iterator<Item = (&'a str, &'a [u8])>) -> String {
    let mut h = Sha256::new();
    for (name, data) in items {
        h.update((name.len() as u64).to_le_bytes());
        h.update(name.as_bytes());
        h.update((data.len() as u64).to_le_bytes());
        h.update(data);
    }
    crate::files::hex(&h.finalize())
}

/// Whether a checkpoint file is whole: a safetensors file with our format tag whose tensors
/// match its checksum. The error is one reason, without the path.
pub fn verify(path: &Path) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    check_bytes(&bytes).map(drop)
}

/// [`verify`] on a checkpoint's bytes; its metadata when whole (the learner reads on from it).
pub fn check_bytes(bytes: &[u8]) -> Result<std::collections::HashMap<String, String>, String> {
    let st = safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| format!("not a complete safetensors file (truncated or corrupted?): {e}"))?;
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| e.to_string())?;
    let meta = header.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err("not a GesTHOR-RS learner checkpoint (no format tag)".into());
    }
    let mut views = st.tensors();
    views.sort_by(|a, b| a.0.cmp(&b.0));
    if meta.get("sha256") != Some(&digest(views.iter().map(|(n, v)| (n.as_str(), v.data())))) {
        return Err("its data does not match its checksum (the file is corrupted)".into());
    }
    Ok(meta)
}

/// The environment frames a whole checkpoint was trained on (its `frames` metadata).
pub fn frames(path: &Path) -> Result<u64, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    let meta = check_bytes(&bytes)?;
    meta.get("frames").and_then(|f| f.parse().ok()).ok_or_else(|| "no `frames` in its metadata".into())
}

/// The newest checkpoint in `dir` that [`verify`]s, and the newer ones passed over with why.
pub fn latest_verified(dir: &Path) -> (Option<PathBuf>, Vec<(PathBuf, String)>) {
    let mut skipped = Vec::new();
    for (_, p) in list(dir).into_iter().rev() {
        match verify(&p) {
            Ok(()) => return (Some(p), skipped),
            Err(why) => skipped.push((p, why)),
        }
    }
    (None, skipped)
}

/// One line per checkpoint passed over, for the user.
pub fn describe_skipped(skipped: &[(PathBuf, String)]) -> String {
    skipped.iter().map(|(p, why)| format!("skipped {}: {why}", p.display())).collect::<Vec<_>>().join("\n")
}

/// A file in the checkpoint format holding one u8 tensor `w`: what discovery tests write.
pub fn minimal_file(data: &[u8]) -> Vec<u8> {
    let view = safetensors::tensor::TensorView::new(safetensors::Dtype::U8, vec![data.len()], data)
        .expect("a u8 vector fits its shape");
    let meta = std::collections::HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("sha256".to_string(), digest([("w", data)].into_iter())),
    ]);
    safetensors::serialize([("w", view)], Some(meta)).expect("one small tensor serializes")
}

/// Present in a run's checkpoint folder while the learner writes its final checkpoint (after
/// a stop was asked for), so the orchestrator waits for it instead of escalating.
pub const FINAL_WRITE_MARKER: &str = ".writing-final";

/// Whether the learner is writing its final checkpoint in `dir` now.
pub fn final_write_in_progress(dir: &Path) -> bool {
    dir.join(FINAL_WRITE_MARKER).exists()
}

/// Removes temporary files of checkpoint writes that never finished (a writer killed mid-write);
/// only the run's one learner writes here, so any found at its start are stale.
pub fn remove_partial(dir: &Path) -> usize {
    let mut n = 0;
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let partial = (name.starts_with(".ckpt-") && name.contains(".safetensors.tmp")) || name == FINAL_WRITE_MARKER;
        if partial && std::fs::remove_file(e.path()).is_ok() {
            n += 1;
        }
    }
    n
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
        assert_eq!(remove_partial(d.path()), 1);
        assert!(!d.path().join(".ckpt-00000030.safetensors.tmp123").exists());
    }

    /// A truncated or bit-flipped newest checkpoint is passed over, with the reason, for the
    /// newest one that verifies.
    #[test]
    fn latest_verified_passes_over_damaged_files() {
        let d = tempfile::tempdir().unwrap();
        let good = minimal_file(&[1, 2, 3, 4, 5, 6, 7, 8]);
        std::fs::write(path(d.path(), 1), &good).unwrap();
        assert_eq!(verify(&path(d.path(), 1)), Ok(()));
        std::fs::write(path(d.path(), 2), &good[..good.len() - 3]).unwrap();
        let mut flipped = good.clone();
        *flipped.last_mut().unwrap() ^= 1;
        std::fs::write(path(d.path(), 3), &flipped).unwrap();
        let (found, skipped) = latest_verified(d.path());
        assert_eq!(found, Some(path(d.path(), 1)));
        assert_eq!(skipped.len(), 2);
        assert!(skipped[0].1.contains("checksum"), "{:?}", skipped[0]);
        assert!(skipped[1].1.contains("truncated"), "{:?}", skipped[1]);
        assert!(describe_skipped(&skipped).contains("ckpt-00000003.safetensors"));
    }
}
