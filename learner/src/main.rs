//! The `learner` process: `serve` is the farm's policy server (started by `orchestrator up`: it
//! batches the workers' observations from shared memory, runs the policy, answers); also a
//! device report, a self-contained smoke run (PPO on a synthetic in-process task, with metrics,
//! curves and checkpoints), and throughput figures.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use farm::config::{Device as DeviceChoice, RunConfig};
use farm::process;
use learner::policy::{ExpertPolicy, Policy, RandomPolicy};
use learner::ppo_policy::{Blank, PpoPolicy};
use learner::serve::{ServeOptions, serve};
use learner::{bench, checkpoint, device, metrics::MetricsLog, smoke};
use nix::sys::signal::Signal;

#[derive(Parser)]
#[command(name = "learner", about = "GesTHOR-RS PPO learner (tch / libtorch)")]
struct Cli {
    /// cpu, cuda or auto (CUDA when a GPU is usable).
    #[arg(long, global = true, default_value = "auto", value_parser = parse_device)]
    device: DeviceChoice,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Serve a policy to the run's workers over shared memory (started by `orchestrator up`).
    Serve(ServeArgs),
    /// Which device torch sees, and how the CUDA backend was loaded.
    Info,
    /// Train on a synthetic "go where the gesture points" task in-process: shows learning end to end.
    Smoke {
        #[arg(long, default_value_t = 40)]
        updates: u64,
        #[arg(long, default_value_t = 16)]
        envs: usize,
        /// Run directory for metrics.jsonl, curves.png and checkpoints/.
        #[arg(long, default_value = "runs/smoke")]
        run_dir: PathBuf,
        /// Continue from the latest checkpoint in the run directory.
        #[arg(long)]
        resume: bool,
    },
    /// Check a torchvision ResNet-18 checkpoint (.pth/.pt/.safetensors) before a long run.
    Weights { path: PathBuf },
    /// Time a forward of the tiny network (batch 32) and PPO updates on 1280 samples.
    Bench {
        /// Also the dissertation's network (frozen ResNet-18 at 224², GRU 2×512) — slow on a CPU.
        #[arg(long)]
        faithful: bool,
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
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

/// Visual inputs to zero during evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum BlankKind {
    Rgb,
    Depth,
    Both,
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
    /// Evaluate this checkpoint (with `--policy ppo --eval`) instead of training.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Evaluation: zero these visual inputs (blind mode: both; T4.7 ablations: one).
    #[arg(long, value_enum)]
    blank: Option<BlankKind>,
    /// Evaluation: take the policy's most likely action instead of sampling it.
    #[arg(long)]
    greedy: bool,
    /// Before the first batch, wait up to this many seconds for every worker to connect.
    #[arg(long, default_value_t = 60.0)]
    start_wait: f64,
}

fn make_policy(a: &ServeArgs, cfg: &RunConfig, dev: tch::Device) -> anyhow::Result<Box<dyn Policy>> {
    Ok(match (a.policy, &a.checkpoint) {
        (PolicyKind::Random, _) => Box::new(RandomPolicy::new(cfg.run.seed)),
        (PolicyKind::Expert, _) => Box::new(ExpertPolicy),
        (PolicyKind::Ppo, Some(ckpt)) => {
            let blank = match a.blank {
                None => Blank::default(),
                Some(BlankKind::Rgb) => Blank { rgb: true, depth: false },
                Some(BlankKind::Depth) => Blank { rgb: false, depth: true },
                Some(BlankKind::Both) => Blank { rgb: true, depth: true },
            };
            Box::new(PpoPolicy::eval(cfg, a.workers, dev, ckpt, blank, a.greedy)?)
        }
        (PolicyKind::Ppo, None) => {
            anyhow::ensure!(!a.eval, "--eval with --policy ppo needs --checkpoint");
            Box::new(PpoPolicy::train(cfg, a.workers, dev, &a.run_dir, a.resume)?)
        }
    })
}

fn run_serve(a: ServeArgs, dev: tch::Device) -> anyhow::Result<()> {
    // Ctrl-C (SIGINT) stops cleanly and checkpoints; the orchestrator's death counts as Ctrl-C.
    process::install_termination_handler()?;
    process::die_with_parent(Signal::SIGINT)?;
    let cfg = RunConfig::load(&a.config)?;
    let mut policy = make_policy(&a, &cfg, dev)?;
    if a.resume && a.policy != PolicyKind::Ppo {
        tracing::info!("--resume: policy `{}` keeps no state; nothing to resume", policy.name());
    }
    let mut opts =
        ServeOptions::new(&a.run_id, a.workers, &a.run_dir, cfg.env.envs_per_worker, cfg.env.width, cfg.env.height);
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

fn parse_device(s: &str) -> Result<DeviceChoice, String> {
    match s {
        "auto" => Ok(DeviceChoice::Auto),
        "cpu" => Ok(DeviceChoice::Cpu),
        "cuda" => Ok(DeviceChoice::Cuda),
        _ => Err(format!("`{s}`: use auto, cpu or cuda")),
    }
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_sigint(_: libc::c_int) {
    STOP.store(true, Ordering::SeqCst);
}

/// Ctrl-C asks for a checkpoint and a clean stop instead of killing the process.
fn install_ctrl_c() -> Result<()> {
    use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};
    let action = SigAction::new(SigHandler::Handler(on_sigint), SaFlags::empty(), SigSet::empty());
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        sigaction(Signal::SIGINT, &action)?;
        sigaction(Signal::SIGTERM, &action)?;
    }
    Ok(())
}

fn main() {
    // Before anything asks torch about CUDA, and before torch starts its CPU threads.
    device::load_cuda_backend();
    device::flush_denormals();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    if let Err(e) = run(Cli::parse()) {
        eprintln!("learner: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    let dev = device::select(cli.device)?;
    device::configure(dev);
    match cli.command {
        Command::Serve(a) => run_serve(a, dev)?,
        Command::Info => println!("{}", device::report(dev)),
        Command::Smoke { updates, envs, run_dir, resume } => smoke_run(dev, updates, envs, run_dir, resume)?,
        Command::Bench { faithful, reps } => bench_run(dev, faithful, reps)?,
        Command::Weights { path } => println!("{}", learner::resnet::check_weights(&path)?),
    }
    Ok(())
}

fn smoke_run(dev: tch::Device, updates: u64, envs: usize, run_dir: PathBuf, resume: bool) -> Result<()> {
    install_ctrl_c()?;
    println!("{}", device::report(dev));
    let cfg = smoke::config(updates, envs);
    let ckpt_dir = farm::checkpoints::dir_of(&run_dir);
    std::fs::create_dir_all(&run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    farm::files::write_atomic(&run_dir.join("config.toml"), cfg.to_toml().as_bytes())
        .with_context(|| format!("writing {}", run_dir.join("config.toml").display()))?;
    let mut log = MetricsLog::open(&run_dir)?;
    let from = if resume { checkpoint::latest(&ckpt_dir) } else { None };
    if resume && from.is_none() {
        anyhow::bail!("--resume: no checkpoint in {}", ckpt_dir.display());
    }
    let mut failure = None;
    let on_update = |t: &learner::Trainer, m: &learner::UpdateMetrics| {
        println!(
            "update {:>3}  frames {:>6}  success {:>5}  return {:>7}  entropy {:.3}  kl {:.4}  lr {:.2e}  {:.0} fps",
            m.update,
            m.frames,
            m.success_rate.map(|s| format!("{s:.2}")).unwrap_or("-".into()),
            m.episode_return.map(|s| format!("{s:.3}")).unwrap_or("-".into()),
            m.entropy,
            m.approx_kl,
            m.lr,
            m.fps
        );
        let stop = STOP.load(Ordering::SeqCst);
        let result = log.append(m).map_err(anyhow::Error::from).and_then(|_| {
            if stop || m.update % t.cfg.checkpoint.every_updates == 0 {
                let p = checkpoint::save_in_dir(&ckpt_dir, t, t.cfg.checkpoint.keep)?;
                println!("checkpoint {}", p.display());
            }
            Ok(())
        });
        if let Err(e) = result {
            failure = Some(e);
            return false;
        }
        !stop
    };
    let (report, trainer) = match from {
        Some(path) => {
            println!("resuming from {}", path.display());
            smoke::run_from(&cfg, dev, updates, Some(&path), on_update)?
        }
        None => smoke::run_from(&cfg, dev, updates, None, on_update)?,
    };
    if let Some(e) = failure {
        return Err(e);
    }
    for n in trainer.agent.notes() {
        println!("{n}");
    }
    log.plot()?;
    if STOP.load(Ordering::SeqCst) {
        println!("stopped by signal after update {} (checkpoint written)", trainer.updates);
        return Ok(());
    }
    let p = checkpoint::save_in_dir(&ckpt_dir, &trainer, trainer.cfg.checkpoint.keep)?;
    println!(
        "success rate {:.2} (at start, sampling) → {:.2} (trained, greedy) after {} updates in {:.1} s\n\
         metrics {}  curves {}  checkpoint {}",
        report.before,
        report.after.unwrap_or(f64::NAN),
        report.updates,
        report.seconds,
        log.jsonl.display(),
        log.png.display(),
        p.display()
    );
    Ok(())
}

fn bench_run(dev: tch::Device, faithful: bool, reps: usize) -> Result<()> {
    println!("{}", device::report(dev));
    let tiny = bench::tiny_config();
    println!("{}", bench::forward("tiny (64², small CNN, 256, GRU 1)", &tiny, 32, dev, reps)?);
    println!("{}", bench::update("tiny (64², small CNN, 256, GRU 1)", &tiny, 10, dev, reps)?);
    if faithful {
        let dir = tempfile::tempdir()?;
        let weights = bench::random_resnet_weights(dir.path())?;
        let cfg = bench::faithful_config(&weights);
        let reps_slow = reps.min(3).max(1);
        println!("{}", bench::forward("faithful (224², frozen ResNet-18, 512, GRU 2)", &cfg, 32, dev, reps_slow)?);
        println!(
            "{}",
            bench::update("faithful, stored conv5 features (GRU + heads + 1x1 convs)", &cfg, 10, dev, reps_slow)?
        );
    }
    Ok(())
}
