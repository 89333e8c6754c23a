//! A running farm: one learner and N workers of one run, supervised.
//!
//! [`Crew::start`] spawns the learner, then the workers (they wait for the learner's ports).
//! [`Crew::tick`] reaps children that ended and acts: a worker that crashed is restarted at once
//! as generation + 1 (after the iceoryx2 resources it left are removed); a worker that exits 0
//! was told to shut down and stays down; when the learner ends, the run ends. [`Crew::stop`]
//! stops everything in order: SIGINT to the learner (it cuts its update short at the next
//! minibatch, writes the final checkpoint and tells the workers to shut down) and SIGTERM to the
//! workers, SIGTERM again after the grace period, SIGKILL just before the 5 s mark; the learner
//! is waited for (up to 10 minutes). [`Crew::finish`] then ends the run's iceoryx2 domain, so
//! nothing of the run remains in `/dev/shm`.
//!
//! Used by `orchestrator up`, `orchestrator bench farm` and evaluation.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use farm::config::RunConfig;
use farm::progress::Progress;
use farm::serve_args::{LearnerOptions, Policy, ServeArgs};
use farm::transport;
use nix::sys::signal::Signal;
use nix::unistd::Pid;

use super::binaries;
use super::child::{self, Child, Ended};

/// Everything a farm needs to start.
#[derive(Clone, Debug)]
pub struct CrewSpec {
    pub run_dir: PathBuf,
    pub run_id: String,
    /// The config file the children read (the run directory's copy).
    pub config_path: PathBuf,
    pub cfg: RunConfig,
    pub workers: usize,
    pub policy: Policy,
    pub max_frames: Option<u64>,
    pub max_seconds: Option<f64>,
    /// Evaluation: the programs of each worker, in order; the learner stops when all are done.
    pub programs: Option<Vec<Vec<u64>>>,
    /// Fail on any lost, duplicated or malformed message.
    pub check: bool,
    /// Synthetic environments (farm plumbing only, no simulator).
    pub synthetic: bool,
    pub resume: bool,
    /// What the learner is told beyond the above (e.g. a checkpoint to evaluate).
    pub learner: LearnerOptions,
    /// Seconds between the learner's progress records.
    pub report_every: f64,
    /// Seconds from SIGINT to SIGTERM when stopping (SIGKILL follows at 4.5 s).
    pub grace: f64,
    /// Folder of the `worker` and `learner` programs (default: next to this executable, or
    /// `$GESTHOR_BIN_DIR`).
    pub bin_dir: Option<PathBuf>,
    /// Learner slots served by worker hosts on other machines (`up --listen`): the learner
    /// expects `workers + remote_slots` workers, this crew spawns the first `workers`.
    pub remote_slots: usize,
    /// A worker host's crew (`orchestrator workers`): no learner here.
    pub host: Option<HostSlots>,
}

/// Which of the learner's slots a worker host's workers are: `first_slot..`, their generations
/// counting from `first_generation` (above any earlier process in those slots).
#[derive(Clone, Copy, Debug)]
pub struct HostSlots {
    pub first_slot: u32,
    pub first_generation: u32,
}

impl CrewSpec {
    pub fn new(
        run_dir: &Path,
        run_id: &str,
        config_path: &Path,
        cfg: RunConfig,
        workers: usize,
        policy: Policy,
    ) -> CrewSpec {
        CrewSpec {
            run_dir: run_dir.into(),
            run_id: run_id.into(),
            config_path: config_path.into(),
            cfg,
            workers,
            policy,
            max_frames: None,
            max_seconds: None,
            programs: None,
            check: false,
            synthetic: false,
            resume: false,
            learner: LearnerOptions::default(),
            report_every: farm::serve_args::REPORT_EVERY_S,
            grace: 3.0,
            bin_dir: None,
            remote_slots: 0,
            host: None,
        }
    }
}

/// How a farm ended.
#[derive(Debug)]
pub struct CrewOutcome {
    pub learner: Option<Ended>,
    /// Workers restarted by the orchestrator.
    pub restarts: u64,
    /// The learner's last progress record.
    pub progress: Option<Progress>,
    /// Files of the run iceoryx2 did not remove by itself (deleted by the orchestrator).
    pub leftovers: Vec<PathBuf>,
    pub seconds: f64,
    /// The run was stopped from outside (signal / [`Crew::stop`]) rather than ending by itself.
    pub stopped: bool,
}

