//! `orchestrator up`: start a run (learner + N workers), supervise it, show progress, stop it
//! cleanly on Ctrl-C or SIGTERM.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::Args;
use farm::config::RunConfig;
use farm::process;

use farm::progress::Progress;
use farm::serve_args::Policy;

use crate::report::progress::{Bar, Rate};
use crate::supervise::crew::{Crew, CrewOutcome, CrewSpec, CrewState};
use crate::supervise::launch::{prepare_run, resolve_dataset, resolve_encoder, sweep_dead_runs};
use crate::supervise::run_dir::{self, RunDir};

/// The configuration `up` trains when no `--config` is given: the tiny CPU setup of +Both.
pub const DEFAULT_CONFIG: &str = include_str!("../../../configs/tiny/both.toml");

#[derive(Args, Debug)]
pub struct UpArgs {
    /// Worker processes (each steps the config's `env.envs_per_worker` environments).
    #[arg(long, default_value_t = 4, value_parser = super::values::workers)]
    pub workers: usize,
    /// Run configuration (TOML); the embedded CPU default of +Both when omitted.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run directory (default: runs/up-<UTC time>).
    #[arg(long, conflicts_with = "resume")]
    pub run_dir: Option<PathBuf>,
    /// Continue the run in this directory (its config and latest checkpoint).
    #[arg(long, value_name = "RUN_DIR")]
    pub resume: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = Policy::Ppo)]
    pub policy: Policy,
    /// Stop after this many frames (default: the config's run.total_frames).
    #[arg(long, conflicts_with = "seconds")]
    pub frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_parser = super::values::seconds)]
    pub seconds: Option<f64>,
    /// Fail on any lost, duplicated or malformed message between workers and learner.
    #[arg(long)]
    pub check: bool,
    /// Step synthetic environments instead of the simulator (tests the farm's plumbing only).
    #[arg(long)]
    pub synthetic: bool,
    /// Override a config value, e.g. `--set ppo.lr=1e-4` (repeatable; checked as the file is;
    /// the effective config is the one written into the run directory).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Seconds between the learner's progress records.
    #[arg(long, default_value_t = farm::serve_args::REPORT_EVERY_S, value_parser = super::values::seconds)]
    pub report_every: f64,
    /// Accept worker hosts on this Zenoh endpoint, TLS with certificates on both sides (e.g.
    /// tls/0.0.0.0:7447); each host joins with a bundle from `orchestrator hosts issue` and
    /// `orchestrator workers --connect`.
    #[arg(long, requires = "remote_workers")]
    pub listen: Option<String>,
    /// Allow --listen tcp/...: plain TCP, readable and writable by anyone who reaches the port
    /// (loopback experiments).
    #[arg(long, requires = "listen")]
    pub insecure: bool,
    /// Learner slots kept for worker hosts (after the local --workers).
    #[arg(long, default_value_t = 0, requires = "listen")]
    pub remote_workers: usize,
    /// The secret a worker host must know (default: a new random one, printed, and kept in
    /// RUN/secret for a resume).
    #[arg(long, requires = "listen")]
    pub secret: Option<String>,
}

/// Loads the run configuration: `--config`, the run directory's copy when resuming, or the
/// embedded default.
pub fn load_config(path: Option<&Path>) -> anyhow::Result<RunConfig> {
    Ok(match path {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::from_toml(DEFAULT_CONFIG, "(embedded default config)")?,
    })
}

pub fn run(a: UpArgs) -> anyhow::Result<i32> {
    if let Some(endpoint) = &a.listen {
        crate::remote::check_endpoint(endpoint, a.insecure, "--listen")?;
    }
    process::install_termination_handler()?;
    let (run_path, cfg) = config(&a)?;
    let (dir, config_path) = prepare_run(&run_path, &cfg, a.resume.is_some(), a.workers, a.policy)?;
    sweep_dead_runs();
    let Some((spec, bar_from)) = crew_spec(&a, &dir, &config_path, &cfg)? else { return Ok(0) };
    announce(&a, &dir, &cfg);
    let spec_frames = spec.max_frames.map(|f| f + bar_from);
    let mut crew = Crew::start(spec)?;
    let bridge = match &a.listen {
        Some(endpoint) => Some(listen(&a, endpoint, &dir.path, &dir.run_id, &cfg)?),
        None => None,
    };
    let ui = Progressline::new(spec_frames, a.seconds, bar_from);
    supervise(&mut crew, bridge.as_ref(), &ui, &dir.path)?;
    ui.clear();
    if let Some(b) = bridge {
        finish_bridge(b);
    }
    let stopped_by_signal = process::termination_signal();
    let out = crew.finish()?;
    summarize(&out, &dir);
    Ok(match (stopped_by_signal, out.learner) {
        (Some(sig), _) => process::signal_exit_code(sig),
        (None, Some(e)) if e.success() => 0,
        (None, Some(e)) => {
            eprintln!("[up] the learner {e}; see {}", dir.logs().join("learner.log").display());
            1
        }
        (None, None) => 1,
    })
}

