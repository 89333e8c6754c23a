//! The `learner` process: `serve` is the farm's policy server (started by `orchestrator up`: it
//! batches the workers' observations from shared memory, runs the policy, answers); also a
//! device report, a self-contained smoke run (PPO on a synthetic in-process task, with metrics,
//! curves and checkpoints), and throughput figures.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use farm::config::{Device as DeviceChoice, FramePath, RunConfig};
use farm::process;
use farm::serve_args::{Blank as BlankArg, Policy as PolicyArg, ServeArgs};
use learner::serve::frames::FrameImports;
use learner::serve::policy::{ExpertPolicy, Policy, RandomPolicy};
use learner::serve::ppo_policy::{Blank, PpoPolicy};
use learner::serve::server::{ServeOptions, serve};
use learner::{bench, device, smoke};
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
    /// One env's policy over a pipe: observations on stdin, actions with the policy's
    /// probabilities and value as JSON lines on stdout (started by `orchestrator live`).
    Act {
        /// Run configuration (TOML): the checkpoint's run's, with one env per worker.
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        checkpoint: PathBuf,
        /// Take the policy's most likely action instead of sampling it.
        #[arg(long)]
        greedy: bool,
        /// Torch CPU threads.
        #[arg(long, default_value_t = 1)]
        threads: i32,
    },
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
    /// Pretrain the frozen RGB-D encoder on a frame set (spawned by `orchestrator encoder pretrain`).
    PretrainEncoder(PretrainEncoderArgs),
    /// Linear probes of frozen encoders on a frame set (spawned by `orchestrator encoder probe`).
    ProbeEncoder {
        /// Frame set written by `orchestrator encoder probe`.
        #[arg(long)]
        frames: PathBuf,
        /// NAME=WEIGHTS, one per encoder; NAME=pixels probes the raw cells.
        #[arg(long = "encoder", required = true)]
        encoders: Vec<String>,
        /// Output stem: STEM.json and STEM.md.
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value_t = 4)]
        epochs: usize,
    },
    /// Time a forward of the tiny network (batch 32) and PPO updates on 1280 samples.
    Bench {
        /// Also the dissertation's network (frozen ResNet-18 at 224², GRU 2×512) — slow on a CPU.
        #[arg(long)]
        faithful: bool,
        /// With --faithful: the acting rounds' sizes (envs per forward), e.g. 20,128,256; on a
        /// GPU each also times its frames' copy to the device.
        #[arg(long, value_delimiter = ',', default_value = "32")]
        act: Vec<usize>,
        /// With --faithful: PPO updates as ENVSxMINIBATCHES (128 steps an env), e.g. 20x2,256x8.
        #[arg(long, value_delimiter = ',', default_value = "10x1", value_parser = envs_by_minibatches)]
        update: Vec<(usize, usize)>,
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
}

#[derive(Args)]
struct PretrainEncoderArgs {
    /// Frame set written by `orchestrator encoder pretrain`.
    #[arg(long)]
    frames: PathBuf,
    /// Output stem: STEM.safetensors (the trunk's weights) and STEM.json (the report).
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long, default_value_t = 12)]
    epochs: usize,
    /// reconstruct or contrast (label-free), or semantic (the id target's labels: the semantic sensor).
    #[arg(long, default_value = "contrast")]
    objective: learner::encoder::Objective,
    /// rgbd (configs/tiny's early-fusion encoder) or resnet18 (configs/faithful's trunk; contrast only).
    #[arg(long, default_value = "rgbd")]
    trunk: learner::encoder::Trunk,
    /// Reconstruction: share of cells hidden from the trunk (default 0).
    #[arg(long)]
    mask: Option<f64>,
    /// Frames per step (default 64).
    #[arg(long)]
    batch: Option<usize>,
    /// Adam's initial learning rate (default 2e-3).
    #[arg(long)]
    lr: Option<f64>,
    /// Weight of the "other" class in the loss (default 0.3).
    #[arg(long)]
    other_weight: Option<f64>,
    /// Torch CPU threads (default 2); the weights depend on it.
    #[arg(long)]
    threads: Option<i32>,
}

/// The policy to serve. With `env.frames = "device"` the workers hand their frame memory over
/// `imports` whichever policy runs; PPO takes it to read frames from, the baselines read none
/// (the caller keeps it, and the socket open, while they serve).
fn make_policy(
    a: &ServeArgs,
    cfg: &RunConfig,
    dev: tch::Device,
    imports: &mut Option<FrameImports>,
) -> anyhow::Result<Box<dyn Policy>> {
    let ppo = |p: PpoPolicy, imports: &mut Option<FrameImports>| -> Box<dyn Policy> {
        match imports.take() {
            Some(i) => Box::new(p.with_device_frames(i)),
            None => Box::new(p),
        }
    };
    let o = &a.options;
    Ok(match (a.policy, &o.checkpoint) {
        (PolicyArg::Random, _) => Box::new(RandomPolicy::new(cfg.run.seed)),
        (PolicyArg::Expert, _) => Box::new(ExpertPolicy),
        (PolicyArg::Ppo, Some(ckpt)) => {
            let blank = match o.blank {
                None => Blank::default(),
                Some(BlankArg::Rgb) => Blank { rgb: true, depth: false },
                Some(BlankArg::Depth) => Blank { rgb: false, depth: true },
                Some(BlankArg::Both) => Blank { rgb: true, depth: true },
            };
            ppo(PpoPolicy::eval(cfg, a.workers, dev, ckpt, blank, o.greedy)?, imports)
        }
        (PolicyArg::Ppo, None) => {
            anyhow::ensure!(!a.eval, "--eval with --policy ppo needs --checkpoint");
            let p = PpoPolicy::train(cfg, a.workers, dev, &a.run_dir, a.resume)?;
            ppo(if o.profile_stages { p.with_stage_times() } else { p }, imports)
        }
    })
}

