//! The study (§4.4.1, T4.2): every method of a config folder that learns, trained with N seeds
//! for F frames each; each run's checkpoints evaluated on val and the best by SR at the first
//! stop evaluated on test; Random evaluated on test with the same seeds. One table puts the
//! dissertation's figures beside ours (mean ± std over the seeds, `crate::study_report`).
//!
//! Every step is a child `orchestrator up` or `orchestrator eval` writing into the study folder,
//! and a step whose output is complete is never run again: killed at any point, the same
//! command continues — finished runs are kept, a run with checkpoints resumes from its newest,
//! an evaluation without its tables runs again.
//!
//! ```text
//! OUT/configs/<method>-seed<k>.toml   the run's config (seed, frames, checkpoints)
//! OUT/runs/<method>-seed<k>/          the training run (`up`), with
//!     select/ckpt-N/tables.csv        each checkpoint on val
//!     test/tables.csv                 the selected checkpoint on test
//! OUT/random/seed<k>/tables.csv       Random on test
//! OUT/T4.2.md, OUT/T4.2.csv, OUT/study.json
//! ```

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use farm::config::{Method, RunConfig};

use crate::study_report::{self, METHODS, RunResult};

#[derive(Args, Debug, Clone)]
pub struct StudyArgs {
    /// Folder of run configs named after the methods (vision_only, vis_sem, referencing,
    /// intervention, both, random), e.g. configs/tiny.
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
    /// Only these methods (config file stems), comma-separated; default: every one present.
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    #[arg(long, default_value_t = 4)]
    pub workers: usize,
    /// Checkpoints per run to choose from on val (evenly spaced; the last one always).
    #[arg(long, default_value_t = 5)]
    pub checkpoints: u64,
    /// Val programs per checkpoint evaluation (spread over the val rooms).
    #[arg(long, default_value_t = 500)]
    pub val_programs: usize,
    /// Test programs per evaluation (spread over the test rooms).
    #[arg(long, default_value_t = 1000)]
    pub test_programs: usize,
}

/// One training run of the study.
#[derive(Clone, Debug)]
pub struct Run {
    pub stem: String,
    pub method: Method,
    pub seed_index: u64,
    pub cfg: RunConfig,
    pub dir: PathBuf,
    pub config_path: PathBuf,
}

impl Run {
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

    fn select_dir(&self, ckpt: &Path) -> PathBuf {
        self.dir.join("select").join(ckpt.file_stem().unwrap_or_default())
    }

    fn test_dir(&self) -> PathBuf {
        self.dir.join("test")
    }
}

/// What the study will do, from the config folder: its learning runs and Random's seeds.
pub fn plan(a: &StudyArgs) -> anyhow::Result<(Vec<Run>, Option<RunConfig>)> {
    anyhow::ensure!(a.seeds > 0, "--seeds: at least one");
    anyhow::ensure!(a.frames > 0, "--frames: give a positive count");
    anyhow::ensure!(a.checkpoints > 0, "--checkpoints: at least one");
    for m in &a.methods {
        anyhow::ensure!(
            METHODS.iter().any(|(s, _)| s == m),
            "--methods: `{m}` is not one of {}",
            METHODS.map(|(s, _)| s).join(", ")
        );
    }
    let mut runs = Vec::new();
    let mut random = None;
    for (stem, method) in METHODS {
        let path = a.configs.join(format!("{stem}.toml"));
        if !a.methods.is_empty() && !a.methods.iter().any(|m| m == stem) {
            continue;
        }
        if !path.is_file() {
            anyhow::ensure!(a.methods.is_empty(), "--methods {stem}: no {}", path.display());
            continue;
        }
        let cfg = RunConfig::load(&path)?;
        anyhow::ensure!(
            cfg.run.method == method,
            "{}: run.method is {:?}, the file name says {stem}",
            path.display(),
            cfg.run.method
        );
        if method == Method::Random {
            random = Some(cfg);
            continue;
        }
        for k in 1..=a.seeds {
            let mut c = cfg.clone();
            c.run.seed = cfg.run.seed + k - 1;
            c.run.total_frames = a.frames;
            // every training room, as §4.4.1 (the tiny configs pick 8 for short single runs)
            c.run.scenes.clear();
            let name = format!("{stem}-seed{k}");
            let mut run = Run {
                stem: stem.into(),
                method,
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
    anyhow::ensure!(
        !runs.is_empty() || random.is_some(),
        "{}: no config named after a method of T4.2 ({}.toml)",
        a.configs.display(),
        METHODS.map(|(s, _)| s).join(".toml, ")
    );
    Ok((runs, random))
}

/// Counts the study's steps and says, with an ETA from the steps done in this invocation, where
/// it is (one line per step: studies run for hours, mostly unattended).
struct Progress {
    total: usize,
    done: usize,
    started: Instant,
    done_here: usize,
}

impl Progress {
    fn step(&mut self, what: &str, skipped: bool) {
        self.done += 1;
        if skipped {
            return;
        }
        self.done_here += 1;
        let per = self.started.elapsed().as_secs_f64() / self.done_here as f64;
        let left = per * (self.total - self.done) as f64;
        eprintln!("[study] {}/{} done: {what}; about {} left", self.done, self.total, humantime(left));
    }
}

fn humantime(s: f64) -> String {
    let m = (s / 60.0).round() as u64;
    if m >= 60 { format!("{} h {:02} min", m / 60, m % 60) } else { format!("{m} min") }
}

/// Runs `orchestrator ARGS` (this binary) to the end; a child stopped by a signal stops the study.
fn orchestrator(args: &[String], log: &Path) -> anyhow::Result<()> {
    if let Some(parent) = log.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let out = std::fs::OpenOptions::new().create(true).append(true).open(log)?;
    let exe = std::env::current_exe().context("finding the orchestrator binary")?;
    let mut cmd = Command::new(&exe);
    cmd.args(args).stdout(out.try_clone()?).stderr(out);
    // A study killed outright stops its step too (SIGTERM: `up` then writes its checkpoint), so
    // no orphan keeps writing into the folder the rerun continues. Ctrl-C reaches both anyway
    // (same process group).
    // SAFETY: runs in the forked child before exec; prctl is an async-signal-safe system call.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM).map_err(std::io::Error::from)
        });
    }
    let status = cmd.status().with_context(|| format!("starting {}", exe.display()))?;
    if farm::process::termination_count() > 0 {
        anyhow::bail!("stopped by a signal; run the same command again to continue");
    }
    anyhow::ensure!(status.success(), "`orchestrator {}` failed ({status}); see {}", args.join(" "), log.display());
    Ok(())
}

