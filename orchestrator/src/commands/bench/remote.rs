//! `orchestrator bench remote`: a worker host over Zenoh on loopback against local workers.
//! For each frame size, codec and link (TLS with certificates, plain TCP): `up` with one local
//! worker and one remote slot (`--listen tls|tcp/127.0.0.1`) and `orchestrator workers` joining
//! it, against `up` with two local workers; the Random policy, which answers each worker as soon as it sends, so a worker's
//! frames/s shows what its path costs it.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::Context;
use clap::Args;

use crate::remote::Codec;

#[derive(Args, Debug)]
pub struct BenchRemoteArgs {
    /// Frame sizes (square) to measure.
    #[arg(long, value_delimiter = ',', default_value = "64,224")]
    pub sizes: Vec<u32>,
    /// Codecs of the remote path.
    #[arg(long, value_delimiter = ',', value_enum, default_value = "lz4,zstd,raw")]
    pub codecs: Vec<Codec>,
    /// Links of the remote path: TLS with certificates on both sides, and plain TCP.
    #[arg(long, value_delimiter = ',', value_enum, default_value = "tls,tcp")]
    pub links: Vec<Link>,
    /// Seconds per run.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Environments per worker.
    #[arg(long, default_value_t = 4)]
    pub envs: usize,
    /// Dataset.
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Where to write the runs and the table (default: runs/bench-remote-<UTC time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

impl Default for BenchRemoteArgs {
    /// The command line's defaults (for `bench farm --remote`).
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            args: BenchRemoteArgs,
        }
        <Defaults as clap::Parser>::parse_from(["bench-remote"]).args
    }
}

/// frames/s of each worker of a finished run (frames over `seconds`), from farm_summary.json.
fn worker_fps(run: &Path) -> anyhow::Result<Vec<(u64, f64)>> {
    let p = run.join("farm_summary.json");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).with_context(|| p.display().to_string())?)?;
    let secs = s["seconds"].as_f64().unwrap_or(1.0);
    Ok(s["workers"].as_array().into_iter().flatten().map(|w| (w["frames"].as_u64().unwrap_or(0), secs)).collect())
}

/// How the remote worker's host reaches the learner's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Link {
    Tls,
    Tcp,
}

/// Issues the bench host's bundle once `up` has made the run's certificates.
fn issue_bundle(run: &Path, out: &Path) -> anyhow::Result<()> {
    let t = std::time::Instant::now();
    while !run.join("tls/learner-ca.pem").exists() || !run.join("secret").exists() {
        anyhow::ensure!(t.elapsed() < Duration::from_secs(60), "{}: no TLS certificates after 60 s", run.display());
        std::thread::sleep(Duration::from_millis(100));
    }
    crate::remote::certs::issue(run, "bench", out)
}

fn orchestrator(args: &[String], log: &Path) -> anyhow::Result<std::process::Child> {
    let out = std::fs::File::create(log)?;
    Ok(Command::new(std::env::current_exe()?)
        .args(args)
        .stdin(Stdio::null())
        .stdout(out.try_clone()?)
        .stderr(out)
        .spawn()?)
}

fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

pub fn run(a: BenchRemoteArgs) -> anyhow::Result<()> {
    let out = a.out.clone().unwrap_or_else(|| crate::supervise::run_dir::default_path("bench-remote"));
    std::fs::create_dir_all(&out)?;
    let secs = format!("{}", a.seconds);
    let mut md = format!(
        "| frame | path | local worker (frames/s) | remote worker (frames/s) | remote / local | bytes per observation | MB/s per remote worker |\n|---|---|---:|---:|---:|---:|---:|\n"
    );
    for &size in &a.sizes {
        let cfg = out.join(format!("cfg{size}.toml"));
        std::fs::write(
            &cfg,
            format!(
                "[run]\nmethod = \"both\"\nseed = 7\ndataset = \"{}\"\n\n[env]\nenvs_per_worker = {}\nwidth = {size}\nheight = {size}\n",
                std::fs::canonicalize(&a.dataset)?.display(),
                a.envs
            ),
        )?;
        md += &local_row(&out, &cfg, size, &secs)?;
        for (&codec, &link) in a.codecs.iter().flat_map(|c| a.links.iter().map(move |l| (c, l))) {
            md += &remote_row(&out, &cfg, size, &secs, codec, link)?;
        }
    }
    farm::files::write_atomic(&out.join("bench_remote.md"), md.as_bytes())?;
    println!("{md}");
    eprintln!("[bench] written {}", out.join("bench_remote.md").display());
    Ok(())
}

