//! A run's record: the episodes a stopped run recorded already, and summary.json.

use std::path::{Path, PathBuf};

use farm::files::write_atomic;
use worker::scene::Split;

use crate::commands::live::record::EpisodeRecord;
use crate::commands::live::wire::Outcome;
use crate::commands::program::program_ref;

pub(super) fn episode_dir(out: &Path, number: usize) -> PathBuf {
    out.join(format!("episode-{number:03}"))
}

/// The episodes a run of the same list recorded in `out` before it stopped, in order up to the
/// first unfinished one: the same command goes on where it stopped.
pub(super) fn recorded(
    out: &Path,
    split: Split,
    list: &[u64],
    checkpoint: &Path,
) -> anyhow::Result<Vec<(String, Outcome)>> {
    let mut done = Vec::new();
    for (n, &p) in list.iter().enumerate() {
        let dir = episode_dir(out, n + 1);
        if !dir.join("episode.json").exists() {
            break;
        }
        let r = EpisodeRecord::load(&dir)?;
        let program = program_ref(split, p);
        anyhow::ensure!(
            r.program == program && r.checkpoint == checkpoint,
            "{}: {} by {} is recorded there, not {program} by {}: give another --out, or remove it",
            dir.display(),
            r.program,
            r.checkpoint.display(),
            checkpoint.display()
        );
        done.push((program, r.outcome));
    }
    Ok(done)
}

/// summary.json: SR, SPL and DTS at the first stop over the episodes, as `eval` gives them.
pub(super) fn summary(out: &Path, checkpoint: &Path, outcomes: &[(String, Outcome)]) -> anyhow::Result<()> {
    let n = outcomes.len().max(1) as f64;
    let sr = outcomes.iter().filter(|(_, o)| o.success).count() as f64 / n * 100.0;
    let spl = outcomes.iter().map(|(_, o)| o.spl).sum::<f64>() / n * 100.0;
    let dts = outcomes.iter().map(|(_, o)| o.dts).sum::<f64>() / n;
    let s = serde_json::json!({
        "checkpoint": checkpoint,
        "episodes": outcomes.len(),
        "sr": sr, "spl": spl, "dts": dts,
        "programs": outcomes.iter().map(|(p, o)| serde_json::json!({"program": p, "outcome": o})).collect::<Vec<_>>(),
    });
    let path = out.join("summary.json");
    write_atomic(&path, serde_json::to_string_pretty(&s)?.as_bytes())?;
    say!("{} episodes: SR {sr:.1}, SPL {spl:.1}, DTS {dts:.2} at the first stop ({})", outcomes.len(), path.display());
    Ok(())
}