struct WorkerSlot {
    child: Option<Child>,
    generation: u32,
    /// Consecutive failures within `QUICK_FAILURE` of starting.
    quick_failures: u32,
    /// Exited 0 (told to shut down).
    done: bool,
}

/// Mesa llvmpipe/lavapipe's rasteriser thread count.
const LP_THREADS_ENV: &str = "LP_NUM_THREADS";

/// A failure this soon after start counts towards giving up on a worker slot.
const QUICK_FAILURE: Duration = Duration::from_secs(10);
const MAX_QUICK_FAILURES: u32 = 3;
/// When stopping: SIGKILL the workers left at this point.
const KILL_AFTER: Duration = Duration::from_millis(4500);
/// When stopping: the learner finishes (or cuts short) its update and writes the final
/// checkpoint, however long that takes; only a learner still alive after this is killed (a
/// third Ctrl-C does it at once).
const LEARNER_STOP_LIMIT: Duration = Duration::from_secs(600);

/// Whether the farm is still running.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CrewState {
    Running,
    /// Every child has ended.
    Ended,
}

pub struct Crew {
    spec: CrewSpec,
    worker_bin: PathBuf,
    learner_bin: PathBuf,
    learner: Option<Child>,
    learner_ended: Option<Ended>,
    workers: Vec<WorkerSlot>,
    restarts: u64,
    started: Instant,
    stopping: Option<Instant>,
    stopped_from_outside: bool,
    escalated_term: bool,
    fatal: Option<anyhow::Error>,
    /// `farm.jsonl`'s length before this crew's learner: a resumed run's file holds the lines of
    /// the processes before it, which are not this crew's progress.
    progress_from: u64,
}

impl Crew {
    /// Spawns the learner and the workers.
    pub fn start(spec: CrewSpec) -> anyhow::Result<Crew> {
        let worker_bin = binaries::sibling_in(spec.bin_dir.as_deref(), "worker")?;
        let learner_bin = binaries::sibling_in(spec.bin_dir.as_deref(), "learner")?;
        if spec.workers == 0 {
            anyhow::bail!("--workers must be at least 1");
        }
        if let Some(p) = &spec.programs {
            anyhow::ensure!(p.len() == spec.workers, "{} program lists for {} workers", p.len(), spec.workers);
        }
        anyhow::ensure!(
            spec.cfg.env.frames == farm::config::FramePath::SharedMemory
                || (spec.host.is_none() && spec.remote_slots == 0),
            "env.frames = \"device\" keeps frames in the GPU memory of the learner's machine: no remote workers"
        );
        let first_generation = spec.host.map_or(0, |h| h.first_generation);
        let progress_from = std::fs::metadata(spec.run_dir.join("farm.jsonl")).map_or(0, |m| m.len());
        let mut crew = Crew {
            progress_from,
            workers: (0..spec.workers)
                .map(|_| WorkerSlot { child: None, generation: first_generation, quick_failures: 0, done: false })
                .collect(),
            spec,
            worker_bin,
            learner_bin,
            learner: None,
            learner_ended: None,
            restarts: 0,
            started: Instant::now(),
            stopping: None,
            stopped_from_outside: false,
            escalated_term: false,
            fatal: None,
        };
        // A previous run in this folder may have been killed: remove what it left.
        let _ = transport::clean_dead_nodes(&crew.spec.run_id);
        if crew.spec.host.is_none() {
            crew.spawn_learner()?;
        }
        for k in 0..crew.spec.workers {
            if let Err(e) = crew.spawn_worker(k) {
                crew.kill_now();
                return Err(e);
            }
        }
        Ok(crew)
    }

    pub fn spec(&self) -> &CrewSpec {
        &self.spec
    }

    fn log_path(&self, name: &str) -> PathBuf {
        self.spec.run_dir.join("logs").join(format!("{name}.log"))
    }

    fn spawn_learner(&mut self) -> anyhow::Result<()> {
        let s = &self.spec;
        let mut serve = ServeArgs::new(
            s.config_path.clone(),
            s.run_id.clone(),
            s.workers + s.remote_slots,
            s.run_dir.clone(),
            s.policy,
        );
        serve.max_frames = s.max_frames;
        serve.max_seconds = s.max_seconds;
        serve.eval = s.programs.is_some();
        serve.check = s.check;
        serve.resume = s.resume;
        serve.report_every = s.report_every;
        serve.options = s.learner.clone();
        let args: Vec<OsString> = std::iter::once("serve".into()).chain(serve.to_args()).collect();
        let log = self.log_path("learner");
        append_line(&log, &format!("=== learner, run {} ===", s.run_id));
        let child = child::spawn(&self.learner_bin, &args, &child::learner_env(), &log, Signal::SIGINT)
            .with_context(|| format!("starting {}", self.learner_bin.display()))?;
        self.learner = Some(child);
        Ok(())
    }

