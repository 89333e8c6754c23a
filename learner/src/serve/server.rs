//! The policy server: gathers one observation from every worker that answers, runs the policy
//! on the whole batch, sends each worker its actions, and keeps the books (frames, episodes,
//! message integrity) of the run.
//!
//! A round closes when every live worker has sent, or `batch_timeout` after its first
//! observation arrived: a worker that misses the deadline is marked absent and no round waits
//! for it again until it sends (so a dead worker costs one timeout, not one per round). A
//! policy that decides env by env (random, expert) does not want full batches: each round then
//! takes whoever has sent and answers at once, so no worker waits for a slower one. A policy may
//! split rounds into groups of workers taken in turn ([`Policy::groups_now`], `ppo.env_groups`):
//! a group's round closes as a round for all does, and while its envs are inferred the next
//! group's workers step and render. A worker restarted by the orchestrator announces
//! `generation + 1`: its state is reset, and observations of older generations still in flight
//! are dropped.
//!
//! Every observation is checked as it arrives (`crate::serve::integrity`: header, layout, and the
//! message and env-step counters within a generation). Violations are counted (`lost`,
//! `duplicates`, `corrupt`) and, in check mode, fail the run.
//!
//! Files in the run directory (`crate::logs::records`): `farm.jsonl` (a progress record every
//! `report_every`, and a final one), `episodes.jsonl` (one line per finished episode), in
//! evaluation `trajectories.jsonl` (every episode step by step), `farm_summary.json` (at exit).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use farm::process;
use farm::profile::{LearnerTime, Profile, WorkerTime, process_cpu_seconds};
use farm::transport::TransportError;
use shm_schema::{ACT_MAGIC, ActionMsg, EnvRecord, MAX_ENVS, ObsHeader, ObsShape, WorkerTiming, action, command};

use crate::logs::records::{RecordError, RunRecords, Summary, WorkerSummary};
use crate::serve::batch::{WorkerBatch, WorkerObs};
use crate::serve::integrity::{self, Expected, Verdict};
use crate::serve::policy::Policy;
use crate::transport::{LearnerPorts, ObsMessage};
use farm::progress::{Counters, Progress};

/// How to serve a run.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    pub run_id: String,
    pub workers: usize,
    pub run_dir: PathBuf,
    /// What every worker's observations must look like (from the run config).
    pub envs_per_worker: usize,
    pub width: u32,
    pub height: u32,
    /// Close a round this long after its first observation even if some workers are missing.
    pub batch_timeout: Duration,
    /// Stop (SHUTDOWN to every worker) after this many frames.
    pub max_frames: Option<u64>,
    pub max_seconds: Option<f64>,
    /// Evaluation: stop once every worker reports `finished`.
    pub eval: bool,
    /// Fail the run on any lost, duplicated or malformed message.
    pub check: bool,
    pub report_every: Duration,
    /// How long to keep answering SHUTDOWN to stragglers when stopping.
    pub drain_timeout: Duration,
    /// Before the first round, wait until every worker has sent its first observation, or
    /// this long, whichever comes first (workers start at different speeds; a worker that
    /// fails to start must not hold the run up for ever).
    pub start_wait: Duration,
}

impl ServeOptions {
    pub fn new(run_id: &str, workers: usize, run_dir: &Path, envs_per_worker: usize, width: u32, height: u32) -> Self {
        ServeOptions {
            run_id: run_id.into(),
            workers,
            run_dir: run_dir.into(),
            envs_per_worker,
            width,
            height,
            batch_timeout: Duration::from_millis(1000),
            max_frames: None,
            max_seconds: None,
            eval: false,
            check: false,
            report_every: Duration::from_secs(2),
            drain_timeout: Duration::from_secs(2),
            start_wait: Duration::from_secs(60),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("policy `{name}`")]
    Policy { name: String, source: anyhow::Error },
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("check failed: {0}")]
    Check(String),
}

