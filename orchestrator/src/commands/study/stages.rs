//! One model's pipeline, stage by stage: train it, select its checkpoint on val, test that one
//! (and evaluate it on train), record it. Each stage skips itself when its output is there, so
//! the same command continues a study stopped at any point.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use farm::rooms::Split;

use super::args::StudyArgs;
use super::plan::Run;
use super::progress::{Kind, Lane};
use super::records;
use super::steps::{Eval, evaluate, orchestrator, s};
use super::summary::{self, RunResult};

/// One model's pipeline, as `lane`: train it, select its checkpoint on val, test that one and
/// evaluate it on train, record it (`--publish`); a model recorded there is taken as it is.
pub fn model(
    a: &StudyArgs,
    run: &Run,
    planned: &[(Kind, f64)],
    settings: records::Settings,
    lane: &Lane,
) -> anyhow::Result<RunResult> {
    if let Some(r) = recorded(a, run, planned, settings, lane)? {
        return Ok(r);
    }
    train_stage(a, run, planned[0].1, lane)?;
    let chosen = select_stage(a, run, lane)?;
    let (test, fit) = test_stage(a, run, &chosen.ckpt, lane)?;
    let r = result(a, run, &chosen, &test, &fit)?;
    match &a.publish {
        Some(p) => records::write(p, &run.file_name(), &run.cfg, settings, &r, Some(&run.dir.join("metrics.jsonl"))),
        None => Ok(r),
    }
}

/// The model's record under `--publish`, if it has one: its steps counted as done.
fn recorded(
    a: &StudyArgs,
    run: &Run,
    planned: &[(Kind, f64)],
    settings: records::Settings,
    lane: &Lane,
) -> anyhow::Result<Option<RunResult>> {
    let Some(p) = &a.publish else { return Ok(None) };
    let Some(r) = records::read(p, &run.file_name(), &run.cfg, settings)? else { return Ok(None) };
    for (k, (kind, work)) in planned.iter().enumerate() {
        lane.step(*kind, *work, None, if k == 0 { "recorded" } else { "" });
    }
    eprintln!("[study] {}: recorded in {}", run.name(), p.join("records").join(run.file_name()).display());
    records::add_outcomes(p, &run.file_name(), &r, &run.test_dir())?;
    Ok(Some(r))
}

/// Trains the run to its frame budget unless it is there.
fn train_stage(a: &StudyArgs, run: &Run, work: f64, lane: &Lane) -> anyhow::Result<()> {
    let name = run.name();
    let trained = run.trained(a.workers);
    let t = Instant::now();
    if !trained {
        lane.doing(&format!("training {name}"));
        train(a, run)?;
        anyhow::ensure!(run.trained(a.workers), "{}: the run ended before its last update", run.dir.display());
    }
    lane.step(Kind::Train, work, (!trained).then(|| t.elapsed().as_secs_f64()), &format!("trained {name}"));
    Ok(())
}

/// The checkpoint val chose, with what it was chosen by.
struct Chosen {
    ckpt: PathBuf,
    frames: u64,
    val_sr1: f64,
    /// (frames, SR at the first stop on val) of every candidate.
    val_curve: Vec<(u64, f64)>,
}

/// Evaluates every candidate checkpoint on val (those evaluated already are read) and takes the
/// best by SR at the first stop, the later one on a tie.
fn select_stage(a: &StudyArgs, run: &Run, lane: &Lane) -> anyhow::Result<Chosen> {
    let name = run.name();
    let (mut ran, mut work) = (false, 0.0);
    let mut best: Option<(f64, PathBuf, u64)> = None;
    let mut val_curve = Vec::new();
    let t = Instant::now();
    lane.doing(&format!("selecting {name} on val"));
    for ckpt in run.candidates(a.workers) {
        let e = Eval {
            what: vec!["--checkpoint".into(), s(&ckpt)],
            split: Split::Val,
            programs: a.val_programs,
            modes: &["normal"],
            rooms: run.rooms(Split::Val),
            out: run.select_dir(&ckpt),
        };
        ran |= e.run(a.workers)?;
        work += e.work();
        let sr1 = summary::first_stop(&e.out.join("tables.csv"))?.sr;
        let frames = farm::checkpoints::frames(&ckpt).map_err(|e| anyhow::anyhow!("{}: {e}", ckpt.display()))?;
        val_curve.push((frames, sr1));
        if best.as_ref().is_none_or(|(b, _, _)| sr1 >= *b) {
            best = Some((sr1, ckpt, frames));
        }
    }
    let (val_sr1, ckpt, frames) = best.with_context(|| format!("{}: no checkpoint", run.dir.display()))?;
    lane.step(Kind::Eval, work, ran.then(|| t.elapsed().as_secs_f64()), &format!("selected {name} on val"));
    Ok(Chosen { ckpt, frames, val_sr1, val_curve })
}