/// The run's folder and its config: the run's own when resuming (`--set` refused), else
/// `--config` or the default with `--set`, its dataset and encoder resolved.
fn config(a: &UpArgs) -> anyhow::Result<(PathBuf, RunConfig)> {
    let resume = a.resume.is_some();
    let (run_path, mut cfg) = match &a.resume {
        Some(dir) => {
            let p = dir.join("config.toml");
            anyhow::ensure!(p.is_file(), "--resume {}: no config.toml there (not a run directory)", dir.display());
            if a.config.is_some() {
                eprintln!("[up] --resume: using {} (the run's own config), not --config", p.display());
            }
            (dir.clone(), RunConfig::load(&p)?)
        }
        None => (a.run_dir.clone().unwrap_or_else(|| run_dir::default_path("up")), load_config(a.config.as_deref())?),
    };
    anyhow::ensure!(
        !(resume && !a.set.is_empty()),
        "--set with --resume: a resumed run keeps its own config (start a new run to change it)"
    );
    cfg = cfg.with_overrides(&a.set)?;
    if !resume && let Some(c) = farm::checkpoints::latest_in_run(&run_path) {
        anyhow::bail!(
            "{} already holds a training run ({}): continue it with `orchestrator up --resume {}`, or choose another --run-dir",
            run_path.display(),
            c.display(),
            run_path.display()
        );
    }
    resolve_dataset(&mut cfg, a.synthetic)?;
    if !resume && a.policy == Policy::Ppo {
        resolve_encoder(&mut cfg)?;
    }
    Ok((run_path, cfg))
}

/// The crew to start, and the frames trained before it (where a resumed run's bar starts);
/// None when the run has trained its budget already.
fn crew_spec(a: &UpArgs, dir: &RunDir, config_path: &Path, cfg: &RunConfig) -> anyhow::Result<Option<(CrewSpec, u64)>> {
    let resume = a.resume.is_some();
    let mut spec = CrewSpec::new(&dir.path, &dir.run_id, config_path, cfg.clone(), a.workers, a.policy);
    spec.max_seconds = a.seconds;
    // A resumed run trains to its own budget: what its newest checkpoint was trained on counts
    // (--frames stays this process's frames: `study` passes what is left itself).
    let trained = if resume && a.policy == Policy::Ppo { frames_trained(&dir.path)? } else { 0 };
    spec.max_frames = match (a.frames, a.seconds) {
        (Some(f), _) => Some(f),
        (None, Some(_)) => None,
        (None, None) => Some(cfg.run.total_frames.saturating_sub(trained)),
    };
    if spec.max_frames == Some(0) {
        eprintln!(
            "[up] {} has trained its budget already ({trained} of run.total_frames = {} frames): nothing to do",
            dir.path.display(),
            cfg.run.total_frames
        );
        return Ok(None);
    }
    spec.check = a.check;
    spec.synthetic = a.synthetic;
    spec.resume = resume;
    spec.report_every = a.report_every;
    spec.remote_slots = a.remote_workers;
    // a resumed run's bar counts the run's frames: those trained before, then these (a study's
    // log after a restart reads 2061472/5000000 frames, not 61472/2998304)
    let bar_from = if a.seconds.is_none() { trained } else { 0 };
    Ok(Some((spec, bar_from)))
}

fn announce(a: &UpArgs, dir: &RunDir, cfg: &RunConfig) {
    eprintln!(
        "[up] run {} in {}: {} workers × {} envs ({}x{}){}, policy {}{}",
        dir.run_id,
        dir.path.display(),
        a.workers,
        cfg.env.envs_per_worker,
        cfg.env.width,
        cfg.env.height,
        if cfg.ppo.env_groups > 1 { format!(", rounds in {} groups", cfg.ppo.env_groups) } else { String::new() },
        a.policy.name(),
        if a.synthetic { ", synthetic envs" } else { "" }
    );
}