    /// Programs worker `k` still has to run: its list minus those already recorded in
    /// `episodes.jsonl` (by any generation).
    fn remaining_programs(&self, k: usize) -> Option<Vec<u64>> {
        let all = self.spec.programs.as_ref()?.get(k)?.clone();
        let done: std::collections::HashSet<u64> = std::fs::read_to_string(self.spec.run_dir.join("episodes.jsonl"))
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter(|v| v["worker"].as_u64() == Some(k as u64))
            .filter_map(|v| v["program"].as_u64())
            .collect();
        Some(all.into_iter().filter(|p| !done.contains(p)).collect())
    }

    /// The learner's slot of this crew's worker `k`.
    fn worker_id(&self, k: usize) -> usize {
        k + self.spec.host.map_or(0, |h| h.first_slot as usize)
    }

    fn spawn_worker(&mut self, k: usize) -> anyhow::Result<()> {
        let g = self.workers[k].generation;
        let s = &self.spec;
        let id = self.worker_id(k);
        let mut args: Vec<OsString> = vec![
            "--config".into(),
            s.config_path.clone().into(),
            "--run-id".into(),
            s.run_id.clone().into(),
            "--worker-id".into(),
            id.to_string().into(),
            "--generation".into(),
            g.to_string().into(),
        ];
        if let Some(programs) = self.remaining_programs(k) {
            let dir = s.run_dir.join("programs");
            std::fs::create_dir_all(&dir)?;
            let p = dir.join(format!("worker-{k}-g{g}.json"));
            farm::files::write_atomic(&p, serde_json::to_string(&programs)?.as_bytes())?;
            args.extend(["--programs".into(), p.into()]);
        }
        if s.policy == Policy::Expert {
            args.push("--expert-hints".into());
        }
        if s.synthetic {
            args.push("--synthetic".into());
        }
        if s.cfg.env.frames == farm::config::FramePath::Device {
            // the learner binds it in the run folder (`learner::device_frames`)
            args.extend(["--frames-socket".into(), farm::frame_socket::socket_path(&s.run_dir).into()]);
        }
        let log = self.log_path(&format!("worker-{id}"));
        append_line(&log, &format!("=== worker {id}, generation {g} ==="));
        let child = child::spawn(&self.worker_bin, &args, &self.renderer_env(), &log, Signal::SIGTERM)
            .with_context(|| format!("starting {}", self.worker_bin.display()))?;
        self.workers[k].child = Some(child);
        Ok(())
    }

    /// Environment for the workers' renderers. On a machine without a GPU the renderer is
    /// Mesa's lavapipe, which by default rasterises on as many extra threads as there are
    /// cores, in every worker. Once there are at least as many workers as cores, the processes
    /// fill the cores by themselves and the extra threads only add hand-offs and contention:
    /// each worker then rasterises in its own thread (`LP_NUM_THREADS=0`); with fewer workers
    /// each gets its share of the cores (`orchestrator bench farm` with and without
    /// `LP_NUM_THREADS=0` compares them). A user's `LP_NUM_THREADS` wins; a GPU driver ignores the variable.
    fn renderer_env(&self) -> Vec<(&'static str, String)> {
        if std::env::var_os(LP_THREADS_ENV).is_some() {
            return vec![];
        }
        let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        let share = cores / self.spec.workers;
        vec![(LP_THREADS_ENV, if share <= 1 { 0 } else { share }.to_string())]
    }

    /// Reaps what ended, restarts crashed workers, escalates a stop. Call it often (every
    /// few tens of milliseconds).
    pub fn tick(&mut self) -> anyhow::Result<CrewState> {
        self.reap_learner();
        let crashed = self.reap_workers();
        self.restart(crashed);
        self.escalate_stop();
        let alive = self.learner.is_some() || self.workers.iter().any(|w| w.child.is_some());
        Ok(if alive { CrewState::Running } else { CrewState::Ended })
    }

