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
mod lanes;
mod paired;
mod progress;
pub mod records;
pub mod steps;
pub mod summary;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use farm::config::{Method, RunConfig};
use farm::rooms::{SceneId, SceneType, Split};

use progress::{Kind, Lane, Progress};
use steps::{Eval, evaluate, orchestrator, s};
use summary::{METHODS, RunResult, StudyMethod};

#[derive(Args, Debug, Clone)]
pub struct StudyArgs {
    /// Folder of run configs named after the methods (vision_only, vis_sem, referencing,
    /// intervention, both, random; T4.7's rgb_sem_both and depth_sem_both), e.g. configs/tiny.
    #[arg(long)]
    pub configs: PathBuf,
    /// Seeds per method (1..=N, each the config's seed plus k − 1).
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Frames to train each run for.
    #[arg(long)]
    pub frames: u64,
    /// The study folder (created; an existing one is continued).
    #[arg(long)]
    pub out: PathBuf,
    /// Only these methods (config file stems), comma-separated, trained in this order (seed by
    /// seed); default: every one present, in T4.2's order.
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Also train VisSem, +Referencing and +Intervention once per scene type, in that type's
    /// rooms only, as the dissertation does for T4.3/T4.4 (12 more runs per seed).
    #[arg(long)]
    pub per_scene_type: bool,
    #[arg(long, default_value_t = 4, value_parser = crate::commands::values::workers)]
    pub workers: usize,
    /// Checkpoints per run to choose from on val (evenly spaced; the last one always).
    #[arg(long, default_value_t = 5)]
    pub checkpoints: u64,
    /// Val programs per checkpoint evaluation (spread over the val rooms); as many train
    /// programs evaluate the selected checkpoint on train (T4.3).
    #[arg(long, default_value_t = 500)]
    pub val_programs: usize,
    /// Test programs per evaluation (spread over the test rooms).
    #[arg(long, default_value_t = 1000)]
    pub test_programs: usize,
    /// Override a config value, e.g. `--set ppo.lr=1e-4` (repeatable; checked as the file is;
    /// the effective config is the one written into each run directory).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Train and evaluate every method on this dataset instead of the configs' `run.dataset`
    /// (e.g. one built with `dataset build --pointing realistic`).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Also write the tables and figures here (e.g. docs/study), with each finished model's
    /// record (its result, evaluation tables and training curve; no checkpoints): a model
    /// recorded here is taken as done, so a clone continues the study without OUT.
    #[arg(long)]
    pub publish: Option<PathBuf>,
    /// Models trained at once, each its own crew of --workers workers and a learner, all on this
    /// machine's cores and GPU, publishing into the one --out (and --publish); 1: one after
    /// another. It changes only the wall time: each model keeps its config, seed and frame
    /// budget. On a machine of few cores (two) more than 1 mostly makes the crews compete for
    /// the same cores.
    #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub parallel: usize,
}

/// One training run of the study.
#[derive(Clone, Debug)]
pub struct Run {
    pub method: StudyMethod,
    /// Trained, selected and tested in this type's rooms only (`--per-scene-type`).
    pub scene_type: Option<SceneType>,
    pub seed_index: u64,
    pub cfg: RunConfig,
    pub dir: PathBuf,
    pub config_path: PathBuf,
}