/// Ticks the crew until it ends, showing its progress: the first termination signal stops it
/// cleanly, the second says what a third would lose, the third kills it; a failed bridge to
/// worker hosts stops it too.
fn supervise(
    crew: &mut Crew,
    bridge: Option<&crate::remote::LearnerBridge>,
    ui: &Progressline,
    run: &Path,
) -> anyhow::Result<()> {
    let mut signals_seen = 0;
    while crew.tick()? == CrewState::Running {
        let n = process::termination_count();
        if n > signals_seen {
            signals_seen = n;
            match n {
                1 => {
                    ui.println(&format!(
                        "[up] {}: stopping; the learner ends its update and writes a final checkpoint",
                        process::termination_signal().map(|s| s.to_string()).unwrap_or_default()
                    ));
                    crew.stop();
                }
                2 => ui.println(&format!("[up] {}", what_killing_loses(crew, run))),
                _ => crew.kill_now(),
            }
        }
        if bridge.is_some_and(|b| b.ended()) && !crew.is_stopping() {
            ui.println("[up] the bridge to worker hosts failed; stopping");
            crew.stop();
        }
        ui.update(crew);
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}

fn finish_bridge(b: crate::remote::LearnerBridge) {
    let refused = b.counts.refused.load(std::sync::atomic::Ordering::Relaxed);
    if let Err(e) = b.finish() {
        eprintln!("[up] the bridge to worker hosts: {e:#}");
    }
    if refused > 0 {
        eprintln!("[up] {refused} message(s) from worker hosts without a grant were dropped");
    }
}

/// The run's last line: frames, rate, episodes, success and restarts.
fn summarize(out: &CrewOutcome, dir: &RunDir) {
    if !out.leftovers.is_empty() {
        eprintln!("[up] removed {} shared-memory file(s) the run left behind", out.leftovers.len());
    }
    if let Some(p) = &out.progress {
        eprintln!(
            "[up] {}: {} frames in {:.1} s ({:.1}/s), {} episodes, success {}, {} worker restart(s)",
            p.stop_reason.as_deref().unwrap_or("ended"),
            p.totals.frames,
            out.seconds,
            p.totals.frames as f64 / out.seconds.max(1e-9),
            p.totals.episodes,
            p.success_rate.map(|s| format!("{:.1}%", 100.0 * s)).unwrap_or_else(|| "-".into()),
            out.restarts
        );
    }
    eprintln!("[up] results in {}", dir.path.display());
}

/// Frames the newest usable checkpoint of a run was trained on (0 without one: the learner then
/// refuses the resume itself, with the reason).
fn frames_trained(run: &Path) -> anyhow::Result<u64> {
    match farm::checkpoints::latest_verified(&farm::checkpoints::dir_of(run)).0 {
        Some(p) => farm::checkpoints::frames(&p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display())),
        None => Ok(0),
    }
}

/// The run's progress: frames of the frame budget (or seconds of the time budget), with what
/// the learner last reported beside them.
struct Progressline {
    bar: Bar,
    by_frames: bool,
    /// Frames trained before this process (a resume to the run's budget).
    from: u64,
    /// Frames/s over the last half minute (the learner's own figure swings with its updates).
    rate: std::cell::RefCell<Rate>,
    started: Instant,
    /// When farm.jsonl was last read (twice a second is enough).
    polled: std::cell::Cell<Instant>,
}

impl Progressline {
    fn new(max_frames: Option<u64>, max_seconds: Option<f64>, from: u64) -> Progressline {
        let every = Duration::from_secs(5);
        let (bar, by_frames) = match (max_frames, max_seconds) {
            (Some(f), _) => (Bar::new("up", f, "frames", every).starting_at(from), true),
            (None, s) => (Bar::new("up", s.unwrap_or(0.0).ceil() as u64, "s", every), false),
        };
        let now = Instant::now();
        // counted from the start: the first report already holds a rollout's frames, and the
        // first update's pause must not read as 0 frames/s
        let mut rate = Rate::new(Duration::from_secs(30));
        rate.add(now, 0);
        let rate = std::cell::RefCell::new(rate);
        Progressline { bar, by_frames, from, rate, started: now, polled: std::cell::Cell::new(now) }
    }

    fn text(crew: &Crew, p: &Progress, fps: f64) -> String {
        format!(
            "{:.0} frames/s  episodes {}  success {}  workers {}/{}  restarts {}{}",
            fps,
            p.totals.episodes,
            p.success_rate.map(|s| format!("{:.1}%", 100.0 * s)).unwrap_or_else(|| "-".into()),
            p.workers_live,
            crew.spec().workers + crew.spec().remote_slots,
            crew.restarts(),
            p.latency_ms.map(|l| format!("  step {l:.1} ms")).unwrap_or_default()
        )
    }

    fn update(&self, crew: &Crew) {
        if self.polled.get().elapsed() < Duration::from_millis(500) {
            return;
        }
        self.polled.set(Instant::now());
        let Some(p) = crew.progress() else { return };
        let pos = if self.by_frames { self.from + p.totals.frames } else { self.started.elapsed().as_secs() };
        let fps = self.rate.borrow_mut().add(Instant::now(), p.totals.frames).unwrap_or(p.fps);
        self.bar.set(pos, &Self::text(crew, &p, fps));
    }

    fn println(&self, line: &str) {
        self.bar.println(line);
    }

