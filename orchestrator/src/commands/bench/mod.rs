//! `orchestrator bench ...`: throughput reports. One variant per benchmark.

pub mod capture;
pub mod farm;
pub mod live;
pub mod remote;
pub mod sim;
pub mod train;

use clap::Subcommand;

use capture::BenchCaptureArgs;
use farm::BenchFarmArgs;
use live::BenchLiveArgs;
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
    /// `orchestrator live` without a browser: the live loop's steps/s over whole episodes, and
    /// a filmed gesture's webcam frames → landmarks → the 95 muscles.
    Live(BenchLiveArgs),
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
        BenchCmd::Live(a) => live::run(a),
    }
}
