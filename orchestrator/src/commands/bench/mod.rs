//! `orchestrator bench ...`: throughput reports. One variant per benchmark.

pub mod capture;
pub mod farm;
pub mod remote;
pub mod sim;
pub mod train;

use clap::Subcommand;

use capture::BenchCaptureArgs;
use farm::BenchFarmArgs;
use remote::BenchRemoteArgs;
use sim::SimArgs;
use train::BenchTrainArgs;

#[derive(Subcommand, Debug)]
pub enum BenchCmd {
    /// Farm scaling: aggregate frames/s, CPU per worker and step latency for several worker
    /// counts, against a renderer-only ceiling.
    Farm(BenchFarmArgs),
    /// The simulator's speed in one process: renderer, env steps, env loop with rendering.
    Sim(SimArgs),
    /// Training throughput end to end for a fixed frame count, and where the time went
    /// (learner: update, inference, waiting; workers: env step, render, transport).
    Train(BenchTrainArgs),
    /// A worker host over Zenoh on loopback against local workers: frames/s and bytes per
    /// remote worker, per frame size and codec.
    Remote(BenchRemoteArgs),
    /// The closed loop of `gesture capture`: filmed avatar gestures captured back, pointing
    /// lines against the originals.
    Capture(BenchCaptureArgs),
}

pub fn run(cmd: BenchCmd) -> anyhow::Result<()> {
    match cmd {
        BenchCmd::Farm(a) if a.remote => {
            remote::run(BenchRemoteArgs { seconds: a.seconds, out: a.out, ..Default::default() })
        }
        BenchCmd::Farm(a) => farm::run(a),
        BenchCmd::Sim(a) => sim::run(a),
        BenchCmd::Train(a) => train::run(a),
        BenchCmd::Remote(a) => remote::run(a),
        BenchCmd::Capture(a) => capture::run(a),
    }
}
