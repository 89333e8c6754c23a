//! What an evaluation folder's passes hold: each pass's episodes, and the trajectories of those
//! that kept them.

use std::path::Path;

use farm::metrics::{EpisodeResult, Trajectory};
use worker::program::Program;

use crate::report::first_turn::FirstHeading;
use crate::report::tables::EvalMode;

/// The `episodes.jsonl` of an evaluation pass.
pub fn read_episodes(path: &Path) -> anyhow::Result<Vec<EpisodeResult>> {
    farm::files::read_jsonl(path)
}

/// The trajectories of each of `modes` whose pass in the evaluation folder `dir` kept them.
pub(super) fn pass_trajectories(
    dir: &Path,
    modes: impl IntoIterator<Item = EvalMode>,
) -> anyhow::Result<Vec<(EvalMode, Vec<Trajectory>)>> {
    let mut found = Vec::new();
    for mode in modes {
        let f = dir.join(mode.name()).join("trajectories.jsonl");
        if f.is_file() {
            found.push((mode, crate::report::trajectory::read(&f)?));
        }
    }
    Ok(found)
}

/// Where the policy heads at its first move ahead, a row per pass.
pub(super) fn first_headings(
    label: &str,
    passes: &[(EvalMode, Vec<Trajectory>)],
    programs: &[Program],
    fov_deg: f32,
) -> Vec<(String, &'static str, FirstHeading)> {
    passes
        .iter()
        .map(|(mode, trajs)| (label.to_string(), mode.name(), FirstHeading::of(trajs, programs, fov_deg)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An explicit --out may hold passes of an earlier evaluation: only the asked ones are read.
    #[test]
    fn trajectories_are_read_for_the_asked_passes_only() {
        let d = tempfile::tempdir().unwrap();
        for (mode, program) in [(EvalMode::Normal, 3), (EvalMode::Blind, 4)] {
            std::fs::create_dir_all(d.path().join(mode.name())).unwrap();
            let line = serde_json::to_string(&Trajectory { program, ..Trajectory::default() }).unwrap();
            std::fs::write(d.path().join(mode.name()).join("trajectories.jsonl"), line + "\n").unwrap();
        }
        let found = pass_trajectories(d.path(), [EvalMode::Normal, EvalMode::OtherGesture]).unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!((found[0].0, found[0].1[0].program), (EvalMode::Normal, 3));
        assert_eq!(pass_trajectories(d.path(), EvalMode::ALL).unwrap().len(), 2);
    }
}
