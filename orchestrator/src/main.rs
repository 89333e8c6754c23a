//! `orchestrator`: the command line of GesTHOR-RS. Each subcommand is one variant here and one
//! module of the library; this file only parses and dispatches.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use orchestrator::{bench_sim, dataset_cmd, render_cmd};

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
    /// The simulator's speed in one process.
    BenchSim(bench_sim::SimArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Dataset(c) => dataset_cmd::run(c),
        Command::Render(a) => render_cmd::run(a),
        Command::BenchSim(a) => bench_sim::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
