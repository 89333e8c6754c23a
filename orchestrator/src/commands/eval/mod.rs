//! `orchestrator eval`: runs a split's programs on the farm, each exactly once, and writes the
//! tables of chapter 4 (T4.2–T4.7) as Markdown and CSV, with success by the target's nearness to
//! the start; `--compare` puts several evaluations side by side like T4.2 and by that nearness,
//! and each against the first episode by episode; `--trajectories` draws episodes like Figs 4.2/4.3.
//!
//! A checkpoint (or a run directory, whose latest *complete* checkpoint is used, so a training
//! that is still writing can be evaluated) is evaluated greedily in several passes: with all its
//! inputs, blind (visual inputs zeroed, T4.6), and with RGB or depth alone (T4.7) when it was
//! trained with both. Without a checkpoint the Random baseline runs. Episodes allow unlimited
//! stops; the metrics at 1, 2 and 3 stops read each episode up to its k-th stop.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;

use farm::config::{Method, RunConfig};
use farm::metrics::EpisodeResult;
use worker::program::Program;
use worker::scene::Split;

use crate::report::first_turn::FirstHeading;
use crate::report::nearness;
use crate::report::progress::Bar;
use crate::report::tables::{EvalMode, Evaluation};
use crate::supervise::crew::{Crew, CrewSpec, CrewState, PolicyArg};
use crate::supervise::launch::{prepare_run, resolve_dataset, sweep_dead_runs};

mod compare;
mod passes;

