//! `orchestrator workers`: this machine becomes a worker host of a run whose learner is on
//! another machine (`orchestrator up --listen`). It joins the run over Zenoh, runs N workers
//! here exactly as `up` does (same supervision and restarts, shared memory on this host), and
//! bridges their observations to the learner and the learner's actions back (`remote`).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;

use farm::config::RunConfig;
use farm::process;

use crate::remote::certs::JoinInfo;
use crate::remote::{self, BridgeCounts, Codec, HostBridge, HostOptions, JoinGrant};
use crate::supervise::crew::{Crew, CrewSpec, CrewState, HostSlots};
use farm::serve_args::Policy;

#[derive(Args, Debug)]
pub struct WorkersArgs {
    /// The learner host's endpoint (e.g. tls/10.0.0.5:7447).
    #[arg(long)]
    pub connect: String,
    /// This host's bundle from `orchestrator hosts issue` (its certificate, the learner's CA,
    /// the run id and secret).
    #[arg(long, value_name = "DIR")]
    pub certs: Option<PathBuf>,
    /// Allow --connect tcp/...: plain TCP, no certificates (loopback experiments).
    #[arg(long)]
    pub insecure: bool,
    /// Worker processes on this machine.
    #[arg(long, default_value_t = 4, value_parser = super::values::workers)]
    pub workers: usize,
    /// The run to join (default: the bundle's; `up --listen` prints it).
    #[arg(long)]
    pub run_id: Option<String>,
    /// The run's secret (default: the bundle's, else $GESTHOR_SECRET; `up --listen` prints it).
    #[arg(long)]
    pub secret: Option<String>,
    /// The dataset on this machine (default: the path in the run's config); it must be the
    /// learner's dataset (its manifest is compared).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Folder for this host's copy of the config and its workers' logs (default:
    /// runs/host-<run id>).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// How observations travel: LZ4- or Zstandard-compressed, or raw (BENCHMARKS.md compares them).
    #[arg(long, value_enum, default_value_t = Codec::Lz4)]
    pub codec: Codec,
    /// Step synthetic environments (the farm's plumbing only).
    #[arg(long)]
    pub synthetic: bool,
    /// Seconds to keep asking while the learner is not up yet.
    #[arg(long, default_value_t = 60.0, value_parser = super::values::seconds)]
    pub wait: f64,
}

/// SHA-256 of a dataset's manifest: the same bytes mean the same dataset (it holds every
/// file's checksum).
pub fn manifest_digest(dataset: &std::path::Path) -> anyhow::Result<String> {
    let p = dataset.join("manifest.json");
    let bytes = std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?;
    Ok(farm::files::sha256_hex(&bytes))
}

pub fn run(a: WorkersArgs) -> anyhow::Result<i32> {
    remote::check_endpoint(&a.connect, a.insecure, "--connect")?;
    let (security, bundle) = security(&a)?;
    let (run_id, secret) = credentials(&a, bundle.as_ref())?;
    process::install_termination_handler()?;
    let session = remote::session(&[], std::slice::from_ref(&a.connect), &security)?;
    let host = bundle.as_ref().map(|b| b.name.clone()).unwrap_or_else(remote::hostname);
    let Some(grant) = join(&a, &session, &run_id, &secret, &host)? else { return Ok(130) };
    let cfg = host_config(&a, &grant)?;
    // Shared memory of earlier hosts on this machine that were killed (after the join: a
    // refused host says one line).
    crate::supervise::launch::sweep_dead_runs();
    let dir = a.dir.clone().unwrap_or_else(|| PathBuf::from("runs").join(format!("host-{}", run_id)));
    std::fs::create_dir_all(dir.join("logs"))?;
    let config_path = dir.join("config.toml");
    farm::files::write_atomic(&config_path, cfg.to_toml().as_bytes())?;
    // This host's own shared-memory domain, apart from any other run or host on the machine.
    let local_run_id = format!("{}-h{:06x}", run_id, grant.token & 0xff_ffff);
    let slots = grant.first_slot..grant.first_slot + a.workers as u32;
    eprintln!(
        "[workers] joined run {} at {}: {} workers as learner slots {}..{}, generations from {}",
        run_id,
        a.connect,
        a.workers,
        slots.start,
        slots.end - 1,
        grant.first_generation
    );
    let host_slots = HostSlots { first_slot: grant.first_slot, first_generation: grant.first_generation };
    let options =
        HostOptions { run_id, local_run_id: local_run_id.clone(), grant, workers: a.workers as u32, codec: a.codec };
    let bridge = HostBridge::start(session, options)?;
    let mut spec = CrewSpec::new(&dir, &local_run_id, &config_path, cfg, a.workers, Policy::Ppo);
    spec.host = Some(host_slots);
    spec.synthetic = a.synthetic;
    let mut crew = Crew::start(spec)?;
    let learner_gone = supervise(&mut crew, &bridge)?;
    // The bridge's ports go first: ending the host's shared-memory domain needs every node gone.
    let counts = bridge.counts.clone();
    bridge.finish()?;
    let out = crew.finish()?;
    // The totals last: `bench remote` reads the bytes per observation from this line.
    traffic(&counts, out.restarts);
    eprintln!("[workers] ended after {:.1} s, {} worker restart(s)", out.seconds, out.restarts);
    Ok(match process::termination_signal() {
        Some(sig) => process::signal_exit_code(sig),
        None if learner_gone => 1,
        None => 0,
    })
}

