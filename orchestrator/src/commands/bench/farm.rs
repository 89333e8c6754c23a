//! `orchestrator bench farm`: how the farm scales with the number of worker processes.
//!
//! For each worker count the farm runs with the random policy; after every worker has sent and
//! a warm-up, the learner's own counters give the aggregate frame rate and the mean step round
//! trip over the measured window, and `/proc/<pid>/stat` gives each process's CPU use. A
//! renderer-only ceiling (`worker --bench-render`: one process rendering the same scene content
//! as fast as it can) is measured in the same run. Results: a Markdown table and a CSV in the
//! bench directory.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use farm::config::RunConfig;
use farm::process;
use nix::unistd::Pid;

use crate::supervise::binaries;
use crate::supervise::child;
use crate::supervise::crew::{Crew, CrewSpec, CrewState};
use crate::supervise::launch;
use farm::progress::Progress;
use farm::serve_args::Policy;

/// The bench's configuration when none is given: the dissertation's 224×224 RGB-D frames.
pub const BENCH_CONFIG: &str = r#"# Embedded configuration of `orchestrator bench farm`: 224x224 RGB-D, 4 envs per worker.
[run]
method = "both"
dataset = "data/gond"

[env]
envs_per_worker = 4
width = 224
height = 224
"#;

#[derive(Args, Debug)]
pub struct BenchFarmArgs {
    /// Worker counts to measure.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,20")]
    pub workers: Vec<usize>,
    /// Run configuration (default: 224×224, 4 envs per worker, data/gond).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seconds measured per worker count (after the warm-up).
    #[arg(long, default_value_t = 20.0)]
    pub seconds: f64,
    /// Seconds of warm-up once every worker has sent its first observation.
    #[arg(long, default_value_t = 5.0)]
    pub warmup: f64,
    /// Where to write the table and the runs (default: runs/bench-farm-<UTC time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Synthetic environments: measures the farm's transport alone (no simulator, no renderer).
    #[arg(long)]
    pub synthetic: bool,
    /// A worker host over Zenoh on loopback against local workers instead: `bench remote`
    /// with its defaults and these `--seconds` and `--out`.
    #[arg(long, conflicts_with_all = ["workers", "config", "synthetic"])]
    pub remote: bool,
}

/// One row of the table.
#[derive(Clone, Debug, Default)]
pub struct Row {
    pub workers: usize,
    pub fps: f64,
    /// Mean CPU use of one worker process, percent of one core.
    pub worker_cpu: f64,
    pub learner_cpu: f64,
    /// CPU other processes of the machine took during the window, percent of one core.
    pub other_cpu: f64,
    pub latency_ms: Option<f64>,
    pub frames: u64,
    pub window_s: f64,
    pub restarts: u64,
    pub integrity_errors: u64,
}

fn cpu(pids: &[Option<Pid>]) -> Vec<Option<f64>> {
    pids.iter().map(|p| p.and_then(child::cpu_seconds)).collect()
}

