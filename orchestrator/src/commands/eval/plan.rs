//! What an evaluation runs: the checkpoint and its run's config set for evaluation, the split's
//! programs chosen and shared among the workers, the passes, and where the tables go.

use std::path::{Path, PathBuf};

use anyhow::Context;

use farm::config::{Method, RunConfig};
use worker::dataset::Dataset;
use worker::program::Program;
use worker::scene::Split;

use super::args::EvalArgs;
use crate::report::tables::EvalMode;
use crate::supervise::launch::resolve_dataset;
use farm::serve_args::Policy;

/// What an evaluation runs: the checkpoint and its run's config set for evaluation, the
/// programs, the passes, and where the tables go.
pub(super) struct Plan {
    pub(super) split: Split,
    pub(super) checkpoint: Option<PathBuf>,
    /// The run directory (or shipped model's folder) holding the checkpoint's config.
    pub(super) run_dir: Option<PathBuf>,
    /// The checkpoint is a shipped model's: its folder stays as shipped.
    pub(super) shipped: bool,
    pub(super) cfg: RunConfig,
    pub(super) ds: Dataset,
    /// Every program of the split, and those evaluated.
    pub(super) index: Vec<Program>,
    pub(super) programs: Vec<u64>,
    pub(super) modes: Vec<EvalMode>,
    pub(super) policy: Policy,
    pub(super) greedy: bool,
    pub(super) label: String,
    pub(super) out: PathBuf,
}

impl Plan {
    pub(super) fn new(a: &EvalArgs) -> anyhow::Result<Plan> {
        let split = Split::from_name(&a.split)
            .with_context(|| format!("--split: `{}` is not one of train, val, test", a.split))?;
        let (checkpoint, run_dir) = match &a.checkpoint {
            Some(p) => locate(p).map(|(c, r)| (Some(c), Some(r)))?,
            None => (None, None),
        };
        let shipped = run_dir.as_ref().is_some_and(|r| farm::models::is_model(r));
        let baseline = checkpoint.is_none();
        let mut cfg = eval_config(a, run_dir.as_deref(), split, baseline)?;
        let ds = resolve_dataset(&mut cfg, false)?.expect("a dataset is opened unless synthetic");
        let index: Vec<Program> = ds.index(split)?;
        let programs = chosen_programs(a, &index, split)?;
        let modes = modes_for(&cfg, baseline, &a.modes)?;
        let default_label = if a.expert { "Expert (shortest path)" } else { cfg.run.method.label() };
        let greedy = a.greedy && !baseline;
        let label =
            a.label.clone().unwrap_or_else(|| format!("{default_label}{}", if greedy { ", greedy" } else { "" }));
        // An explicit --out is replaced; a default one is never: a second evaluation of the same
        // run and split goes beside the first (test-2, test-3, ...).
        let out = a.out.clone().unwrap_or_else(|| {
            unused_dir(match &run_dir {
                Some(r) if shipped => {
                    PathBuf::from("runs/eval-models").join(r.file_name().unwrap_or_default()).join(split.name())
                }
                Some(r) => r.join("eval").join(split.name()),
                None if a.expert => PathBuf::from("runs/eval-expert").join(split.name()),
                None => PathBuf::from("runs/eval-random").join(split.name()),
            })
        });
        let policy = policy(checkpoint.as_deref(), a.expert);
        Ok(Plan { split, checkpoint, run_dir, shipped, cfg, ds, index, programs, modes, policy, greedy, label, out })
    }
}

/// The run's config (or the one given, or the default), set for evaluation: every program of
/// the fold, with unlimited stops (the metrics at k stops read each episode up to its k-th).
fn eval_config(a: &EvalArgs, run_dir: Option<&Path>, split: Split, baseline: bool) -> anyhow::Result<RunConfig> {
    let cfg = match (run_dir, &a.config) {
        (Some(r), _) => {
            RunConfig::load(&r.join("config.toml")).with_context(|| format!("{}: the run's config", r.display()))?
        }
        (None, Some(c)) => RunConfig::load(c)?,
        (None, None) => crate::commands::up::load_config(None)?,
    };
    let mut cfg = cfg.with_overrides(&a.set)?;
    if baseline && !a.expert {
        cfg.run.method = Method::Random;
    }
    if let Some(d) = &a.dataset {
        cfg.run.dataset = d.clone();
    }
    cfg.run.split = split;
    cfg.run.scenes.clear();
    cfg.run.max_programs = None;
    cfg.task.max_stops = 0;
    Ok(cfg)
}

