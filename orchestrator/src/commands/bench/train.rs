//! `orchestrator bench train`: end-to-end training throughput of a configuration (the embedded
//! default of `up` when none is given) over a fixed number of frames, and where the time went.
//!
//! The run is an ordinary training run (PPO, checkpoints off); its learner's last progress record
//! carries the profile (`farm::profile`): the learner's timeline (waiting for observations,
//! receiving, inference, sending, updates) and the workers' loops (env step, render, transport,
//! waiting for actions), cumulative seconds. Frame-limited, so a row can be repeated. With
//! `--stages` the learner also times its acting and updates stage by stage (`StageTimes`).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use farm::config::RunConfig;
use farm::process;
use farm::profile::{Profile, StageTimes};

use crate::commands::up;
use crate::supervise::crew::{Crew, CrewSpec, CrewState};
use crate::supervise::launch;
use farm::progress::Progress;
use farm::serve_args::Policy;

#[derive(Args, Debug)]
pub struct BenchTrainArgs {
    /// Run configuration (default: the embedded default of `up`, tiny +Both).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Worker processes.
    #[arg(long, default_value_t = 4, value_parser = crate::commands::values::workers)]
    pub workers: usize,
    /// Frames to train for (the run stops at the first update boundary past it).
    #[arg(long, default_value_t = 50_000)]
    pub frames: u64,
    /// Where the run goes (default: runs/bench-train-<UTC time>); the table is written there.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write the table (Markdown) here, e.g. docs/bench/train.md.
    #[arg(long)]
    pub table: Option<PathBuf>,
    /// Override a config value, as `up --set` (repeatable), e.g. `--set env.envs_per_worker=16`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Also time the learner's acting and updates stage by stage (`learner serve
    /// --profile-stages`): the device is synchronized after each stage, so the run is slower.
    #[arg(long)]
    pub stages: bool,
}

/// What one bench run measured.
#[derive(Clone, Debug, Default)]
pub struct TrainBench {
    pub frames: u64,
    pub seconds: f64,
    pub updates: u64,
    pub profile: Profile,
    pub workers: usize,
    /// The learner's report of where it ran (torch device, CUDA backend, threads), from its log.
    pub learner_device: Option<String>,
}

impl TrainBench {
    pub fn fps(&self) -> f64 {
        self.frames as f64 / self.seconds.max(1e-9)
    }

    /// Frames per second while collecting (the wall time outside updates).
    pub fn collection_fps(&self) -> f64 {
        self.frames as f64 / (self.seconds - self.profile.learner.update_s).max(1e-9)
    }

    /// Update seconds per 4,096 frames (the embedded default's rollout: 32 envs × 128 steps).
    pub fn update_s_per_4096(&self) -> f64 {
        self.profile.learner.update_s * 4096.0 / self.frames.max(1) as f64
    }
}

fn share(part: f64, whole: f64) -> String {
    if whole > 0.0 { format!("{:.1}%", 100.0 * part / whole) } else { "-".into() }
}