/// Ticks the farm until `pred` holds for its progress, or `timeout`.
fn wait_for(
    crew: &mut Crew,
    timeout: Duration,
    what: &str,
    mut pred: impl FnMut(&Progress) -> bool,
) -> anyhow::Result<Progress> {
    let start = Instant::now();
    loop {
        if crew.tick()? == CrewState::Ended || crew.is_stopping() {
            anyhow::bail!("the farm ended while waiting for {what}");
        }
        if process::termination_signal().is_some() {
            anyhow::bail!("interrupted");
        }
        if let Some(p) = crew.progress()
            && pred(&p)
        {
            return Ok(p);
        }
        if start.elapsed() > timeout {
            anyhow::bail!("no {what} within {} s", timeout.as_secs());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn measure(n: usize, a: &BenchFarmArgs, cfg: &RunConfig, out: &Path) -> anyhow::Result<Row> {
    let run_dir = out.join(format!("w{n}"));
    let (dir, config_path) = launch::prepare_run(&run_dir, cfg, false, n, Policy::Random)?;
    let mut spec = CrewSpec::new(&dir.path, &dir.run_id, &config_path, cfg.clone(), n, Policy::Random);
    spec.synthetic = a.synthetic;
    spec.report_every = 0.5;
    spec.check = true;
    // A safety net: the learner ends the run by itself should this process hang.
    spec.max_seconds = Some(300.0 + a.warmup + a.seconds);
    let mut crew = Crew::start(spec)?;
    let result = (|| -> anyhow::Result<Row> {
        let startup = Duration::from_secs(60 + 10 * n as u64);
        wait_for(&mut crew, startup, "first observation from every worker", |p| {
            p.workers_seen == n && p.totals.frames > 0
        })?;
        let warm_until = Instant::now() + Duration::from_secs_f64(a.warmup);
        while Instant::now() < warm_until {
            crew.tick()?;
            std::thread::sleep(Duration::from_millis(50));
        }
        let p0 = crew.progress().context("no progress record")?;
        let p0 = wait_for(&mut crew, Duration::from_secs(10), "a fresh progress record", |p| p.t > p0.t)?;
        let (w0, c0, l0, g0) = (
            Instant::now(),
            cpu(&crew.worker_pids()),
            crew.learner_pid().and_then(child::cpu_seconds),
            crew.generations(),
        );
        let m0 = child::machine_cpu_seconds();
        let until = Instant::now() + Duration::from_secs_f64(a.seconds);
        while Instant::now() < until {
            if crew.tick()? == CrewState::Ended {
                anyhow::bail!("the farm ended during the measurement");
            }
            anyhow::ensure!(process::termination_signal().is_none(), "interrupted");
            std::thread::sleep(Duration::from_millis(50));
        }
        let p1 = crew.progress().context("no progress record")?;
        let p1 = wait_for(&mut crew, Duration::from_secs(10), "a fresh progress record", |p| p.t > p1.t)?;
        let (wall, c1, l1, g1) = (
            w0.elapsed().as_secs_f64(),
            cpu(&crew.worker_pids()),
            crew.learner_pid().and_then(child::cpu_seconds),
            crew.generations(),
        );
        let m1 = child::machine_cpu_seconds();
        let per_worker: Vec<f64> =
            (0..n).filter(|&k| g0[k] == g1[k]).filter_map(|k| Some(100.0 * (c1[k]? - c0[k]?) / wall)).collect();
        let dt = (p1.t - p0.t).max(1e-9);
        let dl = p1.totals.latency_count.saturating_sub(p0.totals.latency_count);
        let learner_cpu = match (l0, l1) {
            (Some(a), Some(b)) => 100.0 * (b - a) / wall,
            _ => f64::NAN,
        };
        // Everything busy on the machine minus this farm: someone else's load.
        let ours: f64 =
            (0..n).filter_map(|k| Some(100.0 * (c1[k]? - c0[k]?) / wall)).sum::<f64>() + learner_cpu.max(0.0);
        let other_cpu = match (m0, m1) {
            (Some((b0, _)), Some((b1, _))) => (100.0 * (b1 - b0) / wall - ours).max(0.0),
            _ => f64::NAN,
        };
        Ok(Row {
            workers: n,
            fps: (p1.totals.frames - p0.totals.frames) as f64 / dt,
            worker_cpu: per_worker.iter().sum::<f64>() / per_worker.len().max(1) as f64,
            learner_cpu,
            other_cpu,
            latency_ms: (dl > 0).then(|| 1000.0 * (p1.totals.latency_sum_s - p0.totals.latency_sum_s) / dl as f64),
            frames: p1.totals.frames - p0.totals.frames,
            window_s: dt,
            restarts: crew.restarts(),
            integrity_errors: p1.totals.lost + p1.totals.duplicates + p1.totals.corrupt,
        })
    })();
    crew.stop();
    let outcome = crew.finish();
    let row = result?;
    outcome?;
    Ok(row)
}

/// Runs `worker --bench-render` and returns its views/s (or why it could not).
fn render_ceiling(config_path: &Path, seconds: f64) -> Result<f64, String> {
    let bin = binaries::sibling("worker").map_err(|e| e.to_string())?;
    let out = std::process::Command::new(&bin)
        .args(["--config".as_ref(), config_path.as_os_str(), "--bench-render".as_ref(), seconds.to_string().as_ref()])
        .output()
        .map_err(|e| format!("running {}: {e}", bin.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().lines().last().unwrap_or("failed").to_string());
    }
    text.split_whitespace()
        .next()
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| format!("unexpected output `{}`", text.trim()))
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.filter(|x| x.is_finite()).map(|x| format!("{x:.digits$}")).unwrap_or_else(|| "-".into())
}

/// The table as Markdown (with the targets) and as CSV.
pub fn report(rows: &[Row], ceiling: &Result<f64, String>, cfg: &RunConfig, a: &BenchFarmArgs) -> (String, String) {
    let one = rows.iter().find(|r| r.workers == 1).map(|r| r.fps);
    let best = rows.iter().map(|r| r.fps).fold(0.0, f64::max);
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Farm scaling\n\n{}x{} RGB-D frames, {} envs per worker, random policy{}; {} s measured per row after {} s of warm-up; {} CPU cores. CPU % is of one core; \"other processes\" is what the rest of the machine used meanwhile (a busy machine lowers the figures).\n",
        cfg.env.width,
        cfg.env.height,
        cfg.env.envs_per_worker,
        if a.synthetic { ", synthetic environments (transport only)" } else { "" },
        a.seconds,
        a.warmup,
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0)
    );
    let _ = writeln!(
        md,
        "| workers | frames/s | × 1 worker | CPU % per worker | learner CPU % | other processes CPU % | step round trip (ms) | frames measured | restarts | integrity errors |"
    );
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let csv = rows_table(&mut md, rows, one);
    let _ = writeln!(md);
    match ceiling {
        Ok(c) => {
            let _ = writeln!(
                md,
                "Renderer-only ceiling (one process, same scene content, {} views per submit): **{c:.1} views/s**.\n",
                cfg.env.envs_per_worker
            );
        }
        Err(e) => {
            let _ = writeln!(md, "Renderer-only ceiling: not measured ({e}).\n");
        }
    }
    targets(&mut md, rows, ceiling, one, best);
    (md, csv)
}

