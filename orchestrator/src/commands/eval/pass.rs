//! One pass of an evaluation: the farm runs the chosen programs, each exactly once, with the
//! checkpoint's inputs as the pass asks (all, blind, RGB or depth alone, another room's gesture).

use std::path::Path;
use std::time::{Duration, Instant};

use farm::metrics::EpisodeResult;
use farm::serve_args::{Blank, LearnerOptions};

use super::passes::read_episodes;
use super::plan::{Plan, assign};
use crate::report::progress::Bar;
use crate::report::tables::EvalMode;
use crate::supervise::crew::{Crew, CrewSpec, CrewState};
use crate::supervise::launch::prepare_run;

/// Runs `mode`'s pass into `plan.out/<mode>` on `workers` workers: its episodes, one per
/// program in program order, and its seconds.
pub(super) fn run_pass(plan: &Plan, mode: EvalMode, workers: usize) -> anyhow::Result<(Vec<EpisodeResult>, f64)> {
    let pass_dir = plan.out.join(mode.name());
    if pass_dir.exists() {
        std::fs::remove_dir_all(&pass_dir)?;
    }
    let mut cfg = plan.cfg.clone();
    if mode == EvalMode::OtherGesture {
        // half the split on: another room, whatever the programs chosen
        cfg.task.gesture_shift = plan.index.len() as u64 / 2;
    }
    let (dir, config_path) = prepare_run(&pass_dir, &cfg, false, workers, plan.policy)?;
    let mut spec = CrewSpec::new(&dir.path, &dir.run_id, &config_path, cfg, workers, plan.policy);
    spec.programs = Some(assign(&plan.programs, workers));
    if let Some(c) = &plan.checkpoint {
        spec.learner = learner_options(c, mode, plan.greedy);
    }
    let t = Instant::now();
    let mut crew = Crew::start(spec)?;
    let bar =
        Bar::new(&format!("eval {}", mode.name()), plan.programs.len() as u64, "episodes", Duration::from_secs(10));
    let mut polled = Instant::now();
    while crew.tick()? == CrewState::Running {
        if polled.elapsed() >= Duration::from_millis(500) {
            polled = Instant::now();
            if let Some(p) = crew.progress() {
                bar.set(p.totals.episodes, &format!("{:.0} frames/s", p.fps));
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    bar.finish();
    let outcome = crew.finish()?;
    let secs = t.elapsed().as_secs_f64();
    if !outcome.learner.as_ref().is_some_and(|e| e.success()) {
        let finished = outcome.progress.as_ref().and_then(|p| p.stop_reason.clone()).unwrap_or_default();
        let log = dir.logs().join("learner.log");
        let tail = std::fs::read_to_string(&log).unwrap_or_default();
        let last = tail.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("");
        anyhow::bail!("{} pass failed ({finished}); the learner said: {last}\n(see {})", mode.name(), log.display());
    }
    let eps = once_each(&dir.path.join("episodes.jsonl"), &plan.programs, mode)?;
    Ok((eps, secs))
}

/// The learner's options for `mode`'s pass of `checkpoint`: the inputs it zeroes.
fn learner_options(checkpoint: &Path, mode: EvalMode, greedy: bool) -> LearnerOptions {
    let blank = match mode {
        EvalMode::Normal | EvalMode::OtherGesture => None,
        EvalMode::Blind => Some(Blank::Both),
        EvalMode::RgbOnly => Some(Blank::Depth),
        EvalMode::DepthOnly => Some(Blank::Rgb),
    };
    LearnerOptions { checkpoint: Some(checkpoint.into()), blank, greedy, profile_stages: false }
}

/// Each program's first episode (a restarted worker may repeat programs it had begun); every
/// program must have one.
fn once_each(episodes: &Path, programs: &[u64], mode: EvalMode) -> anyhow::Result<Vec<EpisodeResult>> {
    let mut by_program = std::collections::BTreeMap::new();
    for e in read_episodes(episodes)? {
        by_program.entry(e.program).or_insert(e);
    }
    let missing = programs.iter().filter(|p| !by_program.contains_key(p)).count();
    anyhow::ensure!(missing == 0, "{} pass: {missing} of {} programs have no episode", mode.name(), programs.len());
    Ok(by_program.into_values().collect())
}