/// The bench's table as Markdown.
pub fn report(b: &TrainBench, cfg: &RunConfig, command: &str) -> String {
    let l = &b.profile.learner;
    let w = &b.profile.workers;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Training throughput\n\n`{command}`\n\n{} ({}, {}×{} RGB-D, encoder {:?}), {} workers × {} envs{}, {} CPU cores; \
         {} frames in {:.1} s, {} PPO updates.\n",
        cfg.run.method.label(),
        cfg.run.dataset.display(),
        cfg.env.width,
        cfg.env.height,
        cfg.model.encoder,
        b.workers,
        cfg.env.envs_per_worker,
        match cfg.ppo.env_groups {
            1 => String::new(),
            g => format!(" in {g} groups taking rounds in turn"),
        },
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0),
        b.frames,
        b.seconds,
        b.updates,
    );
    if let Some(d) = &b.learner_device {
        let _ = writeln!(md, "Learner: {d}.\n");
    }
    let _ = writeln!(md, "| measure | value |\n|---|---:|");
    let _ = writeln!(md, "| end-to-end frames/s | **{:.0}** |", b.fps());
    let _ = writeln!(md, "| frames/s while collecting (outside updates) | {:.0} |", b.collection_fps());
    let _ = writeln!(md, "| update seconds per 4,096 frames | {:.2} |", b.update_s_per_4096());
    let _ = writeln!(md);
    let _ = writeln!(md, "The learner's wall time ({:.1} s):\n", l.total());
    let _ = writeln!(md, "| learner | seconds | share |\n|---|---:|---:|");
    for (name, v) in [
        ("PPO update (workers wait)", l.update_s),
        ("waiting for observations (workers step, render, send)", l.wait_s),
        ("inference (forward + sampling)", l.infer_s),
        ("receiving (checks, batching, records)", l.receive_s),
        ("sending actions", l.send_s),
    ] {
        let _ = writeln!(md, "| {name} | {v:.1} | {} |", share(v, l.total()));
    }
    let cores = |cpu: f64, wall: f64| if wall > 0.0 { format!("{:.2}", cpu / wall) } else { "-".into() };
    let _ = writeln!(
        md,
        "\nCores the learner process keeps busy (processor seconds of all its threads over wall \
         seconds): in updates {}, in inference {}, over the whole run {} ({:.1} processor seconds).\n",
        cores(l.update_cpu_s, l.update_s),
        cores(l.infer_cpu_s, l.infer_s),
        cores(l.cpu_s, l.total()),
        l.cpu_s,
    );
    let _ = writeln!(md, "The workers' wall time, summed over {} workers ({:.1} s):\n", b.workers, w.total());
    let _ = writeln!(md, "| workers | seconds | share |\n|---|---:|---:|");
    for (name, v) in [
        ("env step (physics, task, gestures, writing observations)", w.sim_s),
        ("render", w.render_s),
        ("transport (loan, send, notify)", w.send_s),
        ("waiting for actions (learner infers or updates)", w.wait_s),
    ] {
        let _ = writeln!(md, "| {name} | {v:.1} | {} |", share(v, w.total()));
    }
    if let Some(s) = &b.profile.stages {
        stages_table(&mut md, s);
    }
    md
}

/// The learner's acting and updates by stage: seconds, share of acting (of the update), and
/// milliseconds per round (per update).
fn stages_table(md: &mut String, s: &StageTimes) {
    let _ = writeln!(
        md,
        "\n## Acting and update by stage (synchronized after each stage: this run is slower than one \
         without --stages)\n\n{} acting calls (rounds, or one group's round), {} updates.\n",
        s.rounds, s.updates
    );
    let _ = writeln!(md, "| stage | seconds | share | ms |\n|---|---:|---:|---:|");
    for (phase, stages, count, per) in
        [("acting", &s.acting()[..], s.rounds, "a round"), ("update", &s.updating()[..], s.updates, "an update")]
    {
        let total: f64 = stages.iter().map(|(_, v)| v).sum();
        let ms = |v: f64| if count > 0 { format!("{:.2}", 1e3 * v / count as f64) } else { "-".into() };
        let _ = writeln!(md, "| **{phase}** | **{total:.1}** | 100% | **{}** {per} |", ms(total));
        for (name, v) in stages {
            let _ = writeln!(md, "| {name} | {v:.1} | {} | {} |", share(*v, total), ms(*v));
        }
    }
}