/// One row per worker count into `md`; the same rows as CSV, returned.
fn rows_table(md: &mut String, rows: &[Row], one: Option<f64>) -> String {
    let mut csv = String::from(
        "workers,frames_per_s,speedup_vs_1,worker_cpu_pct,learner_cpu_pct,other_cpu_pct,step_latency_ms,frames,window_s,restarts,integrity_errors\n",
    );
    for r in rows {
        let speedup = one.map(|o| r.fps / o.max(1e-9));
        let _ = writeln!(
            md,
            "| {} | {:.1} | {} | {:.0} | {} | {} | {} | {} | {} | {} |",
            r.workers,
            r.fps,
            fmt_opt(speedup, 2),
            r.worker_cpu,
            fmt_opt(Some(r.learner_cpu), 0),
            fmt_opt(Some(r.other_cpu), 0),
            fmt_opt(r.latency_ms, 2),
            r.frames,
            r.restarts,
            r.integrity_errors
        );
        let _ = writeln!(
            csv,
            "{},{:.2},{},{:.1},{},{},{},{},{:.2},{},{}",
            r.workers,
            r.fps,
            fmt_opt(speedup, 3),
            r.worker_cpu,
            fmt_opt(Some(r.learner_cpu), 1),
            fmt_opt(Some(r.other_cpu), 1),
            fmt_opt(r.latency_ms, 3),
            r.frames,
            r.window_s,
            r.restarts,
            r.integrity_errors
        );
    }
    csv
}