pub use passes::read_episodes;
use passes::{first_headings, pass_trajectories};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A checkpoint file, a run directory (its latest complete checkpoint), or a shipped model
    /// (`models/both`; its evaluations go to runs/eval-models/NAME). Without it, the
    /// Random baseline is evaluated.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Evaluate the shortest-path expert instead of a checkpoint (an upper bound, and a check of
    /// the metrics: SR 100%, SPL close to 1).
    #[arg(long, conflicts_with = "checkpoint")]
    pub expert: bool,
    /// Take the checkpoint's most likely action at every step instead of sampling from the
    /// policy as in training (a greedy policy that never ranks Stop first never succeeds).
    #[arg(long)]
    pub greedy: bool,
    /// Only the programs of these rooms (e.g. a run's training rooms), comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Fold to evaluate on.
    #[arg(long, default_value = "test")]
    pub split: String,
    #[arg(long, default_value_t = 4, value_parser = super::values::workers)]
    pub workers: usize,
    /// Run configuration when there is no run directory to take it from (Random baseline).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dataset (default: the configuration's).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Evaluate only this many programs, spread evenly over the split (every room keeps its share).
    #[arg(long)]
    pub max_programs: Option<usize>,
    /// Passes to run: normal, blind, rgb_only, depth_only (default: all the checkpoint allows
    /// of these), other_gesture (every program shows another room's referencing gesture: is
    /// where the arm points read? Compared with normal program by program).
    #[arg(long, value_delimiter = ',')]
    pub modes: Vec<String>,
    /// DTS threshold in metres (the dissertation writes 1.5 m; success uses 1 m).
    #[arg(long, default_value_t = 1.5)]
    pub dts_threshold: f64,
    /// Where to write the tables (default: RUN/eval/<split>, or runs/eval-random|eval-expert/<split>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Name of the method in the tables (default: from the run's config).
    #[arg(long)]
    pub label: Option<String>,
    /// Draw this many episodes (trajectory map PNG + robot-view GIF) from the normal pass.
    #[arg(long, default_value_t = 0)]
    pub trajectories: usize,
    /// Override a config value, e.g. `--set ppo.lr=1e-4` (repeatable; checked as the file is;
    /// the effective config is the one written into the run directory).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Put earlier evaluations side by side instead (their output folders, or run directories);
    /// each after the first is also compared with it episode by episode (McNemar's test).
    #[arg(long, num_args = 1..)]
    pub compare: Vec<PathBuf>,
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

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    if !a.compare.is_empty() {
        return compare::run(&compare::Comparison {
            dirs: a.compare.clone(),
            split: a.split.clone(),
            dataset: a.dataset.clone(),
            dts_threshold: a.dts_threshold,
            out: a.out.clone(),
        });
    }
    let split =
        Split::from_name(&a.split).with_context(|| format!("--split: `{}` is not one of train, val, test", a.split))?;
    let (checkpoint, run_dir) = match &a.checkpoint {
        Some(p) => {
            let (c, r) = locate(p)?;
            (Some(c), Some(r))
        }
        None => (None, None),
    };
    let cfg = match (&run_dir, &a.config) {
        (Some(r), _) => {
            RunConfig::load(&r.join("config.toml")).with_context(|| format!("{}: the run's config", r.display()))?
        }
        (None, Some(c)) => RunConfig::load(c)?,
        (None, None) => super::up::load_config(None)?,
    };
    let mut cfg = cfg.with_overrides(&a.set)?;
    // a shipped model's folder stays as shipped: its evaluations go elsewhere
    let shipped = run_dir.as_ref().is_some_and(|r| farm::models::is_model(r));
    let baseline = checkpoint.is_none();
    if baseline && !a.expert {
        cfg.run.method = Method::Random;
    }
    if let Some(d) = &a.dataset {
        cfg.run.dataset = d.clone();
    }
    // Evaluation runs every program of the fold, with unlimited stops (the metrics at k stops
    // read each episode up to its k-th stop).
    cfg.run.split = split;
    cfg.run.scenes.clear();
    cfg.run.max_programs = None;
    cfg.task.max_stops = 0;
    let ds = resolve_dataset(&mut cfg, false)?.expect("a dataset is opened unless synthetic");
    let index: Vec<Program> = ds.index(split)?;
    let mut candidates: Vec<u64> = (0..index.len() as u64).collect();
    if !a.scenes.is_empty() {
        for s in &a.scenes {
            anyhow::ensure!(index.iter().any(|p| &p.scene == s), "--scenes: {s} has no programs in {}", split.name());
        }
        candidates.retain(|&i| a.scenes.contains(&index[i as usize].scene));
    }
    let programs: Vec<u64> =
        choose_programs(candidates.len(), a.max_programs).into_iter().map(|i| candidates[i as usize]).collect();
    let modes = modes_for(&cfg, baseline, &a.modes)?;
    let default_label = if a.expert { "Expert (shortest path)" } else { cfg.run.method.label() };
    let greedy = if a.greedy && checkpoint.is_some() { ", greedy" } else { "" };
    let label = a.label.clone().unwrap_or_else(|| format!("{default_label}{greedy}"));
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
    std::fs::create_dir_all(&out)?;
    eprintln!(
        "[eval] {label}: {} programs of {} × {} pass(es) ({}) on {} workers{}",
        programs.len(),
        split.name(),
        modes.len(),
        modes.iter().map(|m| m.name()).collect::<Vec<_>>().join(", "),
        a.workers,
        checkpoint.as_ref().map(|c| format!(", checkpoint {}", c.display())).unwrap_or_default()
    );
    sweep_dead_runs();
    let mut passes = BTreeMap::new();
    let mut timing = Vec::new();
    for mode in &modes {
        let pass_dir = out.join(mode.name());
        if pass_dir.exists() {
            std::fs::remove_dir_all(&pass_dir)?;
        }
        let policy = match (baseline, a.expert) {
            (_, true) => PolicyArg::Expert,
            (true, false) => PolicyArg::Random,
            (false, false) => PolicyArg::Ppo,
        };
        let mut cfg = cfg.clone();
        if *mode == EvalMode::OtherGesture {
            // half the split on: another room, whatever the programs chosen
            cfg.task.gesture_shift = index.len() as u64 / 2;
        }
        let (dir, config_path) = prepare_run(&pass_dir, &cfg, false, a.workers, policy)?;
        let mut spec = CrewSpec::new(&dir.path, &dir.run_id, &config_path, cfg, a.workers, policy);
        spec.programs = Some(assign(&programs, a.workers));
        if let Some(c) = &checkpoint {
            let mut args: Vec<OsString> = vec!["--checkpoint".into(), c.clone().into_os_string()];
            let blank = match mode {
                EvalMode::Normal | EvalMode::OtherGesture => None,
                EvalMode::Blind => Some("both"),
                EvalMode::RgbOnly => Some("depth"),
                EvalMode::DepthOnly => Some("rgb"),
            };
            if let Some(b) = blank {
                args.extend(["--blank".into(), b.into()]);
            }
            if a.greedy {
                args.push("--greedy".into());
            }
            spec.learner_args = args;
        }
        let t = Instant::now();
        let mut crew = Crew::start(spec)?;
        let bar =
            Bar::new(&format!("eval {}", mode.name()), programs.len() as u64, "episodes", Duration::from_secs(10));
        let mut polled = Instant::now();
        while crew.tick()? == CrewState::Running {
            if polled.elapsed() >= Duration::from_millis(500) {
                polled = Instant::now();
                if let Some(p) = crew.progress() {
                    bar.set(p.episodes, &format!("{:.0} frames/s", p.fps));
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        bar.finish();
        let outcome = crew.finish()?;
        let secs = t.elapsed().as_secs_f64();
        let ok = outcome.learner.as_ref().is_some_and(|e| e.success());
        let finished = outcome.progress.as_ref().and_then(|p| p.stop_reason.clone()).unwrap_or_default();
        if !ok {
            let log = dir.logs().join("learner.log");
            let tail = std::fs::read_to_string(&log).unwrap_or_default();
            let last = tail.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("");
            anyhow::bail!(
                "{} pass failed ({finished}); the learner said: {last}\n(see {})",
                mode.name(),
                log.display()
            );
        }
        let eps = read_episodes(&dir.path.join("episodes.jsonl"))?;
        // each program exactly once (a restarted worker may repeat programs it had begun)
        let mut by_program: BTreeMap<u64, EpisodeResult> = BTreeMap::new();
        for e in eps {
            by_program.entry(e.program).or_insert(e);
        }
        let missing = programs.iter().filter(|p| !by_program.contains_key(p)).count();
        anyhow::ensure!(missing == 0, "{} pass: {missing} of {} programs have no episode", mode.name(), programs.len());
        let eps: Vec<EpisodeResult> = by_program.into_values().collect();
        let steps: u64 = eps.iter().map(|e| e.steps as u64 + 1).sum();
        eprintln!(
            "[eval] {}: {} episodes in {:.1} s ({:.1} episodes/s, {:.0} frames/s)",
            mode.name(),
            eps.len(),
            secs,
            eps.len() as f64 / secs,
            steps as f64 / secs
        );
        timing.push((mode.name(), eps.len(), secs));
        passes.insert(*mode, eps);
    }
    let evaluation = Evaluation {
        label: label.clone(),
        split: split.name(),
        programs: &index,
        passes,
        dts_threshold: a.dts_threshold,
    };
    let mut md = evaluation.markdown();
    // this evaluation's passes only: an explicit --out may still hold other passes of an earlier one
    let trajectories = pass_trajectories(&out, evaluation.passes.keys().copied())?;
    if let Some((_, trajs)) = trajectories.iter().find(|(mode, _)| *mode == EvalMode::Normal) {
        md += &crate::report::first_turn::FirstTurns::of(trajs, &index, cfg.env.fov_deg).markdown();
    }
    if !trajectories.is_empty() {
        md += &FirstHeading::markdown(&first_headings(&label, &trajectories, &index, cfg.env.fov_deg));
    }
    if let Some(eps) = evaluation.passes.get(&EvalMode::Normal) {
        let ranks = nearness::target_ranks(&ds, &index)?;
        md += &nearness::markdown(&[(label.clone(), eps.as_slice())], &ranks);
    }
    if baseline && !a.expert {
        md += "\n";
        md += &evaluation.calibration().unwrap_or_default();
    }
    md += "\n## Throughput\n\n| pass | episodes | seconds | episodes/s |\n|---|---:|---:|---:|\n";
    for (m, n, s) in &timing {
        md += &format!("| {m} | {n} | {s:.1} | {:.2} |\n", *n as f64 / s);
    }
    if let Some(c) = &checkpoint {
        md += &format!("\nCheckpoint: `{}`\n", c.display());
    }
    farm::files::write_atomic(&out.join("tables.md"), md.as_bytes())?;
    farm::files::write_atomic(&out.join("tables.csv"), evaluation.csv().as_bytes())?;
    let maps = if a.trajectories > 0 {
        crate::report::trajectory::draw(&cfg, &ds, split, &evaluation, checkpoint.as_deref(), &out, a.trajectories)?
    } else {
        Vec::new()
    };
    // Beside the training curves when the checkpoint belongs to a run, at its frame count.
    let tb = run_dir.as_ref().filter(|_| !shipped).unwrap_or(&out).join("tb");
    let step = match &checkpoint {
        Some(c) => farm::checkpoints::frames(c).map_err(|e| anyhow::anyhow!("{}: {e}", c.display()))?,
        None => 0,
    };
    write_tensorboard(&tb, step, &evaluation, &md, &maps).with_context(|| format!("writing {}", tb.display()))?;
    println!("{md}");
    let (short, successes) = evaluation.shorter_than_l();
    if short > 0 {
        eprintln!(
            "[eval] warning: {short} of {successes} successful episodes were shorter than their l_i (a bug in SPL's lower bound)"
        );
    }
    eprintln!("[eval] tables in {}", out.display());
    Ok(())
}

/// The evaluation's SR/SPL/DTS at 1, 2, 3 and unlimited stops under `eval/<split>/` (other
/// passes under `eval/<split>/<pass>/`), its tables as text and the trajectory maps as images,
/// all at `step` (the checkpoint's frames). SR and SPL are fractions, as training's success
/// rate and SPL are, so the curves share an axis (the tables show percent).
fn write_tensorboard(tb: &Path, step: u64, ev: &Evaluation, md: &str, maps: &[PathBuf]) -> anyhow::Result<()> {
    let mut w = farm::tensorboard::EventWriter::create(tb, &format!("eval-{}", ev.split))?;
    let step = step as i64;
    let mut values: Vec<(String, f64)> = Vec::new();
    for &mode in ev.passes.keys() {
        let prefix = match mode {
            EvalMode::Normal => format!("eval/{}", ev.split),
            other => format!("eval/{}/{}", ev.split, other.name()),
        };
        for (k, stops) in [(Some(1), "1"), (Some(2), "2"), (Some(3), "3"), (None, "inf")] {
            let s = ev.scores(mode, k, |_| true).unwrap_or_default();
            values.push((format!("{prefix}/SR@{stops}"), s.sr / 100.0));
            values.push((format!("{prefix}/SPL@{stops}"), s.spl / 100.0));
            values.push((format!("{prefix}/DTS@{stops}"), s.dts));
        }
    }
    w.scalars(step, &values.iter().map(|(t, v)| (t.as_str(), *v)).collect::<Vec<_>>())?;
    w.text(&format!("eval/{}/tables", ev.split), step, md)?;
    for png in maps {
        let (width, height) = image::image_dimensions(png)?;
        let name = png.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        w.image_png(&format!("eval/{}/trajectories/{name}", ev.split), step, &std::fs::read(png)?, width, height)?;
    }
    Ok(())
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