/// Runs the crew until it ends by itself at `frames` (or is interrupted).
fn train(a: &BenchTrainArgs, cfg: &RunConfig, out: &std::path::Path) -> anyhow::Result<(Progress, f64)> {
    let run_dir = out.join("run");
    let (dir, config_path) = launch::prepare_run(&run_dir, cfg, false, a.workers, Policy::Ppo)?;
    let mut spec = CrewSpec::new(&dir.path, &dir.run_id, &config_path, cfg.clone(), a.workers, Policy::Ppo);
    spec.max_frames = Some(a.frames);
    spec.report_every = 1.0;
    spec.learner.profile_stages = a.stages;
    let start = Instant::now();
    let mut crew = Crew::start(spec)?;
    let mut last_line = Instant::now();
    while crew.tick()? == CrewState::Running {
        if process::termination_signal().is_some() && !crew.is_stopping() {
            crew.stop();
        }
        if last_line.elapsed() > Duration::from_secs(10)
            && let Some(p) = crew.progress()
        {
            eprintln!("[bench] {} of {} frames, {:.0} frames/s", p.totals.frames, a.frames, p.fps);
            last_line = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let outcome = crew.finish()?;
    anyhow::ensure!(!outcome.stopped, "interrupted before {} frames", a.frames);
    let p = outcome.progress.context("the learner wrote no progress record")?;
    Ok((p, start.elapsed().as_secs_f64()))
}

/// The device report the learner logs when it starts (`learner::device::report`).
fn learner_device(log: &std::path::Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().find_map(|l| l.split_once(" learner: device ").map(|(_, r)| format!("device {}", r.trim())))
}

/// A bench writes no periodic checkpoint (the final one only): the largest count a TOML integer
/// holds, so the run's config.toml reads back (`eval --checkpoint` on a bench's run).
const NO_PERIODIC_CHECKPOINT: u64 = i64::MAX as u64;

pub fn run(a: BenchTrainArgs) -> anyhow::Result<()> {
    process::install_termination_handler()?;
    anyhow::ensure!(a.workers > 0, "--workers: give a positive count");
    anyhow::ensure!(a.frames > 0, "--frames: give a positive count");
    let mut cfg = up::load_config(a.config.as_deref())?.with_overrides(&a.set)?;
    cfg.checkpoint.every_updates = NO_PERIODIC_CHECKPOINT;
    launch::resolve_dataset(&mut cfg, false)?;
    launch::resolve_encoder(&mut cfg)?;
    launch::sweep_dead_runs();
    let out = a.out.clone().unwrap_or_else(|| crate::supervise::run_dir::default_path("bench-train"));
    let (p, wall) = train(&a, &cfg, &out)?;
    let metrics: Vec<serde_json::Value> = farm::files::read_jsonl(&out.join("run/metrics.jsonl")).unwrap_or_default();
    let mut profile = p.profile;
    if profile.learner.update_s == 0.0 {
        // a learner that writes no profile still reports each update's time
        profile.learner.update_s = metrics.iter().filter_map(|m| m["update_seconds"].as_f64()).sum();
    }
    let bench = TrainBench {
        frames: p.totals.frames,
        // the learner's own clock: from its start to its last record (process start-up excluded)
        seconds: if p.t > 0.0 { p.t } else { wall },
        updates: metrics.len() as u64,
        profile,
        workers: a.workers,
        learner_device: learner_device(&out.join("run/logs/learner.log")),
    };
    let mut command = format!("orchestrator bench train --workers {} --frames {}", a.workers, a.frames);
    if let Some(c) = &a.config {
        let _ = write!(command, " --config {}", c.display());
    }
    for kv in &a.set {
        let _ = write!(command, " --set {kv}");
    }
    if a.stages {
        command.push_str(" --stages");
    }
    let md = report(&bench, &cfg, &command);
    print!("{md}");
    farm::files::write_atomic(&out.join("bench_train.md"), md.as_bytes())?;
    if let Some(t) = &a.table {
        farm::files::write_atomic(t, md.as_bytes()).with_context(|| format!("writing {}", t.display()))?;
    }
    eprintln!("[bench] written {}", out.join("bench_train.md").display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bench_runs_config_reads_back() {
        let mut cfg = up::load_config(None).unwrap();
        cfg.checkpoint.every_updates = NO_PERIODIC_CHECKPOINT;
        assert_eq!(RunConfig::from_toml(&cfg.to_toml(), "config.toml").unwrap(), cfg);
    }

    /// The stage table comes with a learner's stage times only, with each stage's share of its
    /// phase and its milliseconds per round or update.
    #[test]
    fn the_stage_table_is_there_only_with_stage_times() {
        let cfg = up::load_config(None).unwrap();
        let mut b = TrainBench { frames: 100, seconds: 2.0, workers: 1, ..Default::default() };
        assert!(!report(&b, &cfg, "x").contains("by stage"));
        b.profile.stages = Some(StageTimes {
            act_inputs_s: 1.0,
            act_visual_s: 3.0,
            rounds: 500,
            update_backward_s: 2.0,
            updates: 4,
            ..Default::default()
        });
        let md = report(&b, &cfg, "x");
        assert!(md.contains("## Acting and update by stage"), "{md}");
        assert!(md.contains("| **acting** | **4.0** | 100% | **8.00** a round |"), "{md}");
        assert!(md.contains("| visual encoders | 3.0 | 75.0% | 6.00 |"), "{md}");
        assert!(md.contains("| forward + backward | 2.0 | 100.0% | 500.00 |"), "{md}");
    }
}