/// The programs of `--scenes` (all without it), `--max-programs` of them spread evenly.
fn chosen_programs(a: &EvalArgs, index: &[Program], split: Split) -> anyhow::Result<Vec<u64>> {
    let mut candidates: Vec<u64> = (0..index.len() as u64).collect();
    if !a.scenes.is_empty() {
        for s in &a.scenes {
            anyhow::ensure!(index.iter().any(|p| &p.scene == s), "--scenes: {s} has no programs in {}", split.name());
        }
        candidates.retain(|&i| a.scenes.contains(&index[i as usize].scene));
    }
    Ok(choose_programs(candidates.len(), a.max_programs).into_iter().map(|i| candidates[i as usize]).collect())
}

/// Resolves `--checkpoint` into (checkpoint file, run directory or shipped model's folder
/// holding its config).
pub(crate) fn locate(path: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    if farm::models::is_model(path) {
        return Ok((path.join(farm::models::WEIGHTS), path.to_path_buf()));
    }
    if path.is_dir() {
        let (ckpt, skipped) = farm::checkpoints::latest_verified(&farm::checkpoints::dir_of(path));
        if !skipped.is_empty() {
            eprintln!("[eval] {}", farm::checkpoints::describe_skipped(&skipped).replace('\n', "\n[eval] "));
        }
        let ckpt = ckpt.with_context(|| {
            let none = if skipped.is_empty() { "no checkpoint" } else { "no usable checkpoint" };
            format!("{}: {none} in {}/checkpoints yet", path.display(), path.display())
        })?;
        return Ok((ckpt, path.to_path_buf()));
    }
    anyhow::ensure!(path.is_file(), "--checkpoint {}: no such file or run directory", path.display());
    let run = path
        .parent()
        .and_then(|p| p.parent())
        .with_context(|| format!("{}: not inside RUN/checkpoints", path.display()))?;
    Ok((path.to_path_buf(), run.to_path_buf()))
}

/// `base` if it does not exist yet, else the first of `base-2`, `base-3`, ... that does not.
fn unused_dir(base: PathBuf) -> PathBuf {
    let name = base.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    std::iter::once(base.clone())
        .chain((2..).map(|k| base.with_file_name(format!("{name}-{k}"))))
        .find(|p| !p.exists())
        .expect("some numbered folder is free")
}

/// Every program of the split, or `max` of them spread evenly (so each room keeps its share).
pub fn choose_programs(total: usize, max: Option<usize>) -> Vec<u64> {
    match max {
        Some(m) if m < total => (0..m).map(|i| (i * total / m) as u64).collect(),
        _ => (0..total as u64).collect(),
    }
}

/// Worker w runs programs w, w + N, w + 2N, ... of the list, in order.
pub fn assign(programs: &[u64], workers: usize) -> Vec<Vec<u64>> {
    let mut out = vec![Vec::new(); workers];
    for (i, &p) in programs.iter().enumerate() {
        out[i % workers].push(p);
    }
    out
}