/// Evaluates the chosen checkpoint on test and on train; an evaluation of another checkpoint
/// (val chose another since) is redone.
fn test_stage<'a>(a: &StudyArgs, run: &'a Run, chosen: &Path, lane: &Lane) -> anyhow::Result<(Eval<'a>, Eval<'a>)> {
    let name = run.name();
    let on = |split: Split, programs: usize, modes: &'a [&'a str], out: PathBuf| Eval {
        what: vec!["--checkpoint".into(), s(chosen)],
        split,
        programs,
        modes,
        rooms: run.rooms(split),
        out,
    };
    let test = on(Split::Test, a.test_programs, run.test_modes(), run.test_dir());
    let fit = on(Split::Train, a.val_programs, &["normal"], run.train_dir());
    for e in [&test, &fit] {
        let stale = std::fs::read_to_string(e.out.join("checkpoint")).ok().is_some_and(|c| c.trim() != s(chosen));
        if stale {
            std::fs::remove_dir_all(&e.out)?;
        }
    }
    evaluate(a.workers, &test, lane, &format!("tested {name}"))?;
    farm::files::write_atomic(&test.out.join("checkpoint"), s(chosen).as_bytes())?;
    evaluate(a.workers, &fit, lane, &format!("evaluated {name} on train"))?;
    farm::files::write_atomic(&fit.out.join("checkpoint"), s(chosen).as_bytes())?;
    Ok((test, fit))
}

/// The model's result: its test tables, with its val and train tables, val curve and budget.
fn result(a: &StudyArgs, run: &Run, chosen: &Chosen, test: &Eval, fit: &Eval) -> anyhow::Result<RunResult> {
    let ckpt = &chosen.ckpt;
    let mut r = RunResult::read(
        run.method.stem,
        run.scene_type,
        run.seed_index,
        // named inside the study folder, as its record keeps it
        ckpt.strip_prefix(&a.out).unwrap_or(ckpt),
        chosen.val_sr1,
        &test.out.join("tables.csv"),
    )?;
    r.val_tables = Some(run.select_dir(ckpt).join("tables.csv"));
    r.train_tables = Some(fit.out.join("tables.csv"));
    r.val_curve = chosen.val_curve.clone();
    let update = farm::checkpoints::update_of(ckpt).unwrap_or(0);
    r.budget = Some(summary::Budget {
        frames: chosen.frames,
        adam_steps: update * (run.cfg.ppo.epochs * run.cfg.ppo.minibatches) as u64,
        frames_per_update: run.frames_per_update(a.workers),
    });
    Ok(r)
}

/// Trains `run` to its frame budget: from scratch, or on from its newest checkpoint.
fn train(a: &StudyArgs, run: &Run) -> anyhow::Result<()> {
    let fpu = run.frames_per_update(a.workers);
    let left = run.updates_needed(a.workers) - run.latest_update();
    // one round past the last update boundary, so that the last update runs
    let frames = (left * fpu + (a.workers * run.cfg.env.envs_per_worker) as u64).to_string();
    let workers = a.workers.to_string();
    let log = run.log();
    if run.latest_update() > 0 {
        orchestrator(
            &["up".into(), "--resume".into(), s(&run.dir), "--workers".into(), workers, "--frames".into(), frames],
            &log,
        )
    } else {
        if run.dir.exists() {
            // a run killed before its first checkpoint: nothing in it to keep
            std::fs::remove_dir_all(&run.dir).with_context(|| format!("clearing {}", run.dir.display()))?;
        }
        let args = [
            "up",
            "--config",
            &s(&run.config_path),
            "--run-dir",
            &s(&run.dir),
            "--workers",
            &workers,
            "--frames",
            &frames,
        ];
        orchestrator(&args.map(String::from), &log)
    }
}
