//! The study (§4.4.1, T4.2–T4.7): every method of a config folder that learns, trained with N
//! seeds for F frames each; each run's checkpoints evaluated on val and the best by SR at the
//! first stop evaluated on test (normally, blind, and — where the referencing gesture is shown —
//! with another room's gesture) and on train; Random evaluated on test with the same seeds.
//! `summary` and `ablations` put the dissertation's figures beside ours (mean ± std over the
//! seeds).
//!
//! Every step is a child `orchestrator up` or `orchestrator eval` writing into the study folder,
//! and a step whose output is complete is never run again: killed at any point, the same
//! command continues — finished runs are kept, a run with checkpoints resumes from its newest,
//! an evaluation without its tables (or without one of its passes) runs again.
//!
//! ```text
//! OUT/configs/<name>.toml     the run's config (seed, frames, checkpoints, rooms)
//! OUT/runs/<name>/            the training run (`up`), name = <method>[-<scene type>]-seed<k>, with
//!     select/ckpt-N/tables.csv    each checkpoint on val
//!     test/tables.csv             the selected checkpoint on test (normal, blind, other_gesture)
//!     train/tables.csv            the selected checkpoint on train (T4.3)
//! OUT/random/seed<k>/tables.csv   Random on test
//! OUT/T4.2.md … T4.7.md, pointing.md, .csv, paired.md, study.json, sr_spl.png, learning_curves.png
//! ```
//!
//! With `--parallel N`, N models are in flight at once (`lanes`), each with its own steps; the
//! tables are rewritten as each finishes, one writer at a time, and list the models in the plan's
//! order.
//!
//! With `--publish DIR` (e.g. docs/study) the tables and figures go into DIR as well, with each
//! finished model's record (`records`): a model recorded there is not trained again, so the
//! study continues from a clone on a machine without OUT.

pub mod ablations;
mod args;
mod lanes;
mod paired;
mod plan;
mod progress;
pub mod records;
mod stages;
pub mod steps;
pub mod summary;

use std::path::{Path, PathBuf};

use anyhow::Context;
use farm::config::RunConfig;
use farm::rooms::Split;

pub use args::StudyArgs;
use plan::{Layout, Run, plan};
use progress::{Kind, Lane, StepBar};
use steps::{Eval, evaluate, s};
use summary::RunResult;

pub fn run(a: StudyArgs) -> anyhow::Result<()> {
    farm::process::install_termination_handler()?;
    let (runs, random) = plan(&a)?;
    write_configs(&runs)?;
    let random_seeds = if random.is_some() { a.seeds } else { 0 };
    let steps = planned_steps(&a, &runs, random_seeds);
    let lanes = a.parallel.min(runs.len()).max(1);
    let progress = StepBar::new(&steps, lanes);
    eprintln!(
        "[study] {} runs ({} frames each, {} workers{}) and Random × {random_seeds} seeds in {}",
        runs.len(),
        a.frames,
        a.workers,
        if lanes > 1 { format!("; {lanes} at once") } else { String::new() },
        a.out.display()
    );
    let random_names: Vec<String> = (1..=random_seeds).map(|k| format!("Random seed {k}")).collect();
    let settings =
        records::Settings { checkpoints: a.checkpoints, val_programs: a.val_programs, test_programs: a.test_programs };
    // each model's result at its place in the plan: the tables list the models in the plan's
    // order however the lanes finish
    let mut done: Vec<Option<RunResult>> = vec![None; runs.len()];
    let jobs: Vec<(&Run, &[(Kind, f64)])> = runs.iter().zip(steps.chunks(4)).collect();
    lanes::run(
        &jobs,
        lanes,
        |lane, (run, planned)| stages::model(&a, run, planned, settings, &progress.lane(lane)),
        |i, r| {
            done[i] = Some(r);
            let results: Vec<RunResult> = done.iter().flatten().cloned().collect();
            let pending = runs.iter().zip(&done).filter(|(_, d)| d.is_none()).map(|(r, _)| r.name());
            // every finished model's tables at once: a study stopped later loses only the
            // models in flight
            report(
                &a,
                &runs,
                random.as_ref(),
                &results,
                &pending.chain(random_names.iter().cloned()).collect::<Vec<_>>(),
            )
        },
    )?;
    let mut results: Vec<RunResult> = done.into_iter().flatten().collect();
    if let Some(cfg) = &random {
        let lane = progress.lane(0);
        for k in 1..=a.seeds {
            results.push(random_seed(&a, cfg, k, settings, &lane)?);
        }
    }
    progress.finish();
    report(&a, &runs, random.as_ref(), &results, &[])?;
    eprintln!("[study] tables in {}", a.out.join("T4.2.md").display());
    Ok(())
}