    /// A learner that ended ends the run (a failure with its log's last lines).
    fn reap_learner(&mut self) {
        if let Some(l) = &self.learner
            && let Some(ended) = child::reap(l.pid)
        {
            self.learner = None;
            self.learner_ended = Some(ended);
            if !ended.success() && self.stopping.is_none() {
                let log = self.log_path("learner");
                self.fatal = Some(anyhow::anyhow!(
                    "the learner {ended}; last lines of {}:\n{}",
                    log.display(),
                    child::tail(&log, 15)
                ));
            }
            if self.stopping.is_none() {
                self.begin_stop();
            }
        }
    }

    /// Workers that ended: done (exit 0), or crashed, to be restarted (returned) unless they
    /// keep failing right after starting, which ends the run.
    fn reap_workers(&mut self) -> Vec<usize> {
        let mut crashed = vec![];
        for k in 0..self.workers.len() {
            let Some(c) = &self.workers[k].child else { continue };
            let Some(ended) = child::reap(c.pid) else { continue };
            let ran = c.started.elapsed();
            let pid = c.pid;
            self.workers[k].child = None;
            if self.stopping.is_some() {
                continue;
            }
            if ended.success() {
                self.workers[k].done = true;
                continue;
            }
            let id = self.worker_id(k);
            let log = self.log_path(&format!("worker-{id}"));
            let tag = if self.spec.host.is_some() { "workers" } else { "up" };
            let slot = &mut self.workers[k];
            slot.quick_failures = if ran < QUICK_FAILURE { slot.quick_failures + 1 } else { 0 };
            if slot.quick_failures >= MAX_QUICK_FAILURES {
                self.fatal = Some(anyhow::anyhow!(
                    "worker {id} failed {MAX_QUICK_FAILURES} times within {} s of starting (last: pid {pid} {ended}); last lines of {}:\n{}",
                    QUICK_FAILURE.as_secs(),
                    log.display(),
                    child::tail(&log, 15)
                ));
                self.begin_stop();
                break;
            }
            eprintln!(
                "[{tag}] worker {id} (pid {pid}, generation {}) {ended}; restarting it as generation {}",
                slot.generation,
                slot.generation + 1
            );
            crashed.push(k);
        }
        crashed
    }

    /// Restarts crashed workers as their next generation, after removing what they left.
    fn restart(&mut self, crashed: Vec<usize>) {
        if !crashed.is_empty() {
            // The dead processes could not remove their ports and segments themselves.
            if let Err(e) = transport::clean_dead_nodes(&self.spec.run_id) {
                eprintln!("[up] cleaning up after dead workers: {e}");
            }
            for k in crashed {
                self.workers[k].generation += 1;
                self.restarts += 1;
                if let Err(e) = self.spawn_worker(k) {
                    self.fatal = Some(e.context(format!("restarting worker {k}")));
                    self.begin_stop();
                    break;
                }
            }
        }
    }

    /// A stop in progress: SIGTERM to the workers after the grace, SIGKILL at the limits.
    fn escalate_stop(&mut self) {
        if let Some(t0) = self.stopping {
            let el = t0.elapsed();
            if el >= KILL_AFTER {
                self.signal_workers(Signal::SIGKILL);
            } else if el >= Duration::from_secs_f64(self.spec.grace) && !self.escalated_term {
                self.escalated_term = true;
                self.signal_workers(Signal::SIGTERM);
            }
            if el >= LEARNER_STOP_LIMIT
                && let Some(l) = &self.learner
            {
                child::signal(l, Signal::SIGKILL);
            }
        }
    }

    fn signal_all(&self, sig: Signal) {
        if let Some(l) = &self.learner {
            child::signal(l, sig);
        }
        self.signal_workers(sig);
    }

    fn signal_workers(&self, sig: Signal) {
        for w in &self.workers {
            if let Some(c) = &w.child {
                child::signal(c, sig);
            }
        }
    }

    /// Whether the learner is writing its final checkpoint now.
    pub fn writing_final_checkpoint(&self) -> bool {
        self.learner.is_some()
            && farm::checkpoints::final_write_in_progress(&farm::checkpoints::dir_of(&self.spec.run_dir))
    }

    /// Whether the learner is still alive.
    pub fn learner_alive(&self) -> bool {
        self.learner.is_some()
    }

    fn begin_stop(&mut self) {
        if self.stopping.is_some() {
            return;
        }
        self.stopping = Some(Instant::now());
        if let Some(l) = &self.learner {
            child::signal(l, Signal::SIGINT);
        }
        for w in &self.workers {
            if let Some(c) = &w.child {
                child::signal(c, Signal::SIGTERM);
            }
        }
    }

