//! `orchestrator`: the command line of GesTHOR-RS. Each subcommand is one variant here and one
//! module of the library's `commands`; this file only parses and dispatches.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use tracing_subscriber::Layer;

use orchestrator::commands::{
    bench, dataset, encoder, eval, follow, gesture, hosts, live, model, program, render, robot, soak, study, up,
    workers,
};

#[derive(Parser)]
#[command(
    name = "orchestrator",
    version,
    about = "GesTHOR-RS: build the dataset, run the rollout farm, evaluate, benchmark"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build GOND or draw its statistics.
    #[command(subcommand)]
    Dataset(dataset::DatasetCmd),
    /// Render what the robot sees in a room, and a top-down map.
    Render(render::RenderArgs),
    /// Export a program in the original recorder's folder layout.
    #[command(subcommand)]
    Program(program::ProgramCmd),
    /// Render the person performing a program's gesture (robot view and from above, PNG + GIF).
    Replay(program::ReplayArgs),
    /// A person's own gesture from a video (capture), and the avatar's filmed (film).
    #[command(subcommand)]
    Gesture(gesture::GestureCmd),
    /// A trained agent answers a gesture: one program with a captured motion, a GIF and SR/SPL.
    Follow(follow::FollowArgs),
    /// A person in the scene with a trained robot, in the browser: a local web server running
    /// the simulator for each tab, the person's gesture from a program or their webcam.
    Live(live::LiveArgs),
    /// The trained robot as a ROS 2 node on a real robot's topics (`robot sim`: GesTHOR
    /// published as such a robot, to run it against).
    Robot(robot::RobotArgs),
    /// Shipped models: make a checkpoint one (weights, config, card, check), or check one.
    #[command(subcommand)]
    Model(model::ModelCmd),
    /// Start a run: the learner and N worker processes, supervised; Ctrl-C stops it cleanly.
    Up(up::UpArgs),
    /// Evaluate a checkpoint (or the Random baseline) on a split: the tables of chapter 4.
    Eval(eval::EvalArgs),
    /// The frozen visual encoder for CPU runs: render labelled frames, pretrain.
    #[command(subcommand)]
    Encoder(encoder::EncoderCmd),
    /// Throughput benchmarks.
    #[command(subcommand)]
    Bench(bench::BenchCmd),
    /// The dissertation's comparison (T4.2): every method trained with N seeds, checkpoints
    /// selected on val, tested; resumable (the same command continues a killed study).
    Study(study::StudyArgs),
    /// A training run under a seeded schedule of kills and Ctrl-Cs, resumed after each stop;
    /// checks that no checkpoint, sample or file is lost or left.
    Soak(soak::SoakArgs),
    /// Run workers here for a run whose learner is on another machine (`up --listen`).
    Workers(workers::WorkersArgs),
    /// Who may join a run over TLS: issue a worker host's bundle, revoke it, list them.
    #[command(subcommand)]
    Hosts(hosts::HostsCmd),
}

fn main() -> ExitCode {
    worker::render::quiet_headless_display();
    // Library and driver logs (wgpu, naga, Vulkan loader) reach the terminal only when asked
    // for; why a TLS link was refused is read from Zenoh's logs always.
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let logs = std::env::var_os("RUST_LOG").is_some().then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(std::io::stderr)
            .with_filter(tracing_subscriber::EnvFilter::from_default_env())
    });
    tracing_subscriber::registry().with(logs).with(orchestrator::remote::refusals::layer()).init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Dataset(c) => dataset::run(c).map(|_| 0),
        Command::Render(a) => render::run(a).map(|_| 0),
        Command::Program(c) => program::run(c).map(|_| 0),
        Command::Replay(a) => program::replay(a).map(|_| 0),
        Command::Gesture(c) => gesture::run(c).map(|_| 0),
        Command::Follow(a) => follow::run(a).map(|_| 0),
        Command::Live(a) => live::run(a).map(|_| 0),
        Command::Model(c) => model::run(c).map(|_| 0),
        Command::Robot(a) => robot::run(a).map(|_| 0),
        Command::Up(a) => up::run(a),
        Command::Eval(a) => eval::run(a).map(|_| 0),
        Command::Encoder(c) => encoder::run(c).map(|_| 0),
        Command::Bench(c) => bench::run(c).map(|_| 0),
        Command::Study(a) => study::run(a).map(|_| 0),
        Command::Soak(a) => soak::run(a),
        Command::Workers(a) => workers::run(a),
        Command::Hosts(c) => hosts::run(c).map(|_| 0),
    };
    match result {
        Ok(code) => ExitCode::from(code.clamp(0, 255) as u8),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