/// Each run's config, as its children read it (written once: a continued study keeps them).
fn write_configs(runs: &[Run]) -> anyhow::Result<()> {
    for r in runs {
        if !r.config_path.is_file() {
            farm::files::write_atomic(&r.config_path, r.cfg.to_toml().as_bytes())
                .with_context(|| format!("writing {}", r.config_path.display()))?;
        }
    }
    Ok(())
}

/// The work of every step, for the ETA: per run train, select (one step for all of its
/// checkpoints), test, train split; then Random's evaluations.
fn planned_steps(a: &StudyArgs, runs: &[Run], random_seeds: u64) -> Vec<(Kind, f64)> {
    let mut steps = Vec::new();
    for r in runs {
        let left = r.updates_needed(a.workers).saturating_sub(r.latest_update()) * r.frames_per_update(a.workers);
        steps.push((Kind::Train, left as f64));
        steps.push((Kind::Eval, ((a.checkpoints + 1) as usize * a.val_programs) as f64));
        steps.push((Kind::Eval, (a.test_programs * r.test_modes().len()) as f64));
        steps.push((Kind::Eval, a.val_programs as f64));
    }
    steps.extend((0..random_seeds).map(|_| (Kind::Eval, a.test_programs as f64)));
    steps
}

/// Random with the config's seed plus `k` − 1, on test (or as recorded under `--publish`).
fn random_seed(
    a: &StudyArgs,
    cfg: &RunConfig,
    k: u64,
    settings: records::Settings,
    lane: &Lane,
) -> anyhow::Result<RunResult> {
    let mut c = cfg.clone();
    c.run.seed = cfg.run.seed + k - 1;
    let name = format!("random-seed{k}");
    if let Some(p) = &a.publish
        && let Some(r) = records::read(p, &name, &c, settings)?
    {
        lane.step(Kind::Eval, a.test_programs as f64, None, "recorded");
        return Ok(r);
    }
    let path = Layout(&a.out).config(&name);
    farm::files::write_atomic(&path, c.to_toml().as_bytes())?;
    let e = Eval {
        what: vec!["--config".into(), s(&path)],
        split: Split::Test,
        programs: a.test_programs,
        modes: &["normal"],
        rooms: vec![],
        out: Layout(&a.out).random(k),
    };
    evaluate(a.workers, &e, lane, &format!("Random seed {k} on test"))?;
    let r = RunResult::read("random", None, k, Path::new("-"), f64::NAN, &e.out.join("tables.csv"))?;
    match &a.publish {
        Some(p) => records::write(p, &name, &c, settings, &r, None),
        None => Ok(r),
    }
}

/// Writes T4.2–T4.7 of the models evaluated so far into the study folder (and `--publish`);
/// `pending` names the runs still to do; `random` is Random's config when the study evaluates it.
fn report(
    a: &StudyArgs,
    runs: &[Run],
    random: Option<&RunConfig>,
    results: &[RunResult],
    pending: &[String],
) -> anyhow::Result<()> {
    // each run's training curve: its metrics, or its record's when the run folder is elsewhere
    let curves: Vec<(String, PathBuf)> = runs
        .iter()
        .filter(|r| r.scene_type.is_none() && results.iter().any(|x| x.stem == r.method.stem && x.seed == r.seed_index))
        .filter_map(|r| {
            let metrics = r.dir.join("metrics.jsonl");
            let recorded = a.publish.as_ref().and_then(|p| records::curve(p, &r.file_name()));
            let path = if r.trained(a.workers) && metrics.is_file() { Some(metrics) } else { recorded };
            path.map(|p| (r.method.stem.to_string(), p))
        })
        .collect();
    // the test programs of the study's dataset (every config of the study has the same)
    let facts = runs.first().map(|r| &r.cfg).or(random).and_then(paired::program_facts);
    let tables = |dir: &Path, results: &[RunResult], curves: &[(String, PathBuf)]| -> anyhow::Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        summary::write(dir, results, curves, pending)?;
        ablations::write(dir, results)?;
        paired::write(dir, results, facts.as_ref())
    };
    tables(&a.out, results, &curves)?;
    if let Some(p) = &a.publish {
        // the published tables hold every model recorded there, of this invocation or another
        // (a study of some methods must not drop the others' rows)
        let (mut all, mut curves) = (results.to_vec(), curves);
        for (r, curve) in records::all(p)? {
            let same =
                |x: &RunResult| (x.stem.as_str(), x.seed, x.scene_type) == (r.stem.as_str(), r.seed, r.scene_type);
            if !all.iter().any(same) {
                if let Some(c) = curve.filter(|_| r.scene_type.is_none()) {
                    curves.push((r.stem.clone(), c));
                }
                all.push(r);
            }
        }
        tables(p, &all, &curves)?;
    }
    Ok(())
}