fn modes_for(cfg: &RunConfig, baseline: bool, asked: &[String]) -> anyhow::Result<Vec<EvalMode>> {
    if !asked.is_empty() {
        let modes = asked
            .iter()
            .map(|m| {
                EvalMode::from_name(m).with_context(|| {
                    format!("--modes: `{m}` is not one of normal, blind, rgb_only, depth_only, other_gesture")
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        for m in &modes {
            let needs_both = matches!(m, EvalMode::RgbOnly | EvalMode::DepthOnly);
            anyhow::ensure!(
                !baseline || *m == EvalMode::Normal,
                "--modes {}: a baseline without a checkpoint has no inputs to zero",
                m.name()
            );
            anyhow::ensure!(
                !needs_both || (cfg.model.rgb && cfg.model.depth),
                "--modes {}: the checkpoint was not trained with both RGB and depth",
                m.name()
            );
            if *m == EvalMode::OtherGesture {
                anyhow::ensure!(
                    cfg.run.method.shows_referencing(),
                    "--modes other_gesture: {} is not shown the referencing gesture",
                    cfg.run.method.label()
                );
                anyhow::ensure!(
                    cfg.task.gesture_shift == 0,
                    "--modes other_gesture chooses the other gesture itself: leave out --set task.gesture_shift"
                );
            }
        }
        return Ok(modes);
    }
    let mut modes = vec![EvalMode::Normal];
    if !baseline && (cfg.model.rgb || cfg.model.depth) {
        modes.push(EvalMode::Blind);
    }
    if !baseline && cfg.model.rgb && cfg.model.depth {
        modes.extend([EvalMode::RgbOnly, EvalMode::DepthOnly]);
    }
    Ok(modes)
}

/// The policy the farm runs for an evaluation of `checkpoint` (none: the Random baseline).
fn policy(checkpoint: Option<&Path>, expert: bool) -> Policy {
    match (checkpoint, expert) {
        (_, true) => Policy::Expert,
        (None, false) => Policy::Random,
        (Some(_), false) => Policy::Ppo,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_default_output_folder_is_never_reused() {
        let d = tempfile::tempdir().unwrap();
        let base = d.path().join("eval").join("test");
        assert_eq!(unused_dir(base.clone()), base);
        std::fs::create_dir_all(&base).unwrap();
        assert_eq!(unused_dir(base.clone()), d.path().join("eval").join("test-2"));
        std::fs::create_dir_all(d.path().join("eval").join("test-2")).unwrap();
        assert_eq!(unused_dir(base), d.path().join("eval").join("test-3"));
    }

    #[test]
    fn another_gesture_is_asked_of_policies_shown_the_referencing_gesture() {
        let mut cfg = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "test").unwrap();
        let asked = |cfg: &RunConfig, m: &str| modes_for(cfg, false, &[m.to_string()]).map_err(|e| e.to_string());
        for method in [Method::Referencing, Method::Both] {
            cfg.run.method = method;
            assert_eq!(asked(&cfg, "other_gesture").unwrap(), vec![EvalMode::OtherGesture]);
        }
        cfg.run.method = Method::VisSem;
        assert!(asked(&cfg, "other_gesture").unwrap_err().contains("VisSem is not shown the referencing gesture"));
        cfg.run.method = Method::Both;
        cfg.task.gesture_shift = 7;
        assert!(asked(&cfg, "other_gesture").unwrap_err().contains("leave out --set task.gesture_shift"));
        assert!(asked(&cfg, "shifted").unwrap_err().contains("other_gesture"));
        // not a default pass: it costs one more evaluation
        cfg.task.gesture_shift = 0;
        assert!(!modes_for(&cfg, false, &[]).unwrap().contains(&EvalMode::OtherGesture));
    }

    #[test]
    fn programs_are_spread_and_assigned_exactly_once() {
        assert_eq!(choose_programs(10, None), (0..10).collect::<Vec<_>>());
        assert_eq!(choose_programs(10, Some(4)), vec![0, 2, 5, 7]);
        let a = assign(&choose_programs(5000, Some(1000)), 3);
        let mut all: Vec<u64> = a.concat();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), 1000);
        assert!(a.iter().all(|w| w.len() >= 333));
    }

    #[test]
    fn locate_takes_the_newest_checkpoint_that_verifies() {
        let d = tempfile::tempdir().unwrap();
        let c = d.path().join("checkpoints");
        std::fs::create_dir_all(&c).unwrap();
        let whole = farm::checkpoints::minimal_file(&[1, 2, 3]);
        std::fs::write(c.join("ckpt-00000010.safetensors"), &whole).unwrap();
        std::fs::write(c.join("ckpt-00000020.safetensors"), &whole).unwrap();
        // truncated by a kill during the write of a newer one, and temporary files
        std::fs::write(c.join("ckpt-00000030.safetensors"), &whole[..whole.len() / 2]).unwrap();
        for f in [".ckpt-00000040.safetensors.tmp123", "ckpt-00000050.safetensors.partial"] {
            std::fs::write(c.join(f), b"x").unwrap();
        }
        assert_eq!(locate(d.path()).unwrap().0, c.join("ckpt-00000020.safetensors"));
        std::fs::write(c.join("ckpt-00000010.safetensors"), b"x").unwrap();
        std::fs::write(c.join("ckpt-00000020.safetensors"), b"x").unwrap();
        let err = locate(d.path()).unwrap_err().to_string();
        assert!(err.contains("no usable checkpoint"), "{err}");
    }
}