fn s(p: &Path) -> String {
    p.display().to_string()
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

/// `orchestrator eval` into `out` unless its tables are there.
fn eval(a: &StudyArgs, what: &[String], split: &str, programs: usize, out: &Path) -> anyhow::Result<bool> {
    if out.join("tables.csv").is_file() {
        return Ok(false);
    }
    let mut args: Vec<String> = vec!["eval".into()];
    args.extend(what.iter().cloned());
    args.extend(
        [
            "--split",
            split,
            "--max-programs",
            &programs.to_string(),
            "--modes",
            "normal",
            "--workers",
            &a.workers.to_string(),
            "--out",
            &s(out),
        ]
        .map(String::from),
    );
    orchestrator(&args, &out.with_extension("log"))?;
    Ok(true)
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
    let random_seeds = if random.is_some() { a.seeds as usize } else { 0 };
    // train, select (one step for all of a run's checkpoints), test; Random's evaluations
    let mut progress =
        Progress { total: runs.len() * 3 + random_seeds, done: 0, started: Instant::now(), done_here: 0 };
    eprintln!(
        "[study] {} runs ({} frames each, {} workers) and Random × {} seeds in {}",
        runs.len(),
        a.frames,
        a.workers,
        random_seeds,
        a.out.display()
    );
    let mut results = Vec::new();
    for run in &runs {
        let name = format!("{} seed {}", run.method.label(), run.seed_index);
        let trained = run.trained(a.workers);
        if !trained {
            train(&a, run)?;
            anyhow::ensure!(run.trained(a.workers), "{}: the run ended before its last update", run.dir.display());
        }
        progress.step(&format!("trained {name}"), trained);
        let mut ran = false;
        let mut best: Option<(f64, PathBuf)> = None;
        for (_, ckpt) in farm::checkpoints::list(&farm::checkpoints::dir_of(&run.dir)) {
            let out = run.select_dir(&ckpt);
            ran |= eval(&a, &["--checkpoint".into(), s(&ckpt)], "val", a.val_programs, &out)?;
            let sr1 = study_report::first_stop(&out.join("tables.csv"))?.sr;
            if best.as_ref().is_none_or(|(b, _)| sr1 >= *b) {
                best = Some((sr1, ckpt));
            }
        }
        let (val_sr1, chosen) = best.with_context(|| format!("{}: no checkpoint", run.dir.display()))?;
        progress.step(&format!("selected {name} on val"), !ran);
        let test = run.test_dir();
        let stale = std::fs::read_to_string(test.join("checkpoint")).ok().is_some_and(|c| c.trim() != s(&chosen));
        if stale {
            std::fs::remove_dir_all(&test)?;
        }
        let ran = eval(&a, &["--checkpoint".into(), s(&chosen)], "test", a.test_programs, &test)?;
        farm::files::write_atomic(&test.join("checkpoint"), s(&chosen).as_bytes())?;
        progress.step(&format!("tested {name}"), !ran);
        results.push(RunResult::read(run.method, run.seed_index, &chosen, val_sr1, &test.join("tables.csv"))?);
    }
    if let Some(cfg) = &random {
        for k in 1..=a.seeds {
            let dir = a.out.join("random").join(format!("seed{k}"));
            let mut c = cfg.clone();
            c.run.seed = cfg.run.seed + k - 1;
            let path = a.out.join("configs").join(format!("random-seed{k}.toml"));
            farm::files::write_atomic(&path, c.to_toml().as_bytes())?;
            let ran = eval(&a, &["--config".into(), s(&path)], "test", a.test_programs, &dir)?;
            progress.step(&format!("Random seed {k} on test"), !ran);
            results.push(RunResult::read(Method::Random, k, Path::new("-"), f64::NAN, &dir.join("tables.csv"))?);
        }
    }
    let curves: Vec<(Method, PathBuf)> = runs.iter().map(|r| (r.method, r.dir.clone())).collect();
    study_report::write(&a.out, &results, &curves)?;
    eprintln!("[study] tables in {}", a.out.join("T4.2.md").display());
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
            workers: 4,
            checkpoints: 5,
            val_programs: 100,
            test_programs: 100,
        }
    }

    #[test]
    fn the_plan_has_every_learning_method_per_seed_and_random_apart() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, random) = plan(&args(dir.path())).unwrap();
        assert_eq!(runs.len(), 5 * 2);
        assert!(random.is_some());
        let both2 = runs.iter().find(|r| r.stem == "both" && r.seed_index == 2).unwrap();
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