/// How this host talks to the learner's: TLS with its bundle (`--certs`), or plain TCP.
fn security(a: &WorkersArgs) -> anyhow::Result<(remote::Security, Option<JoinInfo>)> {
    Ok(match (&a.certs, a.connect.starts_with("tls/")) {
        (Some(dir), true) => {
            let (files, join) = remote::certs::host_files(dir)?;
            (remote::Security::Tls { files, access: None }, Some(join))
        }
        (None, true) => anyhow::bail!(
            "--connect {}: TLS needs this host's bundle (--certs DIR); `orchestrator hosts issue` makes it on the learner's host",
            a.connect
        ),
        (_, false) => (remote::Security::Insecure, None),
    })
}

/// The run to join and its secret: from the arguments, the bundle, or $GESTHOR_SECRET.
fn credentials(a: &WorkersArgs, bundle: Option<&JoinInfo>) -> anyhow::Result<(String, String)> {
    if let Some(b) = bundle {
        anyhow::ensure!(
            a.run_id.as_ref().is_none_or(|r| *r == b.run_id),
            "--run-id {}: the bundle is for run {}",
            a.run_id.as_deref().unwrap_or_default(),
            b.run_id
        );
    }
    let run_id = bundle
        .map(|b| b.run_id.clone())
        .or_else(|| a.run_id.clone())
        .context("--run-id: the run to join is needed (`up --listen` printed it)")?;
    let secret = a
        .secret
        .clone()
        .or_else(|| bundle.map(|b| b.secret.clone()))
        .or_else(|| std::env::var("GESTHOR_SECRET").ok())
        .context("--secret: the run's secret is needed (or $GESTHOR_SECRET); `up --listen` printed it")?;
    Ok((run_id, secret))
}

/// Asks the learner's host for slots, again each second while it is not up yet (or a dead
/// host's slots are not free yet) for up to `--wait`; None when a termination signal came.
fn join(
    a: &WorkersArgs,
    session: &zenoh::Session,
    run_id: &str,
    secret: &str,
    host: &str,
) -> anyhow::Result<Option<JoinGrant>> {
    let asked = Instant::now();
    loop {
        match remote::join(session, run_id, secret, a.workers as u32, host) {
            Ok(g) => return Ok(Some(g)),
            Err(e) if e.to_string().contains("no learner answered") => {
                if let Some(why) = remote::refusals::last_refusal() {
                    anyhow::bail!(
                        "joining run {run_id} at {}: the TLS link was refused ({why}): this host's certificate is not trusted there (revoked, or issued for another run)",
                        a.connect
                    );
                }
                anyhow::ensure!(
                    asked.elapsed().as_secs_f64() < a.wait,
                    "joining run {run_id} at {}: no learner answered for {:.0} s (is `up --listen` running there?)",
                    a.connect,
                    a.wait
                );
            }
            // slots of a host that just died are freed a few seconds after it vanished
            Err(e) if e.to_string().contains("remote slots are free") && asked.elapsed().as_secs_f64() < a.wait => {}
            Err(e) => return Err(e.context(format!("joining run {run_id} at {}", a.connect))),
        }
        if process::termination_signal().is_some() {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_secs(1));
    }
}

/// The learner's config with this host's dataset, checked to be the learner's.
fn host_config(a: &WorkersArgs, grant: &JoinGrant) -> anyhow::Result<RunConfig> {
    let mut cfg = RunConfig::from_toml(&grant.config_toml, "(the learner's config)")?;
    if let Some(d) = &a.dataset {
        cfg.run.dataset = d.clone();
    }
    if !a.synthetic {
        let mine = manifest_digest(&cfg.run.dataset)?;
        anyhow::ensure!(
            mine == grant.manifest_digest,
            "{}: not the learner's dataset (its manifest differs); copy the learner's or pass --dataset",
            cfg.run.dataset.display()
        );
        worker::dataset::Dataset::open(&cfg.run.dataset, worker::dataset::Verify::Full)?;
    }
    Ok(cfg)
}

/// Ticks the crew until it ends: a termination signal, the learner's host going away or the
/// bridge ending stops it. Whether the learner's host went away.
fn supervise(crew: &mut Crew, bridge: &HostBridge) -> anyhow::Result<bool> {
    let mut learner_gone = false;
    let mut last_line = Instant::now();
    while crew.tick()? == CrewState::Running {
        if process::termination_signal().is_some() && !crew.is_stopping() {
            eprintln!("[workers] stopping");
            crew.stop();
        }
        if bridge.learner_gone() && !crew.is_stopping() {
            eprintln!("[workers] the learner's host went away; stopping the workers");
            learner_gone = true;
            crew.stop();
        }
        if bridge.ended() && !crew.is_stopping() {
            crew.stop();
        }
        if last_line.elapsed() > Duration::from_secs(10) {
            last_line = Instant::now();
            traffic(&bridge.counts, crew.restarts());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(learner_gone)
}

fn traffic(counts: &BridgeCounts, restarts: u64) {
    let n = |c: &std::sync::atomic::AtomicU64| c.load(std::sync::atomic::Ordering::Relaxed);
    eprintln!(
        "[workers] {} observations ({:.1} MB) sent, {} actions received, {restarts} restart(s)",
        n(&counts.observations),
        n(&counts.bytes) as f64 / 1e6,
        n(&counts.actions),
    );
}
