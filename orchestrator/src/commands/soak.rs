//! `orchestrator soak`: a training run under a seeded schedule of faults, to show that nothing
//! is lost on kill, Ctrl-C or crash.
//!
//! The run is an `orchestrator up` child of this process. After each fault's delay (drawn from
//! the seed) one fault is injected: SIGKILL to a random worker (the orchestrator restarts it),
//! SIGKILL to the learner (the run ends), SIGKILL to the orchestrator (once; its children follow
//! it), or SIGINT to the orchestrator at a random moment (often during an update or a checkpoint
//! write). A run that ended is resumed with `up --resume`. Checked throughout:
//!
//! - every checkpoint with a final name verifies (header and checksum);
//! - every resume starts from the newest checkpoint that verifies, and updates only grow;
//! - no corrupt or duplicated message reached the learner (the farm's integrity counters);
//! - at the end, no process of the run and no file of any of its sessions in `/dev/shm` remains.
//!
//! `soak.md` and `soak.json` in the output folder say what was injected, survived and lost.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::Rng;
use serde::Serialize;

use crate::supervise::run_dir;

#[derive(Args, Debug)]
pub struct SoakArgs {
    /// Inject faults for this long.
    #[arg(long, default_value_t = 10.0)]
    pub minutes: f64,
    /// Or stop after this many faults (whichever comes first).
    #[arg(long)]
    pub faults: Option<usize>,
    /// Seed of the fault schedule.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value_t = 2, value_parser = super::values::workers)]
    pub workers: usize,
    /// Run configuration (default: a small PPO network on 32×32 frames of the dataset in
    /// data/gond, a checkpoint every 2 updates).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder (the run is `OUT/run`); default runs/soak-<UTC time>.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// The faults, in the order of [`Fault::ALL`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fault {
    KillWorker,
    KillLearner,
    KillOrchestrator,
    Interrupt,
}

impl Fault {
    pub const ALL: [Fault; 4] = [Fault::KillWorker, Fault::KillLearner, Fault::KillOrchestrator, Fault::Interrupt];

    fn index(self) -> usize {
        Fault::ALL.iter().position(|&f| f == self).expect("listed")
    }
}

/// What the soak saw.
#[derive(Debug, Default, Serialize)]
pub struct SoakReport {
    pub seed: u64,
    pub seconds: f64,
    /// Per fault kind (KillWorker, KillLearner, KillOrchestrator, Interrupt): injected, survived.
    pub injected: [usize; 4],
    pub survived: [usize; 4],
    pub resumes: usize,
    /// Resumes that did not start from the newest checkpoint that verified.
    pub bad_resumes: usize,
    /// Checkpoint files with a final name that do not verify.
    pub unusable_checkpoints: usize,
    /// Corrupt or duplicated messages the learner counted.
    pub integrity_errors: u64,
    /// Updates trained and lost to hard kills (their frames had to be collected again).
    pub updates_lost: u64,
    pub frames_lost: u64,
    pub final_update: u64,
    /// Processes or shared-memory files of the run left at the end.
    pub leftovers: Vec<String>,
}

impl SoakReport {
    pub fn passed(&self) -> bool {
        self.survived == self.injected
            && self.bad_resumes == 0
            && self.unusable_checkpoints == 0
            && self.integrity_errors == 0
            && self.leftovers.is_empty()
    }

    fn markdown(&self, command: &str) -> String {
        let mut md = format!(
            "# Soak\n\n`{command}`\n\n{:.1} minutes, seed {}: {}\n\n| fault | injected | survived |\n|---|---:|---:|\n",
            self.seconds / 60.0,
            self.seed,
            if self.passed() { "passed" } else { "FAILED" }
        );
        for f in Fault::ALL {
            md += &format!("| {f:?} | {} | {} |\n", self.injected[f.index()], self.survived[f.index()]);
        }
        md += &format!(
            "\n| check | value |\n|---|---:|\n| resumes | {} |\n| resumes not from the newest whole checkpoint | {} |\n\
             | unusable checkpoints | {} |\n| integrity errors (corrupt + duplicated messages) | {} |\n\
             | updates lost to hard kills | {} ({} frames) |\n| final update | {} |\n| leftover processes and files | {} |\n",
            self.resumes,
            self.bad_resumes,
            self.unusable_checkpoints,
            self.integrity_errors,
            self.updates_lost,
            self.frames_lost,
            self.final_update,
            self.leftovers.len()
        );
        md
    }
}

const SMALL_CONFIG: &str = "[run]\nmethod = \"both\"\nseed = 7\ntotal_frames = 100_000_000\n\n\
    [env]\nenvs_per_worker = 2\nwidth = 32\nheight = 32\n\n\
    [model]\nencoder = \"small_cnn\"\nhidden = 32\ngru_layers = 1\n\n\
    [ppo]\nrollout = 16\nepochs = 4\n\n[checkpoint]\nevery_updates = 2\nkeep = 3\n";