impl Run {
    /// The passes of its test evaluation: normal and blind (T4.6), and where the policy is shown
    /// the referencing gesture, another room's gesture (is where the arm points read?).
    fn test_modes(&self) -> &'static [&'static str] {
        if self.cfg.run.method.shows_referencing() {
            &["normal", "blind", "other_gesture"]
        } else {
            &["normal", "blind"]
        }
    }

    /// Frames one PPO update consumes.
    fn frames_per_update(&self, workers: usize) -> u64 {
        (self.cfg.ppo.rollout * workers * self.cfg.env.envs_per_worker) as u64
    }

    /// Updates a complete run has made.
    fn updates_needed(&self, workers: usize) -> u64 {
        (self.cfg.run.total_frames / self.frames_per_update(workers)).max(1)
    }

    fn latest_update(&self) -> u64 {
        farm::checkpoints::list(&farm::checkpoints::dir_of(&self.dir)).last().map_or(0, |(u, _)| *u)
    }

    fn trained(&self, workers: usize) -> bool {
        self.latest_update() >= self.updates_needed(workers)
    }

    /// The checkpoints val chooses from: the evenly spaced ones and the final one. A checkpoint
    /// written when the run was stopped part-way is not among them, so a study that was stopped
    /// and continued chooses from the same candidates as one that ran through.
    fn candidates(&self, workers: usize) -> Vec<PathBuf> {
        let (every, last) = (self.cfg.checkpoint.every_updates.max(1), self.updates_needed(workers));
        farm::checkpoints::list(&farm::checkpoints::dir_of(&self.dir))
            .into_iter()
            .filter(|(u, _)| u % every == 0 || *u >= last)
            .map(|(_, ckpt)| ckpt)
            .collect()
    }

    fn select_dir(&self, ckpt: &Path) -> PathBuf {
        self.dir.join("select").join(ckpt.file_stem().unwrap_or_default())
    }

    /// The rooms of `split` this run is evaluated in (`--scenes`; empty: all of them).
    fn rooms(&self, split: Split) -> Vec<String> {
        self.scene_type.map_or_else(Vec::new, |t| rooms_of(t, split))
    }

    /// The run's folder and record name, e.g. `both-seed1`.
    fn file_name(&self) -> String {
        self.dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    }

    fn name(&self) -> String {
        let rooms = self.scene_type.map(|t| format!(" in {} rooms", t.name())).unwrap_or_default();
        format!("{}{rooms} seed {}", self.method.label, self.seed_index)
    }
}

fn rooms_of(t: SceneType, split: Split) -> Vec<String> {
    SceneId::of_split(split).filter(|s| s.scene_type == t).map(SceneId::name).collect()
}

/// The methods T4.3/T4.4 train once per scene type.
const PER_SCENE_TYPE: [&str; 3] = ["vis_sem", "referencing", "intervention"];

/// What the study will do, from the config folder: its learning runs and Random's seeds.
pub fn plan(a: &StudyArgs) -> anyhow::Result<(Vec<Run>, Option<RunConfig>)> {
    anyhow::ensure!(a.seeds > 0, "--seeds: at least one");
    anyhow::ensure!(a.frames > 0, "--frames: give a positive count");
    anyhow::ensure!(a.checkpoints > 0, "--checkpoints: at least one");
    for m in &a.methods {
        anyhow::ensure!(
            summary::method(m).is_some(),
            "--methods: `{m}` is not one of {}",
            METHODS.map(|m| m.stem).join(", ")
        );
    }
    let mut runs = Vec::new();
    let mut random = None;
    // T4.2's order, or the order asked for (the first methods of a long study finish first)
    let order: Vec<StudyMethod> = match a.methods.is_empty() {
        true => METHODS.to_vec(),
        false => a.methods.iter().filter_map(|m| summary::method(m)).collect(),
    };
    for sm in order {
        let stem = sm.stem;
        let path = a.configs.join(format!("{stem}.toml"));
        if !path.is_file() {
            anyhow::ensure!(a.methods.is_empty(), "--methods {stem}: no {}", path.display());
            continue;
        }
        let mut cfg = RunConfig::load(&path)?.with_overrides(&a.set)?;
        if let Some(d) = &a.dataset {
            cfg.run.dataset = d.clone();
        }
        anyhow::ensure!(
            cfg.run.method == sm.method,
            "{}: run.method is {:?}, the file name says {stem}",
            path.display(),
            cfg.run.method
        );
        if sm.method == Method::Random {
            random = Some(cfg);
            continue;
        }
        anyhow::ensure!(
            (cfg.model.rgb, cfg.model.depth) == (sm.rgb, sm.depth),
            "{}: model.rgb = {}, model.depth = {}; {stem} needs {} and {}",
            path.display(),
            cfg.model.rgb,
            cfg.model.depth,
            sm.rgb,
            sm.depth
        );
        let types: Vec<Option<SceneType>> = std::iter::once(None)
            .chain(SceneType::ALL.into_iter().map(Some).filter(|_| a.per_scene_type && PER_SCENE_TYPE.contains(&stem)))
            .collect();
        for t in types {
            for k in 1..=a.seeds {
                let mut c = cfg.clone();
                c.run.seed = cfg.run.seed + k - 1;
                c.run.total_frames = a.frames;
                // every training room (of the type), as §4.4.1 (the tiny configs pick 8 for
                // short single runs)
                c.run.scenes = t.map_or_else(Vec::new, |t| rooms_of(t, Split::Train));
                let name = match t {
                    Some(t) => format!("{stem}-{}-seed{k}", t.name().to_ascii_lowercase()),
                    None => format!("{stem}-seed{k}"),
                };
                let mut run = Run {
                    method: sm,
                    scene_type: t,
                    seed_index: k,
                    cfg: c,
                    dir: a.out.join("runs").join(&name),
                    config_path: a.out.join("configs").join(format!("{name}.toml")),
                };
                // keep every checkpoint, `checkpoints` of them evenly spaced (the final one is
                // written at the end of the run whatever the spacing)
                run.cfg.checkpoint.keep = 0;
                run.cfg.checkpoint.every_updates = (run.updates_needed(a.workers) / a.checkpoints).max(1);
                runs.push(run);
            }
        }
    }
    // seed by seed: a study stopped part-way has every method at its first seeds (stable: the
    // methods keep T4.2's order within a seed)
    runs.sort_by_key(|r| r.seed_index);
    anyhow::ensure!(
        !runs.is_empty() || random.is_some(),
        "{}: no config named after a method of T4.2 or T4.7 ({}.toml)",
        a.configs.display(),
        METHODS.map(|m| m.stem).join(".toml, ")
    );
    Ok((runs, random))
}