/// The server's knowledge of one worker slot.
#[derive(Debug)]
struct Slot {
    /// Its generation and message counters.
    expected: Expected,
    /// The observation waiting for this round's answer, and whether it is the first of its
    /// generation.
    held: Option<(ObsMessage, bool)>,
    absent: bool,
    finished: bool,
    shutdown_sent: bool,
    sent_at: Option<Instant>,
    messages: u64,
    frames: u64,
    /// The worker process's own profile, from its latest observation.
    timing: WorkerTiming,
}

impl Slot {
    fn new() -> Slot {
        Slot {
            expected: Expected::default(),
            held: None,
            absent: false,
            finished: false,
            shutdown_sent: false,
            sent_at: None,
            messages: 0,
            frames: 0,
            timing: WorkerTiming::default(),
        }
    }

    fn generation(&self) -> Option<u32> {
        self.expected.generation
    }

    fn live(&self) -> bool {
        self.generation().is_some() && !self.absent && !self.shutdown_sent
    }
}

/// Why serving stopped.
#[derive(Clone, Debug, PartialEq)]
enum Stop {
    Frames,
    Seconds,
    EvalDone,
    Signal(nix::sys::signal::Signal),
}

impl Stop {
    fn describe(&self) -> String {
        match self {
            Stop::Frames => "frame budget reached".into(),
            Stop::Seconds => "time budget reached".into(),
            Stop::EvalDone => "every worker finished its programs".into(),
            Stop::Signal(s) => format!("stopped by {s}"),
        }
    }
}

struct Server<'p> {
    opts: ServeOptions,
    shape: ObsShape,
    ports: LearnerPorts,
    policy: &'p mut dyn Policy,
    slots: Vec<Slot>,
    totals: Counters,
    records: RunRecords,
    start: Instant,
    last_report: (Instant, Counters),
    problems: Vec<String>,
    /// The learner's timeline so far.
    time: LearnerTime,
    /// The group of workers whose round is next when the policy splits rounds
    /// ([`Policy::groups_now`]).
    next_group: usize,
}

/// Serves `policy` to the run's workers until a budget is spent, the evaluation is done or a
/// termination signal arrives; then answers every worker with SHUTDOWN and returns the summary.
pub fn serve(opts: &ServeOptions, policy: &mut dyn Policy) -> Result<Summary, ServeError> {
    let shape = ObsShape::new(opts.envs_per_worker, opts.width, opts.height);
    if opts.envs_per_worker > MAX_ENVS {
        return Err(ServeError::Check(format!("{} envs per worker; at most {MAX_ENVS}", opts.envs_per_worker)));
    }
    let records = RunRecords::open(&opts.run_dir, opts.eval, opts.workers, opts.envs_per_worker)?;
    let ports = LearnerPorts::open(&opts.run_id, opts.workers)?;
    let now = Instant::now();
    if let Some(s) = opts.max_seconds {
        // so that an update running when the budget ends is cut short too
        process::set_deadline(Duration::from_secs_f64(s));
    }
    let mut server = Server {
        opts: opts.clone(),
        shape,
        ports,
        policy,
        slots: (0..opts.workers).map(|_| Slot::new()).collect(),
        totals: Counters::default(),
        records,
        start: now,
        last_report: (now, Counters::default()),
        problems: vec![],
        time: LearnerTime::default(),
        next_group: 0,
    };
    tracing::info!("serving policy `{}` to {} workers of run {}", server.policy.name(), opts.workers, opts.run_id);
    let stop = server.run()?;
    server.finish(stop)
}