/// Longest wait for a run to make progress or to end before the soak gives up on it.
const PATIENCE: Duration = Duration::from_secs(300);

struct Soak {
    args: SoakArgs,
    run: PathBuf,
    config: PathBuf,
    log: PathBuf,
    report: SoakReport,
    run_ids: Vec<String>,
    /// Update of the checkpoint the last resume started from.
    resumed_update: u64,
}

pub fn run(args: SoakArgs) -> anyhow::Result<i32> {
    farm::process::install_termination_handler()?;
    let out = args.out.clone().unwrap_or_else(|| run_dir::default_path("soak"));
    anyhow::ensure!(!out.join("run").exists(), "{}: a soak was already run here; choose another --out", out.display());
    std::fs::create_dir_all(&out)?;
    let config = match &args.config {
        Some(c) => c.clone(),
        None => {
            let p = out.join("soak.toml");
            std::fs::write(&p, SMALL_CONFIG)?;
            p
        }
    };
    let mut s = Soak {
        run: out.join("run"),
        log: out.join("sessions.log"),
        config,
        report: SoakReport { seed: args.seed, ..Default::default() },
        run_ids: Vec::new(),
        resumed_update: 0,
        args,
    };
    let t0 = Instant::now();
    let result = s.go(t0);
    s.report.seconds = t0.elapsed().as_secs_f64();
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    farm::files::write_atomic(&out.join("soak.json"), serde_json::to_string_pretty(&s.report)?.as_bytes())?;
    farm::files::write_atomic(&out.join("soak.md"), s.report.markdown(&command).as_bytes())?;
    result?;
    eprintln!("{}", s.report.markdown(&command));
    Ok(if s.report.passed() { 0 } else { 1 })
}

impl Soak {
    fn go(&mut self, t0: Instant) -> anyhow::Result<()> {
        let deadline = Duration::from_secs_f64(self.args.minutes * 60.0);
        let max_faults = self.args.faults.unwrap_or(usize::MAX);
        let mut child = self.start(false)?;
        let mut faults = 0;
        let mut plan = schedule(self.args.seed);
        while faults < max_faults && t0.elapsed() < deadline && farm::process::termination_signal().is_none() {
            self.wait_for_update(&mut child)?;
            let Planned { delay, fault, pick } = plan.next().expect("endless");
            std::thread::sleep(Duration::from_secs_f64(delay));
            faults += 1;
            self.report.injected[fault.index()] += 1;
            eprintln!("[soak] fault {faults}: {fault:?} after {delay:.1} s");
            let survived = match fault {
                Fault::KillWorker => self.kill_worker(&mut child, pick)?,
                _ => {
                    let before = last_update(&self.run);
                    match fault {
                        Fault::KillLearner => self.kill_role("learner")?,
                        Fault::KillOrchestrator => signal(child.id() as i32, Signal::SIGKILL)?,
                        _ => signal(child.id() as i32, Signal::SIGINT)?,
                    }
                    self.wait_ended(&mut child)?;
                    if matches!(fault, Fault::KillLearner | Fault::KillOrchestrator) {
                        // what a hard kill cost: updates trained since the newest checkpoint
                        let kept = newest_verified_update(&self.run);
                        let lost = before.saturating_sub(kept);
                        self.report.updates_lost += lost;
                        self.report.frames_lost += lost * self.frames_per_update()?;
                    }
                    self.check_checkpoints();
                    child = self.start(true)?;
                    self.check_resume(&mut child)?
                }
            };
            if survived {
                self.report.survived[fault.index()] += 1;
            }
        }
        signal(child.id() as i32, Signal::SIGINT)?;
        self.wait_ended(&mut child)?;
        self.check_checkpoints();
        self.report.final_update = last_update(&self.run);
        self.report.integrity_errors = integrity_errors(&self.run);
        self.report.leftovers = self.leftovers();
        Ok(())
    }

    /// `orchestrator up` on the run (resuming it after the first session).
    fn start(&mut self, resume: bool) -> anyhow::Result<Child> {
        let exe = std::env::current_exe().context("finding this orchestrator binary")?;
        let mut c = Command::new(exe);
        c.arg("up");
        if resume {
            c.arg("--resume").arg(&self.run);
            self.report.resumes += 1;
        } else {
            c.arg("--run-dir").arg(&self.run).arg("--config").arg(&self.config);
        }
        c.args(["--workers", &self.args.workers.to_string(), "--seconds", "1000000", "--report-every", "0.5"]);
        let log = std::fs::OpenOptions::new().create(true).append(true).open(&self.log)?;
        let child = c.stdin(Stdio::null()).stdout(log.try_clone()?).stderr(log).spawn()?;
        // the run id of this session (run.json is rewritten by every session)
        let info = run_dir::wait_for_info(&self.run, child.id(), PATIENCE)
            .with_context(|| format!("see {}", self.log.display()))?;
        self.run_ids.push(info.run_id);
        Ok(child)
    }

