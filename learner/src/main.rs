//! The `learner` process. `learner serve` is the farm's policy server (started by
//! `orchestrator up`): it batches the workers' observations, runs the policy, and answers.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};
use nix::sys::signal::Signal;

use learner::policy::{ExpertPolicy, Policy, RandomPolicy};
use learner::serve::{ServeOptions, serve};
use worker::config::RunConfig;
use worker::process;

#[derive(Parser)]
#[command(name = "learner", version, about = "GesTHOR-RS learner and policy server")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Serve a policy to the run's workers over shared memory.
    Serve(ServeArgs),
}

/// Which policy answers the workers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum PolicyKind {
    /// Uniformly random actions (seeded from the run seed).
    Random,
    /// The shortest-path expert's actions (workers need `--expert-hints`).
    Expert,
    /// The PPO agent: acts and learns.
    Ppo,
}

#[derive(Args)]
struct ServeArgs {
    /// Run configuration (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Run id (names the shared-memory services).
    #[arg(long)]
    run_id: String,
    /// Worker slots 0..N to serve.
    #[arg(long)]
    workers: usize,
    /// Run directory: farm.jsonl, episodes.jsonl, farm_summary.json (and checkpoints).
    #[arg(long)]
    run_dir: PathBuf,
    #[arg(long, value_enum, default_value_t = PolicyKind::Random)]
    policy: PolicyKind,
    /// Stop after this many frames.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long)]
    max_seconds: Option<f64>,
    /// Evaluation: stop when every worker has finished its programs.
    #[arg(long)]
    eval: bool,
    /// Fail on any lost, duplicated or malformed message (tests).
    #[arg(long)]
    check: bool,
    /// Continue from the run directory's latest checkpoint.
    #[arg(long)]
    resume: bool,
    /// Close a batch this many milliseconds after its first observation even if workers are missing.
    #[arg(long, default_value_t = 1000)]
    batch_timeout_ms: u64,
    /// Seconds between progress records.
    #[arg(long, default_value_t = 2.0)]
    report_every: f64,
    /// Before the first batch, wait up to this many seconds for every worker to connect.
    #[arg(long, default_value_t = 60.0)]
    start_wait: f64,
}

fn make_policy(kind: PolicyKind, cfg: &RunConfig) -> anyhow::Result<Box<dyn Policy>> {
    Ok(match kind {
        PolicyKind::Random => Box::new(RandomPolicy::new(cfg.run.seed)),
        PolicyKind::Expert => Box::new(ExpertPolicy),
        PolicyKind::Ppo => anyhow::bail!("--policy ppo: the PPO trainer is not part of this build"),
    })
}

fn run_serve(a: ServeArgs) -> anyhow::Result<()> {
    let cfg = RunConfig::load(&a.config)?;
    let mut policy = make_policy(a.policy, &cfg)?;
    if a.resume && a.policy != PolicyKind::Ppo {
        tracing::info!("--resume: policy `{}` keeps no state; nothing to resume", policy.name());
    }
    let mut opts = ServeOptions::new(&a.run_id, a.workers, &a.run_dir, cfg.env.envs_per_worker, cfg.env.width, cfg.env.height);
    opts.max_frames = a.max_frames;
    opts.max_seconds = a.max_seconds;
    opts.eval = a.eval;
    opts.check = a.check;
    opts.batch_timeout = std::time::Duration::from_millis(a.batch_timeout_ms);
    opts.report_every = std::time::Duration::from_secs_f64(a.report_every.max(0.1));
    opts.start_wait = std::time::Duration::from_secs_f64(a.start_wait.max(0.0));
    let summary = serve(&opts, policy.as_mut()).context("serving the farm")?;
    tracing::info!(
        "{}: {} frames, {} episodes in {:.1} s",
        summary.stop_reason,
        summary.totals.frames,
        summary.totals.episodes,
        summary.seconds
    );
    Ok(())
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .init();
    let cli = Cli::parse();
    // Ctrl-C (SIGINT) stops cleanly and checkpoints; the orchestrator's death counts as Ctrl-C.
    if let Err(e) = process::install_termination_handler().and_then(|_| process::die_with_parent(Signal::SIGINT)) {
        eprintln!("learner: cannot set up signal handling: {e}");
        return ExitCode::from(1);
    }
    let result = match cli.command {
        Command::Serve(a) => run_serve(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("learner: {e:#}");
            ExitCode::from(1)
        }
    }
}
