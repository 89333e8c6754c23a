//! `orchestrator bench ...`: throughput reports. One variant per benchmark.

use clap::Subcommand;

use crate::bench_farm::{self, BenchFarmArgs};

#[derive(Subcommand, Debug)]
pub enum BenchCmd {
    /// Farm scaling: aggregate frames/s, CPU per worker and step latency for several worker
    /// counts, against a renderer-only ceiling.
    Farm(BenchFarmArgs),
}

pub fn run(cmd: BenchCmd) -> anyhow::Result<()> {
    match cmd {
        BenchCmd::Farm(a) => bench_farm::run(a),
    }
}