    /// Waits until the learner finishes an update it had not finished before.
    fn wait_for_update(&self, child: &mut Child) -> anyhow::Result<()> {
        let start = last_update(&self.run);
        let t = Instant::now();
        while last_update(&self.run) <= start {
            if let Some(status) = child.try_wait()? {
                anyhow::bail!("the run ended by itself ({status}); see {}", self.log.display());
            }
            anyhow::ensure!(t.elapsed() < PATIENCE, "no PPO update in {PATIENCE:?} (see {})", self.log.display());
            std::thread::sleep(Duration::from_millis(100));
        }
        Ok(())
    }

    fn wait_ended(&self, child: &mut Child) -> anyhow::Result<()> {
        let t = Instant::now();
        while child.try_wait()?.is_none() || !self.processes().is_empty() {
            anyhow::ensure!(t.elapsed() < PATIENCE, "the run did not end (see {})", self.log.display());
            std::thread::sleep(Duration::from_millis(100));
        }
        Ok(())
    }

    /// SIGKILL to a random worker; survived when its replacement sends and learning goes on.
    fn kill_worker(&mut self, child: &mut Child, pick: f64) -> anyhow::Result<bool> {
        let workers: Vec<i32> =
            self.processes().into_iter().filter(|(_, cmd)| is_binary(cmd, "worker")).map(|(p, _)| p).collect();
        if workers.is_empty() {
            return Ok(false);
        }
        let victim = workers[((pick * workers.len() as f64) as usize).min(workers.len() - 1)];
        signal(victim, Signal::SIGKILL)?;
        let restarts = |run: &Path| last_progress(run).map_or(0, |p| p["restarts"].as_u64().unwrap_or(0));
        let before = restarts(&self.run);
        let t = Instant::now();
        while restarts(&self.run) <= before {
            if child.try_wait()?.is_some() || t.elapsed() > PATIENCE {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        self.wait_for_update(child)?;
        Ok(true)
    }

    fn kill_role(&self, binary: &str) -> anyhow::Result<()> {
        for (pid, _) in self.processes().into_iter().filter(|(_, cmd)| is_binary(cmd, binary)) {
            signal(pid, Signal::SIGKILL)?;
        }
        Ok(())
    }

    /// After a resume: the learner says it resumed from the newest checkpoint that verifies,
    /// whose update is not below the last resume's, and goes on learning.
    fn check_resume(&mut self, child: &mut Child) -> anyhow::Result<bool> {
        let (expected, _) = farm::checkpoints::latest_verified(&farm::checkpoints::dir_of(&self.run));
        self.wait_for_update(child)?;
        let log = std::fs::read_to_string(self.run.join("logs/learner.log")).unwrap_or_default();
        let session = log.rsplit("=== learner, run").next().unwrap_or_default();
        let good = match &expected {
            Some(p) => {
                let update = farm::checkpoints::update_of(p).unwrap_or(0);
                // the learner names the file by its absolute path
                let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                let said = session.lines().any(|l| l.contains("resumed from ") && l.contains(&format!("/{name} ")));
                let ok = said && update >= self.resumed_update;
                self.resumed_update = update;
                ok
            }
            // nothing to resume from yet: the learner must say so and start afresh
            None => !session.contains("resumed from"),
        };
        if !good {
            self.report.bad_resumes += 1;
            eprintln!("[soak] resume did not start from {expected:?}");
        }
        Ok(good)
    }

    fn check_checkpoints(&mut self) {
        for (_, p) in farm::checkpoints::list(&farm::checkpoints::dir_of(&self.run)) {
            if let Err(why) = farm::checkpoints::verify(&p) {
                eprintln!("[soak] unusable checkpoint {}: {why}", p.display());
                self.report.unusable_checkpoints += 1;
            }
        }
    }

    fn frames_per_update(&self) -> anyhow::Result<u64> {
        let cfg = farm::config::RunConfig::load(&self.run.join("config.toml"))?;
        Ok(cfg.ppo.rollout as u64 * cfg.env.envs_per_worker as u64 * self.args.workers as u64)
    }

    /// The run's processes (the orchestrator child and everything it started).
    fn processes(&self) -> Vec<(i32, String)> {
        let dir = self.run.canonicalize().unwrap_or(self.run.clone());
        processes_mentioning(&dir.join("config.toml").display().to_string())
    }

    fn leftovers(&self) -> Vec<String> {
        let mut out: Vec<String> = self.processes().into_iter().map(|(p, cmd)| format!("process {p}: {cmd}")).collect();
        for id in &self.run_ids {
            out.extend(farm::transport::run_files(id).into_iter().map(|p| p.display().to_string()));
        }
        out
    }
}

/// One fault of the schedule: after `delay` seconds of training, `fault`; `pick` in [0, 1)
/// chooses the worker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Planned {
    pub delay: f64,
    pub fault: Fault,
    pub pick: f64,
}

/// The endless fault schedule of `seed`: workers killed 40% of the time, the learner 20%, the
/// orchestrator once (8% until then), Ctrl-C otherwise.
pub fn schedule(seed: u64) -> impl Iterator<Item = Planned> {
    let mut rng = farm::seed::rng(seed, &[0x50A4_0001]);
    let mut orchestrator_killed = false;
    std::iter::from_fn(move || {
        let delay = rng.random_range(0.5..8.0f64);
        let fault = match rng.random_range(0..100u32) {
            0..40 => Fault::KillWorker,
            40..60 => Fault::KillLearner,
            60..68 if !orchestrator_killed => Fault::KillOrchestrator,
            _ => Fault::Interrupt,
        };
        orchestrator_killed |= fault == Fault::KillOrchestrator;
        Some(Planned { delay, fault, pick: rng.random_range(0.0..1.0) })
    })
}

/// `sig` to `pid`; a process that is already gone is not an error.
fn signal(pid: i32, sig: Signal) -> nix::Result<()> {
    match kill(Pid::from_raw(pid), sig) {
        Err(nix::errno::Errno::ESRCH) => Ok(()),
        r => r,
    }
}

/// Whether a command line runs the program named `binary` (its path's last part).
fn is_binary(cmd: &str, binary: &str) -> bool {
    cmd.split(' ').next().is_some_and(|b| Path::new(b).file_name().is_some_and(|n| n == binary))
}

/// The last update in the run's metrics.jsonl (0 before the first).
fn last_update(run: &Path) -> u64 {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .ok()
        .and_then(|t| t.lines().filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()).last())
        .and_then(|v| v["update"].as_u64())
        .unwrap_or(0)
}