/// The farm's targets, measured: scaling to 2 and 20 workers, and the renderer's ceiling.
fn targets(md: &mut String, rows: &[Row], ceiling: &Result<f64, String>, one: Option<f64>, best: f64) {
    let mut targets = vec![];
    if let (Some(o), Some(two)) = (one, rows.iter().find(|r| r.workers == 2)) {
        targets.push(("2 workers ≥ 1.8 × 1 worker", two.fps / o.max(1e-9), 1.8));
    }
    if let Some(twenty) = rows.iter().find(|r| r.workers == 20) {
        targets.push(("20 workers ≥ 90% of the best count", twenty.fps / best.max(1e-9), 0.9));
    }
    if let Ok(c) = ceiling {
        targets.push(("best aggregate ≥ 80% of the renderer-only ceiling", best / c.max(1e-9), 0.8));
    }
    if !targets.is_empty() {
        let _ = writeln!(md, "| target | measured | met |\n|---|---:|:---:|");
        for (name, v, want) in targets {
            let _ = writeln!(md, "| {name} | {v:.2} | {} |", if v >= want { "yes" } else { "no" });
        }
    }
}

pub fn run(a: BenchFarmArgs) -> anyhow::Result<()> {
    process::install_termination_handler()?;
    anyhow::ensure!(
        !a.workers.is_empty() && a.workers.iter().all(|&n| n > 0),
        "--workers: give positive counts, e.g. 1,2,4"
    );
    let mut cfg = match &a.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::from_toml(BENCH_CONFIG, "(embedded bench config)")?,
    };
    launch::resolve_dataset(&mut cfg, a.synthetic)?;
    launch::sweep_dead_runs();
    let out = a.out.clone().unwrap_or_else(|| crate::supervise::run_dir::default_path("bench-farm"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let config_path = out.join("config.toml");
    farm::files::write_atomic(&config_path, cfg.to_toml().as_bytes())?;
    let ceiling = if a.synthetic {
        Err("synthetic environments render nothing".to_string())
    } else {
        eprintln!("[bench] renderer-only ceiling ({} s) ...", a.seconds.min(10.0));
        render_ceiling(&config_path, a.seconds.min(10.0))
    };
    let mut rows = vec![];
    for &n in &a.workers {
        eprintln!("[bench] {n} worker(s) ...");
        let row = measure(n, &a, &cfg, &out).with_context(|| format!("measuring {n} workers"))?;
        eprintln!(
            "[bench] {n} worker(s): {:.1} frames/s, {:.0}% CPU per worker, step {} ms",
            row.fps,
            row.worker_cpu,
            fmt_opt(row.latency_ms, 2)
        );
        rows.push(row);
    }
    let (md, csv) = report(&rows, &ceiling, &cfg, &a);
    farm::files::write_atomic(&out.join("bench_farm.md"), md.as_bytes())?;
    farm::files::write_atomic(&out.join("bench_farm.csv"), csv.as_bytes())?;
    println!("{md}");
    eprintln!("[bench] written {} and {}", out.join("bench_farm.md").display(), out.join("bench_farm.csv").display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_report_checks_the_targets() {
        let cfg = RunConfig::from_toml(BENCH_CONFIG, "x").unwrap();
        let a = BenchFarmArgs {
            workers: vec![1, 2, 20],
            config: None,
            seconds: 5.0,
            warmup: 1.0,
            out: None,
            synthetic: false,
            remote: false,
        };
        let row = |w, fps| Row {
            workers: w,
            fps,
            worker_cpu: 50.0,
            learner_cpu: 5.0,
            latency_ms: Some(3.0),
            frames: 100,
            window_s: 5.0,
            ..Default::default()
        };
        let (md, csv) = report(&[row(1, 100.0), row(2, 190.0), row(20, 170.0)], &Ok(200.0), &cfg, &a);
        assert!(md.contains("| 2 workers ≥ 1.8 × 1 worker | 1.90 | yes |"), "{md}");
        assert!(md.contains("| 20 workers ≥ 90% of the best count | 0.89 | no |"), "{md}");
        assert!(md.contains("| best aggregate ≥ 80% of the renderer-only ceiling | 0.95 | yes |"), "{md}");
        assert_eq!(csv.lines().count(), 4);
    }
}
