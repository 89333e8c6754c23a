//! `orchestrator`: the command line of GesTHOR-RS. Each subcommand is one variant here and one
//! module of the library; this file only parses and dispatches.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use orchestrator::{bench_sim, dataset_cmd, program_cmd, render_cmd};

#[derive(Parser)]
#[command(name = "orchestrator", version, about = "GesTHOR-RS: build the dataset, run the rollout farm, evaluate, benchmark")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build GOND or draw its statistics.
    #[command(subcommand)]
    Dataset(dataset_cmd::DatasetCmd),
    /// Render what the robot sees in a room, and a top-down map.
    Render(render_cmd::RenderArgs),
    /// Export a program in the original recorder's folder layout.
    #[command(subcommand)]
    Program(program_cmd::ProgramCmd),
    /// Render the person performing a program's gesture (robot view and from above, PNG + GIF).
    Replay(program_cmd::ReplayArgs),
    /// The simulator's speed in one process.
    BenchSim(bench_sim::SimArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Dataset(c) => dataset_cmd::run(c),
        Command::Render(a) => render_cmd::run(a),
        Command::BenchSim(a) => bench_sim::run(a),
        Command::Program(c) => program_cmd::run(c),
        Command::Replay(a) => program_cmd::replay(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