fn run_serve(a: ServeArgs, dev: tch::Device) -> anyhow::Result<()> {
    // Ctrl-C (SIGINT) stops cleanly and checkpoints; the orchestrator's death counts as Ctrl-C.
    process::install_termination_handler()?;
    process::die_with_parent(Signal::SIGINT)?;
    let cfg = RunConfig::load(&a.config)?;
    // where the policy runs, for the run's log (`orchestrator bench train` prints it)
    tracing::info!("{}", device::report(dev));
    let mut imports = match cfg.env.frames {
        FramePath::Device => Some(FrameImports::listen(&a.run_dir, dev)?),
        FramePath::SharedMemory => None,
    };
    let mut policy = make_policy(&a, &cfg, dev, &mut imports)?;
    if a.resume && a.policy != PolicyArg::Ppo {
        tracing::info!("--resume: policy `{}` keeps no state; nothing to resume", policy.name());
    }
    if a.options.profile_stages && policy.stage_times().is_none() {
        tracing::info!("--profile-stages: policy `{}` does not train; no stages to time", policy.name());
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

fn main() {
    // Before anything asks torch about CUDA, and before torch starts its CPU threads.
    device::load_cuda_backend();
    device::flush_denormals();
    device::keep_freed_memory();
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
        Command::Act { config, checkpoint, greedy, threads } => {
            process::die_with_parent(Signal::SIGTERM)?;
            if !dev.is_cuda() {
                tch::set_num_threads(threads.max(1));
            }
            let cfg = RunConfig::load(&config)?;
            let (stdin, stdout) = (std::io::stdin().lock(), std::io::stdout().lock());
            learner::serve::pipe::serve_pipe(&cfg, &checkpoint, dev, greedy, stdin, stdout)
                .with_context(|| checkpoint.display().to_string())?;
        }
        Command::Info => println!("{}", device::report(dev)),
        Command::Smoke { updates, envs, run_dir, resume } => {
            // Ctrl-C stops after the current update, with a checkpoint.
            process::install_termination_handler()?;
            println!("{}", device::report(dev));
            smoke::run_in_dir(dev, updates, envs, &run_dir, resume)?
        }
        Command::Bench { faithful, act, update, reps } => {
            println!("{}", device::report(dev));
            let sizes = faithful.then_some(bench::FaithfulSizes { act, update });
            bench::run(dev, sizes, reps, |f| println!("{f}"))?
        }
        Command::Weights { path } => println!("{}", learner::net::resnet::check_weights(&path)?),
        Command::PretrainEncoder(a) => {
            let mut o = learner::encoder::PretrainOptions::new(a.frames, a.out, a.seed, a.epochs);
            o.objective = a.objective;
            o.trunk = a.trunk;
            o.mask = a.mask.unwrap_or(o.mask);
            o.batch = a.batch.unwrap_or(o.batch);
            o.lr = a.lr.unwrap_or(o.lr);
            o.other_weight = a.other_weight.unwrap_or(o.other_weight);
            o.threads = a.threads.unwrap_or(o.threads);
            learner::encoder::pretrain(&o, dev).map(drop)?
        }
        Command::ProbeEncoder { frames, encoders, out, seed, epochs } => {
            let encoders = encoders
                .iter()
                .map(|e| match e.split_once('=') {
                    Some((name, "pixels")) => Ok((name.to_string(), None)),
                    Some((name, path)) => Ok((name.to_string(), Some(PathBuf::from(path)))),
                    None => Err(anyhow::anyhow!("--encoder {e}: NAME=WEIGHTS or NAME=pixels")),
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let o = learner::encoder::ProbeOptions { frames, encoders, seed, epochs, threads: 2 };
            learner::encoder::probe(&o, &out).map(drop)?
        }
    }
    Ok(())
}

/// `ENVSxMINIBATCHES`, e.g. `256x8`: a PPO update's envs and how many minibatches they split into.
fn envs_by_minibatches(s: &str) -> Result<(usize, usize), String> {
    let (e, m) = s.split_once('x').ok_or_else(|| format!("`{s}`: give ENVSxMINIBATCHES, e.g. 256x8"))?;
    let count = |v: &str| {
        v.parse::<usize>().ok().filter(|n| *n > 0).ok_or_else(|| format!("`{s}`: `{v}` is not a positive count"))
    };
    let (envs, minibatches) = (count(e)?, count(m)?);
    if minibatches > envs {
        return Err(format!("`{s}`: more minibatches than envs"));
    }
    Ok((envs, minibatches))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_sizes_parse_and_bad_ones_say_why() {
        assert_eq!(envs_by_minibatches("256x8"), Ok((256, 8)));
        for (bad, why) in [("256", "ENVSxMINIBATCHES"), ("0x1", "`0`"), ("4x8", "more minibatches"), ("ax2", "`a`")] {
            let e = envs_by_minibatches(bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
        let cli = Cli::try_parse_from(["learner", "bench", "--faithful", "--act", "20,256", "--update", "20x2,256x4"]);
        match cli.map(|c| c.command) {
            Ok(Command::Bench { act, update, .. }) => {
                assert_eq!(act, [20, 256]);
                assert_eq!(update, [(20, 2), (256, 4)]);
            }
            other => panic!("{:?}", other.err()),
        }
    }
}