/// Trains `run` to its frame budget: from scratch, or on from its newest checkpoint.
fn train(a: &StudyArgs, run: &Run) -> anyhow::Result<()> {
    let fpu = run.frames_per_update(a.workers);
    let left = run.updates_needed(a.workers) - run.latest_update();
    // one round past the last update boundary, so that the last update runs
    let frames = (left * fpu + (a.workers * run.cfg.env.envs_per_worker) as u64).to_string();
    let workers = a.workers.to_string();
    let log = run.dir.with_extension("log");
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

pub fn run(a: StudyArgs) -> anyhow::Result<()> {
    farm::process::install_termination_handler()?;
    let (runs, random) = plan(&a)?;
    std::fs::create_dir_all(a.out.join("configs"))?;
    for r in &runs {
        if !r.config_path.is_file() {
            farm::files::write_atomic(&r.config_path, r.cfg.to_toml().as_bytes())
                .with_context(|| format!("writing {}", r.config_path.display()))?;
        }
    }
    let random_seeds = if random.is_some() { a.seeds } else { 0 };
    // per run: train, select (one step for all of its checkpoints), test, train split; then
    // Random's evaluations
    let mut steps = Vec::new();
    for r in &runs {
        let left = r.updates_needed(a.workers).saturating_sub(r.latest_update()) * r.frames_per_update(a.workers);
        steps.push((Kind::Train, left as f64));
        steps.push((Kind::Eval, ((a.checkpoints + 1) as usize * a.val_programs) as f64));
        steps.push((Kind::Eval, (a.test_programs * r.test_modes().len()) as f64));
        steps.push((Kind::Eval, a.val_programs as f64));
    }
    steps.extend((0..random_seeds).map(|_| (Kind::Eval, a.test_programs as f64)));
    let lanes = a.parallel.min(runs.len()).max(1);
    let progress = Progress::new(&steps, lanes);
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
        |lane, (run, planned)| model(&a, run, planned, settings, &progress.lane(lane)),
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
    let lane = progress.lane(0);
    if let Some(cfg) = &random {
        for k in 1..=a.seeds {
            let mut c = cfg.clone();
            c.run.seed = cfg.run.seed + k - 1;
            let name = format!("random-seed{k}");
            if let Some(p) = &a.publish
                && let Some(r) = records::read(p, &name, &c, settings)?
            {
                lane.step(Kind::Eval, a.test_programs as f64, None, "recorded");
                results.push(r);
                continue;
            }
            let path = a.out.join("configs").join(format!("{name}.toml"));
            farm::files::write_atomic(&path, c.to_toml().as_bytes())?;
            let e = Eval {
                what: vec!["--config".into(), s(&path)],
                split: Split::Test,
                programs: a.test_programs,
                modes: &["normal"],
                rooms: vec![],
                out: a.out.join("random").join(format!("seed{k}")),
            };
            evaluate(a.workers, &e, &lane, &format!("Random seed {k} on test"))?;
            let mut r = RunResult::read("random", None, k, Path::new("-"), f64::NAN, &e.out.join("tables.csv"))?;
            if let Some(p) = &a.publish {
                r = records::write(p, &name, &c, settings, &r, None)?;
            }
            results.push(r);
        }
    }
    progress.finish();
    report(&a, &runs, random.as_ref(), &results, &[])?;
    eprintln!("[study] tables in {}", a.out.join("T4.2.md").display());
    Ok(())
}

/// One model's pipeline, as `lane`: train it, select its checkpoint on val, test that one and
/// evaluate it on train, record it (`--publish`); a model recorded there is taken as it is.
fn model(
    a: &StudyArgs,
    run: &Run,
    planned: &[(Kind, f64)],
    settings: records::Settings,
    lane: &Lane,
) -> anyhow::Result<RunResult> {
    let name = run.name();
    if let Some(p) = &a.publish
        && let Some(r) = records::read(p, &run.file_name(), &run.cfg, settings)?
    {
        for (k, (kind, work)) in planned.iter().enumerate() {
            lane.step(*kind, *work, None, if k == 0 { "recorded" } else { "" });
        }
        eprintln!("[study] {name}: recorded in {}", p.join("records").join(run.file_name()).display());
        records::add_outcomes(p, &run.file_name(), &r, &run.dir.join("test"))?;
        return Ok(r);
    }
    let trained = run.trained(a.workers);
    let t = Instant::now();
    if !trained {
        lane.doing(&format!("training {name}"));
        train(a, run)?;
        anyhow::ensure!(run.trained(a.workers), "{}: the run ended before its last update", run.dir.display());
    }
    lane.step(Kind::Train, planned[0].1, (!trained).then(|| t.elapsed().as_secs_f64()), &format!("trained {name}"));

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
    let (val_sr1, chosen, chosen_frames) = best.with_context(|| format!("{}: no checkpoint", run.dir.display()))?;
    lane.step(Kind::Eval, work, ran.then(|| t.elapsed().as_secs_f64()), &format!("selected {name} on val"));

    // the test and train evaluations are of the selected checkpoint: redone when val chose another
    let on = |split: Split, programs: usize, modes: &'static [&'static str], dir: &str| Eval {
        what: vec!["--checkpoint".into(), s(&chosen)],
        split,
        programs,
        modes,
        rooms: run.rooms(split),
        out: run.dir.join(dir),
    };
    let (test, fit) = (
        on(Split::Test, a.test_programs, run.test_modes(), "test"),
        on(Split::Train, a.val_programs, &["normal"], "train"),
    );
    for e in [&test, &fit] {
        let stale = std::fs::read_to_string(e.out.join("checkpoint")).ok().is_some_and(|c| c.trim() != s(&chosen));
        if stale {
            std::fs::remove_dir_all(&e.out)?;
        }
    }
    evaluate(a.workers, &test, lane, &format!("tested {name}"))?;
    farm::files::write_atomic(&test.out.join("checkpoint"), s(&chosen).as_bytes())?;
    evaluate(a.workers, &fit, lane, &format!("evaluated {name} on train"))?;
    farm::files::write_atomic(&fit.out.join("checkpoint"), s(&chosen).as_bytes())?;

    let mut r = RunResult::read(
        run.method.stem,
        run.scene_type,
        run.seed_index,
        // named inside the study folder, as its record keeps it
        chosen.strip_prefix(&a.out).unwrap_or(&chosen),
        val_sr1,
        &test.out.join("tables.csv"),
    )?;
    r.val_tables = Some(run.select_dir(&chosen).join("tables.csv"));
    r.train_tables = Some(fit.out.join("tables.csv"));
    r.val_curve = val_curve;
    let update = farm::checkpoints::update_of(&chosen).unwrap_or(0);
    r.budget = Some(summary::Budget {
        frames: chosen_frames,
        adam_steps: update * (run.cfg.ppo.epochs * run.cfg.ppo.minibatches) as u64,
        frames_per_update: run.frames_per_update(a.workers),
    });
    if let Some(p) = &a.publish {
        r = records::write(p, &run.file_name(), &run.cfg, settings, &r, Some(&run.dir.join("metrics.jsonl")))?;
    }
    Ok(r)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn args(dir: &Path) -> StudyArgs {
        StudyArgs {
            configs: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/tiny"),
            seeds: 2,
            frames: 40_960,
            out: dir.to_path_buf(),
            methods: vec![],
            per_scene_type: false,
            workers: 4,
            checkpoints: 5,
            val_programs: 100,
            test_programs: 100,
            dataset: None,
            publish: None,
            set: Vec::new(),
            parallel: 1,
        }
    }

    #[test]
    fn the_plan_has_every_learning_method_per_seed_and_random_apart() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, random) = plan(&args(dir.path())).unwrap();
        assert_eq!(runs.len(), 7 * 2, "T4.2's five learning methods and T4.7's two variants");
        assert!(random.is_some());
        let order: Vec<(&str, u64)> = runs.iter().map(|r| (r.method.stem, r.seed_index)).collect();
        assert_eq!(&order[..2], [("vision_only", 1), ("vis_sem", 1)], "seed by seed, in T4.2's order");
        let mut asked = args(dir.path());
        asked.methods = vec!["both".into(), "vis_sem".into()];
        let (runs2, random) = plan(&asked).unwrap();
        let order: Vec<(&str, u64)> = runs2.iter().map(|r| (r.method.stem, r.seed_index)).collect();
        assert_eq!(order, [("both", 1), ("vis_sem", 1), ("both", 2), ("vis_sem", 2)], "in the order asked for");
        assert!(random.is_none());
        let both2 = runs.iter().find(|r| r.method.stem == "both" && r.seed_index == 2).unwrap();
        assert_eq!(both2.cfg.run.seed, 2, "seeds 1 and 2 from the config's seed 1");
        assert_eq!(both2.cfg.run.total_frames, 40_960);
        // 4 workers × 8 envs × 128 steps = 4,096 frames an update: 10 updates, one checkpoint in 2
        assert_eq!(
            (both2.updates_needed(4), both2.cfg.checkpoint.every_updates, both2.cfg.checkpoint.keep),
            (10, 2, 0)
        );
        assert!(both2.dir.ends_with("runs/both-seed2"));
        assert!(both2.cfg.run.scenes.is_empty(), "the study trains in all 80 training rooms");
    }

    #[test]
    fn val_chooses_from_the_spaced_and_final_checkpoints_not_one_written_at_a_stop() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, _) = plan(&args(dir.path())).unwrap();
        let run = &runs[0];
        // 10 updates, one checkpoint in 2; the run was stopped at update 3 and continued
        let ckpts = farm::checkpoints::dir_of(&run.dir);
        std::fs::create_dir_all(&ckpts).unwrap();
        for u in [2, 3, 4, 6, 8, 10] {
            std::fs::write(farm::checkpoints::path(&ckpts, u), b"").unwrap();
        }
        let chosen_from: Vec<u64> =
            run.candidates(4).iter().map(|p| farm::checkpoints::update_of(p).unwrap()).collect();
        assert_eq!(chosen_from, [2, 4, 6, 8, 10], "as a study that ran through");
    }

    #[test]
    fn t47_variants_and_per_scene_type_runs_are_planned_apart() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path());
        a.seeds = 1;
        a.per_scene_type = true;
        let (runs, _) = plan(&a).unwrap();
        // 7 models in every room (T4.2's five, T4.7's two), 3 methods × 4 scene types
        assert_eq!(runs.len(), 7 + 12, "{:?}", runs.iter().map(|r| r.dir.clone()).collect::<Vec<_>>());
        let rgb = runs.iter().find(|r| r.method.stem == "rgb_sem_both").unwrap();
        assert!(rgb.cfg.model.rgb && !rgb.cfg.model.depth && rgb.cfg.run.method == Method::Both);
        let bath =
            runs.iter().find(|r| r.method.stem == "intervention" && r.scene_type == Some(SceneType::Bathroom)).unwrap();
        assert!(bath.dir.ends_with("runs/intervention-bathroom-seed1"));
        assert_eq!(bath.cfg.run.scenes.len(), 20);
        assert!(bath.cfg.run.scenes.iter().all(|s| SceneId::parse(s).unwrap().scene_type == SceneType::Bathroom));
        assert_eq!(
            bath.rooms(Split::Test),
            ["FloorPlan426", "FloorPlan427", "FloorPlan428", "FloorPlan429", "FloorPlan430"]
        );
        assert!(runs.iter().all(|r| r.scene_type.is_none() || PER_SCENE_TYPE.contains(&r.method.stem)));
        // a variant whose inputs contradict its name
        std::fs::create_dir_all(dir.path().join("c")).unwrap();
        let both = std::fs::read_to_string(a.configs.join("both.toml")).unwrap();
        std::fs::write(dir.path().join("c/depth_sem_both.toml"), both).unwrap();
        a.configs = dir.path().join("c");
        let e = plan(&a).unwrap_err().to_string();
        assert!(e.contains("depth_sem_both.toml") && e.contains("model.rgb = true"), "{e}");
    }

    #[test]
    fn unknown_or_missing_methods_are_one_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path());
        a.methods = vec!["bothh".into()];
        assert!(plan(&a).unwrap_err().to_string().contains("`bothh`"));
        a.configs = dir.path().to_path_buf();
        a.methods = vec![];
        let e = plan(&a).unwrap_err().to_string();
        assert!(e.contains("no config named after a method"), "{e}");
    }
}
