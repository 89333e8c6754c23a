//! `worker`: one process of the rollout farm. Steps E environments, writes their observations
//! straight into shared memory, and waits for the learner's actions (see `farm::transport`).
//! Started by `orchestrator up`; by hand only to debug.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use nix::sys::signal::Signal;

use farm::config::{FramePath, RunConfig};
use farm::process;
use farm::stepper::{Stepper, SyntheticStepper};
use farm::transport::{self, Exit, WorkerOptions};
use worker::dataset::{Dataset, Verify};
use worker::env::{EnvPool, PoolSpec, ProgramSource, eligible_programs};
use worker::program::Program;
use worker::render::{RenderConfig, Renderer, bench_views, benchmark_room};

#[derive(Parser, Debug)]
#[command(
    name = "worker",
    version,
    about = "A GesTHOR-RS rollout worker: E simulated environments behind one shared-memory port"
)]
struct Cli {
    /// Run configuration (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Run id (names the shared-memory services; given by the orchestrator).
    #[arg(long, required_unless_present = "bench_render")]
    run_id: Option<String>,
    /// This worker's slot, 0..N.
    #[arg(long, default_value_t = 0)]
    worker_id: u32,
    /// How many times this slot was restarted; a new generation draws a fresh seed stream.
    #[arg(long, default_value_t = 0)]
    generation: u32,
    /// Evaluation: a JSON array of program indices (of the config's split) to run, in order.
    #[arg(long)]
    programs: Option<PathBuf>,
    /// Compute the shortest-path expert's action for every observation (`--policy expert`).
    #[arg(long)]
    expert_hints: bool,
    /// Step synthetic environments (counters and patterned frames, no simulator): measures
    /// and tests the farm's plumbing alone.
    #[arg(long)]
    synthetic: bool,
    /// Measure the renderer alone for this many seconds (the same scene content as the
    /// environments), print views/s, and exit.
    #[arg(long, value_name = "SECONDS")]
    bench_render: Option<f64>,
    /// Seconds to wait for the learner to connect.
    #[arg(long, default_value_t = 120)]
    connect_timeout: u64,
    /// The learner's frame socket (`env.frames = "device"`: the exported frame memory is handed
    /// over it; given by the orchestrator).
    #[arg(long)]
    frames_socket: Option<PathBuf>,
}

fn read_programs(path: &Path) -> anyhow::Result<Vec<u64>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading program list {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: expected a JSON array of program indices", path.display()))
}

fn build_stepper(cli: &Cli, cfg: &RunConfig) -> anyhow::Result<Box<dyn Stepper>> {
    let programs = cli.programs.as_deref().map(read_programs).transpose()?;
    let on_device = cfg.env.frames == FramePath::Device;
    if cli.synthetic {
        anyhow::ensure!(
            !on_device,
            "--synthetic frames go through shared memory: env.frames must be \"shared_memory\""
        );
        return Ok(Box::new(SyntheticStepper::new(
            cli.worker_id,
            cfg.env.envs_per_worker,
            cfg.env.width,
            cfg.env.height,
            programs,
            cli.expert_hints,
        )));
    }
    let spec = PoolSpec {
        worker_id: cli.worker_id,
        generation: cli.generation,
        programs: programs.map(ProgramSource::Sequence).unwrap_or(ProgramSource::Sample),
        expert_hints: cli.expert_hints,
    };
    let mut pool = EnvPool::new(cfg, spec)?;
    tracing::info!("renderer: {}", pool.renderer_info());
    if on_device {
        let socket = cli.frames_socket.as_deref().context("env.frames = \"device\" needs --frames-socket")?;
        pool.hand_frames_to(socket, std::time::Duration::from_secs(cli.connect_timeout))?;
        tracing::info!("frames stay on the device, handed to the learner over {}", socket.display());
    }
    Ok(Box::new(pool))
}

/// Renders views of the run's first room (the benchmark room without a dataset), E per submit
/// as the environments do, as fast as possible: the renderer-only ceiling of the farm.
fn bench_render(cfg: &RunConfig, seconds: f64) -> anyhow::Result<(f64, String)> {
    let e = cfg.env.envs_per_worker;
    let rcfg = RenderConfig {
        width: cfg.env.width,
        height: cfg.env.height,
        fov_deg: cfg.env.fov_deg,
        max_views_per_submit: e.max(1),
    };
    let mut renderer = Renderer::new(&rcfg).context("starting the renderer")?;
    let room = Dataset::open(&cfg.run.dataset, Verify::Quick).ok().and_then(|ds| {
        let first = *eligible_programs(&ds, cfg).ok()?.first()?;
        let program = Program::from_record(first, &ds.require(cfg.run.split).ok()?.record(first as usize))?;
        let id = program.scene_id();
        Some((ds.scene(id).ok()?.parts(), id.name()))
    });
    let (parts, what) = room.unwrap_or_else(|| (benchmark_room().parts(), "the benchmark room".into()));
    let views = bench_views(&mut renderer, &parts, e, seconds)?;
    Ok((
        views,
        format!("{what}, {}x{}, {e} views per submit, {}", cfg.env.width, cfg.env.height, renderer.adapter_info()),
    ))
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    let cfg = RunConfig::load(&cli.config)?;
    if let Some(seconds) = cli.bench_render {
        let (views, what) = bench_render(&cfg, seconds)?;
        println!("{views:.1} views/s ({what})");
        return Ok(ExitCode::SUCCESS);
    }
    let run_id = cli.run_id.clone().expect("clap requires --run-id");
    let k = cli.worker_id;
    let mut stepper = build_stepper(&cli, &cfg).with_context(|| format!("worker {k}: starting the environments"))?;
    tracing::info!(
        "worker {k} (generation {}): {} envs of {}x{}{}; waiting for the learner",
        cli.generation,
        stepper.num_envs(),
        cfg.env.width,
        cfg.env.height,
        if cli.synthetic { " (synthetic)" } else { "" }
    );
    let mut opts = WorkerOptions::new(&run_id, k, cli.generation, cfg.env.width, cfg.env.height);
    opts.connect_timeout = std::time::Duration::from_secs(cli.connect_timeout);
    match transport::serve(stepper.as_mut(), &opts).with_context(|| format!("worker {k}"))? {
        Exit::Shutdown => {
            tracing::info!("worker {k}: shut down by the learner");
            Ok(ExitCode::SUCCESS)
        }
        Exit::Terminated(sig) => {
            tracing::info!("worker {k}: stopped by {sig}");
            Ok(ExitCode::from(process::signal_exit_code(sig) as u8))
        }
    }
}

fn main() -> ExitCode {
    worker::render::quiet_headless_display();
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .init();
    if let Err(e) = process::install_termination_handler().and_then(|_| process::die_with_parent(Signal::SIGTERM)) {
        eprintln!("worker: cannot set up signal handling: {e}");
        return ExitCode::from(1);
    }
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