impl Server<'_> {
    fn run(&mut self) -> Result<Stop, ServeError> {
        let mut round_start: Option<Instant> = None;
        let mut started = false;
        loop {
            if let Some(sig) = process::termination_signal() {
                return Ok(Stop::Signal(sig));
            }
            if let Some(s) = self.opts.max_seconds
                && self.start.elapsed().as_secs_f64() >= s
            {
                return Ok(Stop::Seconds);
            }
            let t = Instant::now();
            self.collect()?;
            self.time.receive_s += t.elapsed().as_secs_f64();
            self.report(None)?;
            let (group, groups) = self.round_workers();
            let any = group.clone().any(|k| self.slots[k].held.is_some());
            if !started {
                let seen = self.slots.iter().filter(|s| s.generation().is_some()).count();
                started = seen == self.slots.len() || (seen > 0 && self.start.elapsed() >= self.opts.start_wait);
                if !started {
                    self.wait(Duration::from_millis(50));
                    continue;
                }
                tracing::info!("{seen} of {} workers connected; serving", self.slots.len());
            }
            if any {
                let first = *round_start.get_or_insert_with(Instant::now);
                let waiting: Vec<usize> = if self.policy.wants_full_batches() {
                    group.clone().filter(|&k| self.slots[k].live() && self.slots[k].held.is_none()).collect()
                } else {
                    vec![] // answer whoever has sent, now
                };
                if waiting.is_empty() || first.elapsed() >= self.opts.batch_timeout {
                    for k in waiting {
                        tracing::warn!(
                            "worker {k} did not answer within {:?}; going on without it",
                            self.opts.batch_timeout
                        );
                        self.slots[k].absent = true;
                    }
                    round_start = None;
                    if let Some(stop) = self.round(group)? {
                        return Ok(stop);
                    }
                    self.next_group = (self.next_group + 1) % groups;
                    continue;
                }
                let left = self.opts.batch_timeout.saturating_sub(first.elapsed());
                self.wait(left.min(Duration::from_millis(50)));
            } else {
                self.wait(Duration::from_millis(50));
            }
        }
    }

    /// Takes every observation that arrived, checks it, and holds the newest per worker.
    fn collect(&mut self) -> Result<(), ServeError> {
        for k in 0..self.slots.len() {
            while let Some(msg) = self.ports.receive(k)? {
                self.accept(k, msg)?;
            }
        }
        Ok(())
    }

    fn problem(&mut self, what: String) -> Result<(), ServeError> {
        tracing::warn!("{what}");
        if self.problems.len() < 20 {
            self.problems.push(what.clone());
        }
        if self.opts.check { Err(ServeError::Check(what)) } else { Ok(()) }
    }

    /// Judges an arriving message (`crate::serve::integrity`), counts what it says, and holds it
    /// for the round when it is accepted.
    fn accept(&mut self, k: usize, msg: ObsMessage) -> Result<(), ServeError> {
        let h = *msg.header();
        let slot = &self.slots[k];
        let a = match integrity::check(k, &slot.expected, slot.held.is_some(), &self.shape, &h, msg.payload()) {
            Verdict::Accept(a) => a,
            Verdict::Corrupt(why) => {
                self.totals.corrupt += 1;
                return self.problem(format!("worker {k}: malformed observation dropped: {why}"));
            }
            Verdict::Stale { .. } => {
                self.totals.stale += 1;
                return Ok(());
            }
            Verdict::Duplicate(why) => {
                self.totals.duplicates += 1;
                return self.problem(why);
            }
        };
        let slot = &mut self.slots[k];
        if a.new_generation {
            if let Some(g) = a.replaces {
                self.totals.restarts += 1;
                tracing::info!("worker {k} is back as generation {} (was {g})", h.generation);
            }
            *slot = Slot::new();
        }
        slot.expected = a.next;
        self.totals.lost += a.lost;
        self.totals.duplicates += a.duplicates;
        if let Some(t) = slot.sent_at.take() {
            self.totals.latency_sum_s += t.elapsed().as_secs_f64();
            self.totals.latency_count += 1;
        }
        slot.absent = false;
        slot.finished = h.finished != 0;
        slot.messages += 1;
        slot.timing = h.timing;
        slot.held = Some((msg, a.new_generation));
        self.totals.messages += 1;
        for why in a.issues {
            self.problem(why)?;
        }
        Ok(())
    }

    /// Books the frames and finished episodes of one observation.
    fn account(&mut self, k: usize, records: &[EnvRecord], generation: u32) -> Result<(), ServeError> {
        for (e, r) in records.iter().enumerate() {
            if r.idle != 0 {
                continue;
            }
            self.totals.frames += 1;
            self.slots[k].frames += 1;
            self.records.trajectory_step(k, e, r)?;
            if r.terminated != 0 || r.truncated != 0 {
                self.totals.episodes += 1;
                self.totals.successes += (r.summary.success != 0) as u64;
                self.records.episode(k as u32, generation, e, r)?;
            }
        }
        Ok(())
    }

    /// Waits for the next observation (at most `d`), on the profile's clock.
    fn wait(&mut self, d: Duration) {
        let t = Instant::now();
        self.ports.wait(d);
        self.time.wait_s += t.elapsed().as_secs_f64();
    }

    /// The workers of the next round, and into how many groups the policy splits rounds now: all
    /// workers (1), or the next group in turn — contiguous blocks, so a group's envs are one
    /// range of the policy's.
    fn round_workers(&mut self) -> (std::ops::Range<usize>, usize) {
        let w = self.slots.len();
        let groups = if self.policy.wants_full_batches() { self.policy.groups_now().clamp(1, w) } else { 1 };
        if groups == 1 {
            self.next_group = 0;
        }
        let g = self.next_group.min(groups - 1);
        (g * w / groups..(g + 1) * w / groups, groups)
    }

    /// Runs the policy on the held observations of `workers` and answers each of them:
    /// gather → act → check → account → answer. Returns a stop reason when this round ended the
    /// run (its answers were then SHUTDOWN).
    fn round(&mut self, workers: std::ops::Range<usize>) -> Result<Option<Stop>, ServeError> {
        let began = Instant::now();
        let held: Vec<(usize, ObsMessage, bool)> =
            workers.clone().filter_map(|k| self.slots[k].held.take().map(|(m, g)| (k, m, g))).collect();
        let batch = self.gather(workers, &held);
        self.time.receive_s += began.elapsed().as_secs_f64();
        let actions = self.timed(|s| s.policy.act(&batch)).map_err(|source| self.policy_error(source))?;
        let answering = Instant::now();
        self.check(&actions, batch.num_envs())?;
        for p in &batch.parts {
            self.account(p.worker as usize, p.records(), p.generation)?;
        }
        self.totals.rounds += 1;
        let stop = self.stop_reason();
        self.answer(&batch, &actions, if stop.is_some() { command::SHUTDOWN } else { command::STEP })?;
        self.records.flush_episodes()?;
        // The samples go back to their workers' pools here.
        drop(batch);
        drop(held);
        self.time.send_s += answering.elapsed().as_secs_f64();
        Ok(stop)
    }

    /// The round's batch, read in place from the held samples; `missing`: the workers of the
    /// round that have started but sent nothing.
    fn gather<'a>(&self, workers: std::ops::Range<usize>, held: &'a [(usize, ObsMessage, bool)]) -> WorkerBatch<'a> {
        let missing: Vec<u32> = workers
            .clone()
            .filter(|&k| self.slots[k].generation().is_some() && !held.iter().any(|h| h.0 == k))
            .map(|k| k as u32)
            .collect();
        let parts: Vec<WorkerObs> = held
            .iter()
            .map(|(k, m, new_generation)| {
                let header = m.header();
                let view = m.view().expect("checked on arrival");
                let (worker, generation, new_generation) = (*k as u32, header.generation, *new_generation);
                WorkerObs { worker, generation, new_generation, header, view }
            })
            .collect();
        WorkerBatch { width: self.shape.width, height: self.shape.height, workers, parts, missing }
    }

    /// Runs `act` and charges its wall and CPU time to inference and learning, in the share
    /// the policy reports it spent learning.
    fn timed<T>(&mut self, act: impl FnOnce(&mut Self) -> T) -> T {
        let t = Instant::now();
        let learning_before = self.policy.learning_seconds();
        let cpu_before = process_cpu_seconds();
        let out = act(self);
        let acted = t.elapsed().as_secs_f64();
        let cpu = process_cpu_seconds() - cpu_before;
        let learning = (self.policy.learning_seconds() - learning_before).clamp(0.0, acted);
        self.totals.policy_sum_s += acted;
        self.time.update_s += learning;
        self.time.infer_s += acted - learning;
        let learning_share = if acted > 0.0 { learning / acted } else { 0.0 };
        self.time.update_cpu_s += cpu * learning_share;
        self.time.infer_cpu_s += cpu * (1.0 - learning_share);
        out
    }

    fn policy_error(&self, source: anyhow::Error) -> ServeError {
        ServeError::Policy { name: self.policy.name().into(), source }
    }

    /// One action in range per env of the batch, or the policy is broken.
    fn check(&self, actions: &[u8], envs: usize) -> Result<(), ServeError> {
        if actions.len() != envs || actions.iter().any(|&a| a as usize >= action::COUNT) {
            let why =
                anyhow::anyhow!("returned {} actions (values < {}) for {envs} envs", actions.len(), action::COUNT);
            return Err(self.policy_error(why));
        }
        Ok(())
    }

    /// Whether the run ends with this round: its frame budget spent, or every worker of an
    /// evaluation finished.
    fn stop_reason(&self) -> Option<Stop> {
        if self.opts.max_frames.is_some_and(|m| self.totals.frames >= m) {
            Some(Stop::Frames)
        } else if self.opts.eval && self.slots.iter().all(|s| s.generation().is_some() && s.finished) {
            Some(Stop::EvalDone)
        } else {
            None
        }
    }

    /// Sends each worker of the batch its envs' actions with `cmd`.
    fn answer(&mut self, batch: &WorkerBatch<'_>, actions: &[u8], cmd: u32) -> Result<(), ServeError> {
        let mut offset = 0;
        for p in &batch.parts {
            let n = p.num_envs();
            let k = p.worker as usize;
            self.send(k, p.header, cmd, &actions[offset..offset + n])?;
            offset += n;
        }
        Ok(())
    }

    /// Answers worker `k`'s message `header` with `cmd` and `actions` (none for SHUTDOWN).
    fn send(&mut self, k: usize, header: &ObsHeader, cmd: u32, actions: &[u8]) -> Result<(), ServeError> {
        let mut msg = ActionMsg {
            magic: ACT_MAGIC,
            worker_id: k as u32,
            generation: header.generation,
            command: cmd,
            step: header.step,
            num_envs: header.num_envs,
            ..Default::default()
        };
        msg.actions[..actions.len()].copy_from_slice(actions);
        self.ports.send(k, msg)?;
        self.slots[k].sent_at = Some(Instant::now());
        self.slots[k].shutdown_sent |= cmd == command::SHUTDOWN;
        Ok(())
    }

    /// Answers SHUTDOWN to every worker that sends (or holds an answer) until all have been
    /// told or are gone, or the drain timeout passes.
    fn drain(&mut self) -> Result<(), ServeError> {
        let until = Instant::now() + self.opts.drain_timeout;
        loop {
            self.collect()?;
            for k in 0..self.slots.len() {
                if let Some((m, _)) = self.slots[k].held.take() {
                    let h = *m.header();
                    let view = m.view().expect("checked on arrival");
                    self.account(k, view.records(), h.generation)?;
                    self.send(k, &h, command::SHUTDOWN, &[])?;
                }
            }
            let pending = (0..self.slots.len()).any(|k| {
                self.slots[k].generation().is_some() && !self.slots[k].shutdown_sent && self.ports.worker_attached(k)
            });
            if !pending || Instant::now() >= until {
                break;
            }
            self.ports.wait(Duration::from_millis(20));
        }
        Ok(self.records.flush()?)
    }

    fn progress(&self, now: Instant, stop: Option<&Stop>) -> Progress {
        let (t0, before) = &self.last_report;
        let dt = now.duration_since(*t0).as_secs_f64().max(1e-9);
        let dl = self.totals.latency_count - before.latency_count;
        Progress {
            t: now.duration_since(self.start).as_secs_f64(),
            fps: (self.totals.frames - before.frames) as f64 / dt,
            latency_ms: (dl > 0).then(|| 1000.0 * (self.totals.latency_sum_s - before.latency_sum_s) / dl as f64),
            success_rate: (self.totals.episodes > 0)
                .then(|| self.totals.successes as f64 / self.totals.episodes as f64),
            workers_seen: self.slots.iter().filter(|s| s.generation().is_some()).count(),
            workers_live: self.slots.iter().filter(|s| s.generation().is_some() && !s.absent).count(),
            totals: self.totals.clone(),
            stop_reason: stop.map(Stop::describe),
            profile: Profile {
                learner: LearnerTime { cpu_s: process_cpu_seconds(), ..self.time },
                workers: self.slots.iter().fold(WorkerTime::default(), |mut w, s| {
                    w.add(&s.timing);
                    w
                }),
                stages: self.policy.stage_times(),
            },
        }
    }

    /// Appends a progress record (and prints a line) when one is due, or always at the end.
    fn report(&mut self, stop: Option<&Stop>) -> Result<(), ServeError> {
        let now = Instant::now();
        if stop.is_none() && now.duration_since(self.last_report.0) < self.opts.report_every {
            return Ok(());
        }
        let p = self.progress(now, stop);
        self.records.progress(&p)?;
        self.policy.report(&p).map_err(|source| ServeError::Policy { name: self.policy.name().into(), source })?;
        eprintln!(
            "[learner] {:>7.1} s  frames {:>9} ({:>7.1}/s)  episodes {:>6}  success {}  workers {}/{}  restarts {}  step {}",
            p.t,
            p.totals.frames,
            p.fps,
            p.totals.episodes,
            p.success_rate.map(|s| format!("{:.3}", s)).unwrap_or_else(|| "-".into()),
            p.workers_live,
            self.slots.len(),
            p.totals.restarts,
            p.latency_ms.map(|l| format!("{l:.1} ms")).unwrap_or_else(|| "-".into()),
        );
        self.last_report = (now, self.totals.clone());
        Ok(())
    }

    fn finish(mut self, stop: Stop) -> Result<Summary, ServeError> {
        tracing::info!("{}; telling the workers to shut down", stop.describe());
        self.drain()?;
        let checkpoint = !matches!(stop, Stop::Signal(nix::sys::signal::Signal::SIGTERM));
        self.policy
            .finish(checkpoint)
            .map_err(|source| ServeError::Policy { name: self.policy.name().into(), source })?;
        self.report(Some(&stop))?;
        let summary = Summary {
            run_id: self.opts.run_id.clone(),
            policy: self.policy.name().into(),
            seconds: self.start.elapsed().as_secs_f64(),
            stop_reason: stop.describe(),
            totals: self.totals.clone(),
            workers: self
                .slots
                .iter()
                .enumerate()
                .map(|(k, s)| WorkerSummary {
                    worker: k as u32,
                    generation: s.generation(),
                    messages: s.messages,
                    frames: s.frames,
                    finished: s.finished,
                })
                .collect(),
        };
        self.records.summary(&summary)?;
        if self.opts.check {
            let t = &self.totals;
            if t.lost + t.duplicates + t.corrupt > 0 {
                return Err(ServeError::Check(format!(
                    "{} lost, {} duplicated, {} malformed messages: {}",
                    t.lost,
                    t.duplicates,
                    t.corrupt,
                    self.problems.join("; ")
                )));
            }
        }
        Ok(summary)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::logs::records::EpisodeLine;
    use crate::serve::policy::{ExpertPolicy, RandomPolicy};
    use farm::metrics::EpisodeResult;
    use farm::stepper::SyntheticStepper;
    use farm::transport::{self as wt, Exit, WorkerOptions};

    fn spawn_workers(
        run: &str,
        n: u32,
        envs: usize,
        generation: u32,
    ) -> Vec<std::thread::JoinHandle<Result<Exit, TransportError>>> {
        (0..n)
            .map(|k| {
                let opts = WorkerOptions::new(run, k, generation, 24, 16);
                std::thread::spawn(move || {
                    let mut s = SyntheticStepper::new(k, envs, 24, 16, None, true);
                    wt::serve(&mut s, &opts)
                })
            })
            .collect()
    }

    /// Two in-process workers (threads, synthetic envs) and the server: every message and env
    /// step arrives exactly once, episodes are written, every worker is shut down.
    #[test]
    fn serves_synthetic_workers_without_loss_and_shuts_them_down() {
        let run = format!("t{}-serve", std::process::id());
        let dir = tempfile::tempdir().unwrap();
        let workers = spawn_workers(&run, 2, 3, 0);
        let mut opts = ServeOptions::new(&run, 2, dir.path(), 3, 24, 16);
        opts.max_frames = Some(600);
        opts.check = true;
        let mut policy = ExpertPolicy;
        let s = serve(&opts, &mut policy).unwrap();
        for w in workers {
            assert_eq!(w.join().unwrap().unwrap(), Exit::Shutdown);
        }
        assert!(s.totals.frames >= 600, "{s:?}");
        assert_eq!((s.totals.lost, s.totals.duplicates, s.totals.corrupt), (0, 0, 0));
        // env-by-env policies answer each worker at once, so the two need not keep pace
        assert!(s.workers.iter().all(|w| w.generation == Some(0) && w.messages > 0), "{s:?}");
        let episodes = std::fs::read_to_string(dir.path().join("episodes.jsonl")).unwrap();
        let lines: Vec<EpisodeLine> = episodes.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(lines.len() as u64, s.totals.episodes);
        assert!(lines.len() > 50);
        // the synthetic task: even programs succeed
        assert!(lines.iter().all(|l| l.result.success == (l.result.program % 2 == 0)));
        // eval reads the same lines as plain episode results
        let first: EpisodeResult = serde_json::from_str(episodes.lines().next().unwrap()).unwrap();
        assert_eq!(first, lines[0].result);
        let progress = std::fs::read_to_string(dir.path().join("farm.jsonl")).unwrap();
        let last: Progress = serde_json::from_str(progress.lines().last().unwrap()).unwrap();
        assert_eq!(last.stop_reason.as_deref(), Some("frame budget reached"));
        assert!(dir.path().join("farm_summary.json").exists());
        assert!(wt::end_run_domain(&run).unwrap().is_empty());
    }

    /// A worker slot that comes back with a new generation is taken as a restart; answers to
    /// the old generation are never mixed in.
    #[test]
    fn a_new_generation_replaces_the_old_one() {
        let run = format!("t{}-gen", std::process::id());
        let dir = tempfile::tempdir().unwrap();
        let mut opts = ServeOptions::new(&run, 1, dir.path(), 2, 24, 16);
        opts.max_frames = Some(200);
        opts.check = true;
        opts.batch_timeout = Duration::from_millis(200);
        let server = std::thread::spawn(move || serve(&opts, &mut RandomPolicy::new(3)));
        // generation 0 runs a little, then generation 1 takes the slot over
        let g0 = std::thread::spawn({
            let run = run.clone();
            move || {
                let mut opts = WorkerOptions::new(&run, 0, 0, 24, 16);
                opts.learner_check_after = Duration::from_millis(200);
                let s = SyntheticStepper::new(0, 2, 24, 16, None, false);
                // fails after a few steps, as if the process crashed mid-run
                struct Crashing(SyntheticStepper, u32);
                impl farm::stepper::Stepper for Crashing {
                    fn num_envs(&self) -> usize {
                        self.0.num_envs()
                    }
                    fn layout(&self) -> shm_schema::ObsLayout {
                        self.0.layout()
                    }
                    fn reset(&mut self, p: &mut [u8]) -> anyhow::Result<()> {
                        self.0.reset(p)
                    }
                    fn step(&mut self, a: &[u8], p: &mut [u8]) -> anyhow::Result<()> {
                        self.1 += 1;
                        anyhow::ensure!(self.1 < 20, "crash");
                        self.0.step(a, p)
                    }
                    fn finished(&self) -> bool {
                        self.0.finished()
                    }
                }
                wt::serve(&mut Crashing(s, 0), &opts)
            }
        });
        assert!(g0.join().unwrap().is_err());
        let g1 = spawn_workers(&run, 1, 2, 1);
        let s = server.join().unwrap().unwrap();
        for w in g1 {
            assert_eq!(w.join().unwrap().unwrap(), Exit::Shutdown);
        }
        assert_eq!(s.totals.restarts, 1);
        assert_eq!(s.workers[0].generation, Some(1));
        assert_eq!((s.totals.lost, s.totals.duplicates, s.totals.corrupt), (0, 0, 0));
        assert!(wt::end_run_domain(&run).unwrap().is_empty());
    }
}