/// Two local workers of `size`² frames for `secs`: the table's baseline row.
fn local_row(out: &Path, cfg: &Path, size: u32, secs: &str) -> anyhow::Result<String> {
    let base = out.join(format!("{size}-local"));
    eprintln!("[bench] {size}×{size}: two local workers ...");
    let mut up = orchestrator(
        &[
            s(&["up", "--workers", "2", "--policy", "random", "--seconds", &secs, "--config"]),
            vec![cfg.display().to_string()],
            s(&["--run-dir"]),
            vec![base.display().to_string()],
        ]
        .concat(),
        &out.join(format!("{size}-local.log")),
    )?;
    anyhow::ensure!(up.wait()?.success(), "the local run failed; see {}", out.display());
    let local = worker_fps(&base)?;
    let local_fps = local.iter().map(|(f, t)| *f as f64 / t).sum::<f64>() / local.len().max(1) as f64;
    Ok(format!("| {size}² | local only | {local_fps:.0} | | | | |\n"))
}

/// A local worker beside a remote one whose frames travel `codec` over `link`: its row.
fn remote_row(out: &Path, cfg: &Path, size: u32, secs: &str, codec: Codec, link: Link) -> anyhow::Result<String> {
    let name = format!("{size}-{codec:?}-{link:?}").to_lowercase();
    let run = out.join(&name);
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let endpoint = format!("{}/127.0.0.1:{port}", format!("{link:?}").to_lowercase());
    eprintln!("[bench] {size}×{size}: a local and a remote worker, {codec:?} over {link:?} ...");
    let insecure = if link == Link::Tcp { vec!["--insecure".to_string()] } else { vec![] };
    let mut up = orchestrator(
        &[
            s(&["up", "--workers", "1", "--remote-workers", "1", "--secret", "bench", "--policy", "random"]),
            s(&["--listen", &endpoint, "--seconds", &secs, "--config"]),
            vec![cfg.display().to_string(), "--run-dir".into(), run.display().to_string()],
            insecure.clone(),
        ]
        .concat(),
        &out.join(format!("{name}-up.log")),
    )?;
    let info = crate::supervise::run_dir::wait_for_info(&run, up.id(), Duration::from_secs(60))?;
    let credentials = match link {
        Link::Tls => {
            let bundle = out.join(format!("{name}-bundle"));
            issue_bundle(&run, &bundle)?;
            vec!["--certs".to_string(), bundle.display().to_string()]
        }
        Link::Tcp => [insecure, s(&["--run-id", &info.run_id, "--secret", "bench"])].concat(),
    };
    let host_log = out.join(format!("{name}-host.log"));
    let mut host = orchestrator(
        &[
            s(&["workers", "--connect", &endpoint, "--workers", "1"]),
            credentials,
            s(&["--codec", &format!("{codec:?}").to_lowercase(), "--dir"]),
            vec![out.join(format!("{name}-host")).display().to_string()],
        ]
        .concat(),
        &host_log,
    )?;
    anyhow::ensure!(up.wait()?.success(), "the run failed; see {}", out.display());
    anyhow::ensure!(host.wait()?.success(), "the worker host failed; see {}", host_log.display());
    let fps = worker_fps(&run)?;
    let log = std::fs::read_to_string(&host_log)?;
    // "[workers] N observations (X MB) sent, ..." and "[workers] ended after S s"
    let last = |key: &str| log.lines().rev().find(|l| l.contains(key)).map(str::to_string).unwrap_or_default();
    let words = last("observations");
    let w: Vec<&str> = words.split_whitespace().collect();
    let (obs, mb) = (
        w.get(1).and_then(|x| x.parse::<f64>().ok()).unwrap_or(f64::NAN),
        w.get(3).and_then(|x| x.trim_start_matches('(').parse::<f64>().ok()).unwrap_or(f64::NAN),
    );
    let host_secs =
        last("ended after").split_whitespace().nth(3).and_then(|x| x.parse::<f64>().ok()).unwrap_or(f64::NAN);
    let (lf, rf) = (fps[0].0 as f64 / fps[0].1, fps[1].0 as f64 / host_secs);
    Ok(format!(
        "| {size}² | local + remote, {codec:?}, {link:?} | {lf:.0} | {rf:.0} | {:.0}% | {:.0} | {:.1} |\n",
        100.0 * rf / lf,
        mb * 1e6 / obs,
        mb / host_secs
    ))
}