    /// Stops the run from outside (Ctrl-C): SIGINT to the learner so it ends its update and
    /// checkpoints, SIGTERM to the workers; [`Crew::tick`] escalates for the workers (SIGTERM,
    /// SIGKILL) and waits for the learner.
    pub fn stop(&mut self) {
        if self.stopping.is_none() {
            self.stopped_from_outside = true;
        }
        self.begin_stop();
    }

    /// SIGKILL to every child now (a third Ctrl-C).
    pub fn kill_now(&mut self) {
        if self.stopping.is_none() {
            self.stopping = Some(Instant::now());
            self.stopped_from_outside = true;
        }
        self.signal_all(Signal::SIGKILL);
    }

    pub fn is_stopping(&self) -> bool {
        self.stopping.is_some()
    }

    pub fn learner_pid(&self) -> Option<Pid> {
        self.learner.as_ref().map(|c| c.pid)
    }

    /// The pid of each worker slot's current process.
    pub fn worker_pids(&self) -> Vec<Option<Pid>> {
        self.workers.iter().map(|w| w.child.as_ref().map(|c| c.pid)).collect()
    }

    pub fn generations(&self) -> Vec<u32> {
        self.workers.iter().map(|w| w.generation).collect()
    }

    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// The learner's latest progress record.
    pub fn progress(&self) -> Option<Progress> {
        read_last_progress_after(&self.spec.run_dir, self.progress_from)
    }

    /// Runs [`Crew::tick`] until every child has ended (stopping first if asked), then ends the
    /// run's shared-memory domain.
    pub fn finish(mut self) -> anyhow::Result<CrewOutcome> {
        while self.tick()? == CrewState::Running {
            std::thread::sleep(Duration::from_millis(20));
        }
        let leftovers = transport::end_run_domain(&self.spec.run_id).context("cleaning up the run's shared memory")?;
        if let Some(e) = self.fatal.take() {
            return Err(e);
        }
        Ok(CrewOutcome {
            learner: self.learner_ended,
            restarts: self.restarts,
            progress: read_last_progress(&self.spec.run_dir),
            leftovers,
            seconds: self.started.elapsed().as_secs_f64(),
            stopped: self.stopped_from_outside,
        })
    }

    /// An error that ended (or is ending) the run, if any.
    pub fn failed(&self) -> bool {
        self.fatal.is_some()
    }
}

impl Drop for Crew {
    fn drop(&mut self) {
        // Never leave children behind, whatever path dropped the farm.
        if self.learner.is_some() || self.workers.iter().any(|w| w.child.is_some()) {
            self.signal_all(Signal::SIGKILL);
            for c in self.learner.iter().chain(self.workers.iter().filter_map(|w| w.child.as_ref())) {
                let _ = nix::sys::wait::waitpid(c.pid, None);
            }
            let _ = transport::end_run_domain(&self.spec.run_id);
        }
    }
}

fn append_line(path: &Path, line: &str) {
    use std::io::Write;
    if let Ok(mut f) = std::fs::OpenOptions::new().create(true).append(true).open(path) {
        let _ = writeln!(f, "{line}");
    }
}

/// The last complete record of `RUN/farm.jsonl`.
pub fn read_last_progress(run_dir: &Path) -> Option<Progress> {
    read_last_progress_after(run_dir, 0)
}

/// The newest progress line of `farm.jsonl` written past its byte `from`.
fn read_last_progress_after(run_dir: &Path, from: u64) -> Option<Progress> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(run_dir.join("farm.jsonl")).ok()?;
    f.seek(SeekFrom::Start(from)).ok()?;
    let mut text = String::new();
    f.read_to_string(&mut text).ok()?;
    text.lines().rev().find_map(|l| serde_json::from_str(l).ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resumed_crew_reads_only_its_own_learners_progress() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("farm.jsonl");
        std::fs::write(&log, "{\"frames\":3145760}\n").unwrap();
        let from = std::fs::metadata(&log).unwrap().len();
        assert!(read_last_progress_after(dir.path(), from).is_none(), "nothing of this learner yet");
        let mut f = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
        std::io::Write::write_all(&mut f, b"{\"frames\":4096}\n").unwrap();
        assert_eq!(read_last_progress_after(dir.path(), from).unwrap().totals.frames, 4096);
        assert_eq!(read_last_progress(dir.path()).unwrap().totals.frames, 4096);
    }
}
