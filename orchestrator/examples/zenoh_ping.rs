//! Zenoh's round trip between two processes on loopback, for docs/bench/log.md ("More than
//! one machine"): `zenoh_ping pong PORT [--hint]` answers each message with 100 bytes;
//! `zenoh_ping ping PORT N BYTES [--hint]` sends N messages of BYTES, one at a time, and prints
//! the round trip's mean and percentiles. `--hint` sets the bridges' latency hint on every
//! thread of the process.

use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::qos::CongestionControl;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: zenoh_ping pong PORT [--hint] | zenoh_ping ping PORT N BYTES [--hint]";
    anyhow::ensure!(args.len() >= 3, "{usage}");
    if args.iter().any(|a| a == "--hint") {
        orchestrator::remote::short_slices();
    }
    let endpoint = vec![format!("tcp/127.0.0.1:{}", args[2])];
    let put = |s: &zenoh::Session, key: &str, bytes: Vec<u8>| {
        s.put(key, bytes).congestion_control(CongestionControl::Block).express(true).wait()
    };
    match args[1].as_str() {
        "pong" => {
            let s = open(&endpoint, &[])?;
            let sub = s.declare_subscriber("ping/req").wait().map_err(anyhow::Error::msg)?;
            while sub.recv().is_ok() {
                put(&s, "ping/rep", vec![1; 100]).map_err(anyhow::Error::msg)?;
            }
        }
        "ping" => {
            anyhow::ensure!(args.len() >= 5, "{usage}");
            let (n, bytes): (usize, usize) = (args[3].parse()?, args[4].parse()?);
            let s = open(&[], &endpoint)?;
            let sub = s.declare_subscriber("ping/rep").wait().map_err(anyhow::Error::msg)?;
            std::thread::sleep(Duration::from_secs(1));
            let mut us = Vec::with_capacity(n);
            for i in 0..n + 100 {
                let t = Instant::now();
                put(&s, "ping/req", vec![7; bytes]).map_err(anyhow::Error::msg)?;
                sub.recv().map_err(anyhow::Error::msg)?;
                if i >= 100 {
                    us.push(t.elapsed().as_secs_f64() * 1e6);
                }
            }
            us.sort_by(f64::total_cmp);
            let p = |q: f64| us[((us.len() - 1) as f64 * q) as usize];
            let mean = us.iter().sum::<f64>() / n as f64;
            println!("{bytes} B: mean {mean:.0} µs, p50 {:.0}, p90 {:.0}, p99 {:.0}", p(0.5), p(0.9), p(0.99));
        }
        _ => anyhow::bail!("{usage}"),
    }
    Ok(())
}

/// A peer session as the bridges configure it over plain TCP (`--insecure`), opened from this
/// thread (so without the hint unless `--hint` set it).
fn open(listen: &[String], connect: &[String]) -> anyhow::Result<zenoh::Session> {
    let insecure = orchestrator::remote::Security::Insecure;
    zenoh::open(orchestrator::remote::config(listen, connect, &insecure)?).wait().map_err(anyhow::Error::msg)
}