    fn clear(&self) {
        self.bar.finish();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_default_config_is_valid() {
        let c = load_config(None).unwrap();
        assert_eq!(c.run.method, farm::config::Method::Both);
    }

    #[test]
    fn a_missing_encoder_names_the_path_and_the_command() {
        let mut c = load_config(None).unwrap();
        c.model.encoder_weights = Some(PathBuf::from("no/such/rgbd64.safetensors"));
        let e = resolve_encoder(&mut c).unwrap_err().to_string();
        assert!(e.contains("no/such/rgbd64.safetensors") && e.contains("orchestrator encoder pretrain"), "{e}");
        assert!(c.model.encoder_weights.unwrap().is_absolute(), "children may run elsewhere");
        let mut c = load_config(None).unwrap();
        c.model.encoder = farm::config::Encoder::SmallCnn;
        assert!(resolve_encoder(&mut c).is_ok(), "only the pretrained encoder needs the file");
    }

    #[test]
    fn a_missing_dataset_names_the_path_and_the_command() {
        let mut c = load_config(None).unwrap();
        c.run.dataset = PathBuf::from("/nonexistent/gond");
        let e = resolve_dataset(&mut c, false).err().expect("no dataset there").to_string();
        assert!(e.contains("/nonexistent/gond") && e.contains("orchestrator dataset build"), "{e}");
        assert!(resolve_dataset(&mut c, true).is_ok());
    }

    #[test]
    fn a_bad_config_names_the_field() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("bad.toml");
        std::fs::write(&p, "[run]\nmethod = \"both\"\n[env]\nwidht = 3\n").unwrap();
        let e = load_config(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("bad.toml") && e.contains("widht"), "{e}");
    }
}

/// Starts the bridge that lets worker hosts join (`--listen`), and says how to join.
fn listen(
    a: &UpArgs,
    endpoint: &str,
    run: &Path,
    run_id: &str,
    cfg: &RunConfig,
) -> anyhow::Result<crate::remote::LearnerBridge> {
    let secret_file = run.join("secret");
    let secret = match (&a.secret, std::fs::read_to_string(&secret_file)) {
        (Some(s), _) => s.clone(),
        (None, Ok(s)) => s.trim().to_string(),
        (None, Err(_)) => crate::remote::random_hex(16),
    };
    farm::files::write_atomic(&secret_file, secret.as_bytes())?;
    let digest = if a.synthetic { String::new() } else { super::workers::manifest_digest(&cfg.run.dataset)? };
    let (e, w, h) = (cfg.env.envs_per_worker as u32, cfg.env.width, cfg.env.height);
    let tls = endpoint.starts_with("tls/");
    if tls {
        crate::remote::refusals::print_refusals();
        crate::remote::certs::learner_files(run, run_id)?;
        farm::files::write_atomic(&run.join("tls/endpoint"), endpoint.as_bytes())?;
    }
    let bridge = crate::remote::LearnerBridge::start(crate::remote::ListenOptions {
        endpoint: endpoint.into(),
        tls_run: tls.then(|| run.to_path_buf()),
        run_id: run_id.into(),
        secret: secret.clone(),
        first_slot: a.workers as u32,
        slots: a.remote_workers as u32,
        config_toml: cfg.to_toml(),
        manifest_digest: digest,
        layout: shm_schema::ObsLayout::new(e, w, h),
        width: w,
        height: h,
    })?;
    if tls {
        let (issued, _) = crate::remote::certs::hosts(run)?;
        eprintln!(
            "[up] {} learner slot(s) wait for worker hosts on {endpoint} (TLS; hosts with a bundle: {}); for each host:\n[up]   orchestrator hosts issue --run {} NAME    (then copy the bundle as it says)",
            a.remote_workers,
            if issued.is_empty() { "none yet".into() } else { issued.join(", ") },
            run.display()
        );
    } else {
        eprintln!(
            "[up] {} learner slot(s) wait for worker hosts on {endpoint}; on each host:\n[up]   orchestrator workers --connect {endpoint} --insecure --run-id {run_id} --secret {secret} --workers N",
            a.remote_workers
        );
    }
    Ok(bridge)
}

/// What a third Ctrl-C would cost, said before it is needed.
fn what_killing_loses(crew: &Crew, run: &Path) -> String {
    let since = match farm::checkpoints::latest_in_run(run) {
        Some(c) => format!("since {}", c.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()),
        None => "of this run (no checkpoint yet)".into(),
    };
    if crew.writing_final_checkpoint() {
        format!("the final checkpoint is being written; Ctrl-C once more kills it and loses the training {since}")
    } else if crew.learner_alive() {
        format!("the learner is ending its update; Ctrl-C once more kills it and loses the training {since}")
    } else {
        "Ctrl-C once more kills what is left at once".into()
    }
}