fn newest_verified_update(run: &Path) -> u64 {
    farm::checkpoints::latest_verified(&farm::checkpoints::dir_of(run))
        .0
        .and_then(|p| farm::checkpoints::update_of(&p))
        .unwrap_or(0)
}

/// The learner's latest progress record.
fn last_progress(run: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(run.join("farm.jsonl")).ok()?;
    text.lines().rev().find_map(|l| serde_json::from_str(l).ok())
}

/// Corrupt and duplicated messages over every session: each progress record holds its
/// session's running totals, so the largest per session counts.
fn integrity_errors(run: &Path) -> u64 {
    let text = std::fs::read_to_string(run.join("farm.jsonl")).unwrap_or_default();
    let mut total = 0;
    let mut session_max = 0;
    let mut last_t = f64::MAX;
    for v in text.lines().filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()) {
        let t = v["t"].as_f64().unwrap_or(0.0);
        if t < last_t {
            total += session_max;
            session_max = 0;
        }
        last_t = t;
        session_max = session_max.max(v["corrupt"].as_u64().unwrap_or(0) + v["duplicates"].as_u64().unwrap_or(0));
    }
    total + session_max
}

/// `(pid, command line)` of every process whose command line contains `needle` (not this one).
pub fn processes_mentioning(needle: &str) -> Vec<(i32, String)> {
    let me = std::process::id() as i32;
    let mut out = vec![];
    for e in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else { continue };
        if pid == me {
            continue;
        }
        let Ok(raw) = std::fs::read(e.path().join("cmdline")) else { continue };
        let cmd = String::from_utf8_lossy(&raw).replace('\0', " ");
        // zombies have an empty command line: already gone for our purposes
        if !cmd.is_empty() && cmd.contains(needle) {
            out.push((pid, cmd));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The schedule is the seed's alone, kills the orchestrator at most once, and the CI soak's
    /// seed (3) has every kind of fault in its first eight.
    #[test]
    fn the_schedule_is_seeded_and_kills_the_orchestrator_once() {
        let a: Vec<Planned> = schedule(3).take(200).collect();
        assert_eq!(a, schedule(3).take(200).collect::<Vec<_>>());
        assert_ne!(a, schedule(4).take(200).collect::<Vec<_>>());
        assert_eq!(a.iter().filter(|p| p.fault == Fault::KillOrchestrator).count(), 1);
        let first: Vec<Fault> = a.iter().take(8).map(|p| p.fault).collect();
        assert!(Fault::ALL.iter().all(|f| first.contains(f)), "{first:?}");
    }
}
