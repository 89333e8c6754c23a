//! The worker's side of the farm over iceoryx2: node → services → ports → samples.
//!
//! Every iceoryx2 detail of the farm lives here (the learner's transport opens its services with
//! the functions below, so both sides always agree on the quality-of-service settings).
//!
//! Per worker `k` of run `R` (names in `shm_schema::service`, settings in `shm_schema::qos`):
//! - `obs/k` publish-subscribe, `[u8]` payload + [`ObsHeader`]: the worker loans an uninitialised
//!   sample, the [`Stepper`] writes the observation straight into it, the worker sends it;
//! - `obs_ready` event (one for the run, created by the learner): "an observation was sent";
//! - `act/k` publish-subscribe, [`ActionMsg`]: the learner's answer to one observation;
//! - `act_ready/k` event: "actions for worker k were published".
//!
//! All of a run's files carry the prefix `shm_schema::service::prefix(R)`, so two runs never
//! meet and a run's leftovers can be found.
//!
//! **Start handshake.** iceoryx2 delivers a sample only to subscribers connected when it is
//! sent. The worker sends its first observation only once the learner is there (a subscriber on
//! `obs/k` and a publisher on `act/k`); and since `obs/k` keeps the last sample as history, a
//! subscriber that still connects late receives it when the worker next updates its connections
//! (it does so while waiting for an answer).

use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use nix::sys::signal::Signal;
use shm_schema::{
    ACT_MAGIC, ActionMsg, GESTURE_DIMS, GESTURE_FRAMES, OBS_MAGIC, ObsHeader, ObsLayout, SCHEMA_VERSION, WorkerTiming,
    command, qos, service,
};

use crate::process;
use crate::stepper::Stepper;

pub type IpcService = ipc::Service;
pub type ObsService = publish_subscribe::PortFactory<IpcService, [u8], ObsHeader>;
pub type ActService = publish_subscribe::PortFactory<IpcService, ActionMsg, ()>;
pub type EventService = event::PortFactory<IpcService>;

/// A transport failure, named by what was being done.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("iceoryx2: {what}: {detail}")]
    Ipc { what: String, detail: String },
    #[error("no learner connected to {service} within {secs} s")]
    NoLearner { service: String, secs: u64 },
    #[error("the learner is gone: nobody publishes on {0}")]
    LearnerGone(String),
    #[error("environment: {0:#}")]
    Env(anyhow::Error),
}

fn ipc<E: std::fmt::Debug>(what: impl Into<String>) -> impl FnOnce(E) -> TransportError {
    let what = what.into();
    move |e| TransportError::Ipc { what, detail: format!("{e:?}") }
}

/// The iceoryx2 configuration of run `run_id`: defaults (no config file is read, so every
/// process of the run agrees) with the run's resource prefix.
pub fn run_config(run_id: &str) -> Result<Config, TransportError> {
    let mut cfg = Config::default();
    let prefix = service::prefix(run_id);
    cfg.global.prefix = FileName::new(prefix.as_bytes()).map_err(ipc(format!("resource prefix `{prefix}`")))?;
    Ok(cfg)
}

/// A node of run `run_id`. Signals are left to the role ([`crate::process`]), not iceoryx2.
pub fn open_node(run_id: &str, name: &str) -> Result<Node<IpcService>, TransportError> {
    let cfg = run_config(run_id)?;
    let node_name = NodeName::new(name).map_err(ipc(format!("node name `{name}`")))?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .config(&cfg)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(ipc(format!("creating node `{name}`")))?;
    make_private(run_id);
    Ok(node)
}

/// iceoryx2 0.10 creates a domain's node-counter segment (`/dev/shm/<prefix>…node.0_10_0.global_mgmt`)
/// with global access (0666; `GlobalManagementSegment` asks for it and no setting changes
/// that), so any user could corrupt a run's node ids. Every process of a run belongs to one
/// user, so whichever node comes first makes the run's files owner-only.
fn make_private(run_id: &str) {
    use std::os::unix::fs::PermissionsExt;
    for p in run_files(run_id) {
        let Ok(meta) = std::fs::symlink_metadata(&p) else { continue };
        if meta.is_file() && meta.permissions().mode() & 0o077 != 0 {
            if let Err(e) = std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)) {
                tracing::warn!("cannot make {} private to its user: {e}", p.display());
            }
        }
    }
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(ipc(format!("service name `{name}`")))
}

/// Opens (or creates) the observation service of worker `worker`.
pub fn open_obs_service(node: &Node<IpcService>, run_id: &str, worker: u32) -> Result<ObsService, TransportError> {
    let name = service::obs(run_id, worker);
    node.service_builder(&service_name(&name)?)
        .publish_subscribe::<[u8]>()
        .user_header::<ObsHeader>()
        .payload_alignment(Alignment::new(qos::OBS_PAYLOAD_ALIGNMENT).expect("power of two"))
        .enable_safe_overflow(qos::SAFE_OVERFLOW)
        .history_size(qos::OBS_HISTORY)
        .subscriber_max_buffer_size(qos::OBS_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(qos::OBS_SUBSCRIBER_MAX_BORROWED)
        .max_subscribers(qos::OBS_MAX_SUBSCRIBERS)
        .max_publishers(qos::OBS_MAX_PUBLISHERS)
        .max_nodes(qos::OBS_MAX_NODES)
        .open_or_create()
        .map_err(ipc(format!("opening {name}")))
}

/// Opens (or creates) the action service of worker `worker`.
pub fn open_act_service(node: &Node<IpcService>, run_id: &str, worker: u32) -> Result<ActService, TransportError> {
    let name = service::act(run_id, worker);
    node.service_builder(&service_name(&name)?)
        .publish_subscribe::<ActionMsg>()
        .enable_safe_overflow(qos::SAFE_OVERFLOW)
        .history_size(qos::ACT_HISTORY)
        .subscriber_max_buffer_size(qos::ACT_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(qos::ACT_SUBSCRIBER_MAX_BORROWED)
        .max_subscribers(qos::ACT_MAX_SUBSCRIBERS)
        .max_publishers(qos::ACT_MAX_PUBLISHERS)
        .max_nodes(qos::ACT_MAX_NODES)
        .open_or_create()
        .map_err(ipc(format!("opening {name}")))
}

/// Opens (or creates) the `act_ready/<worker>` event service.
pub fn open_act_ready(node: &Node<IpcService>, run_id: &str, worker: u32) -> Result<EventService, TransportError> {
    let name = service::act_ready(run_id, worker);
    node.service_builder(&service_name(&name)?)
        .event()
        .max_notifiers(qos::ACT_READY_MAX_NOTIFIERS)
        .max_listeners(qos::ACT_READY_MAX_LISTENERS)
        .max_nodes(qos::ACT_READY_MAX_NODES)
        .open_or_create()
        .map_err(ipc(format!("opening {name}")))
}

/// Creates the run's `obs_ready` event service, sized for `workers` workers (the learner does).
pub fn create_obs_ready(node: &Node<IpcService>, run_id: &str, workers: usize) -> Result<EventService, TransportError> {
    let name = service::obs_ready(run_id);
    node.service_builder(&service_name(&name)?)
        .event()
        .max_notifiers(qos::obs_ready_max_notifiers(workers))
        .max_listeners(qos::OBS_READY_MAX_LISTENERS)
        .max_nodes(qos::obs_ready_max_nodes(workers))
        .open_or_create()
        .map_err(ipc(format!("creating {name}")))
}

/// Opens the run's `obs_ready` event service once the learner has created it.
pub fn open_obs_ready(
    node: &Node<IpcService>,
    run_id: &str,
    deadline: Instant,
) -> Result<EventService, TransportError> {
    let name = service::obs_ready(run_id);
    let sname = service_name(&name)?;
    loop {
        match node.service_builder(&sname).event().open() {
            Ok(s) => return Ok(s),
            Err(e) => {
                if Instant::now() > deadline || process::termination_signal().is_some() {
                    return Err(TransportError::Ipc {
                        what: format!("opening {name} (the learner creates it)"),
                        detail: format!("{e:?}"),
                    });
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
}

/// What [`clean_dead_nodes`] found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Cleanup {
    pub alive: usize,
    pub dead_removed: usize,
    pub failed: usize,
}

/// Removes the iceoryx2 resources that dead processes of run `run_id` left behind (a worker
/// killed with SIGKILL cannot remove its own ports and segments). Safe while the run goes on:
/// live nodes are not touched.
pub fn clean_dead_nodes(run_id: &str) -> Result<Cleanup, TransportError> {
    let cfg = run_config(run_id)?;
    let mut out = Cleanup::default();
    Node::<IpcService>::list(&cfg, |state| {
        match state {
            NodeState::Alive(_) => out.alive += 1,
            NodeState::Dead(view) => match view.try_remove_stale_resources() {
                Ok(()) => out.dead_removed += 1,
                Err(_) => out.failed += 1,
            },
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => out.failed += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(ipc("listing the run's nodes"))?;
    Ok(out)
}

/// The files of run `run_id` that exist in `/dev/shm` and under iceoryx2's root directory.
pub fn run_files(run_id: &str) -> Vec<std::path::PathBuf> {
    let prefix = service::prefix(run_id);
    let mut out = vec![];
    let mut visit = |dir: &std::path::Path, recurse: bool| {
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            let Ok(rd) = std::fs::read_dir(&d) else { continue };
            for e in rd.flatten() {
                let p = e.path();
                if e.file_name().to_string_lossy().starts_with(&prefix) {
                    out.push(p);
                } else if recurse && e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                    stack.push(p);
                }
            }
        }
    };
    visit(std::path::Path::new("/dev/shm"), false);
    if let Ok(cfg) = run_config(run_id) {
        let root = String::from_utf8_lossy(cfg.global.root_path().as_bytes()).into_owned();
        visit(std::path::Path::new(&root), true);
    }
    out.sort();
    out
}

/// Ends run `run_id`'s iceoryx2 domain once none of its processes is alive: cleans what dead
/// nodes left, removes the domain's node counter segment (it outlives every node by design),
/// and finally deletes any file that still carries the run's prefix. Returns the files that
/// had to be deleted by hand (empty when iceoryx2 cleaned up everything itself).
pub fn end_run_domain(run_id: &str) -> Result<Vec<std::path::PathBuf>, TransportError> {
    let cleanup = clean_dead_nodes(run_id)?;
    if cleanup.alive > 0 {
        return Err(TransportError::Ipc {
            what: "ending the run's iceoryx2 domain".into(),
            detail: format!("{} node(s) of the run are still alive", cleanup.alive),
        });
    }
    let cfg = run_config(run_id)?;
    // SAFETY: no process of this run is alive (checked above), and the prefix is the run's own.
    let _ = unsafe { iceoryx2::testing::remove_global_mgmt_segment::<IpcService>(&cfg) };
    let left = run_files(run_id);
    for p in &left {
        let _ = if p.is_dir() { std::fs::remove_dir_all(p) } else { std::fs::remove_file(p) };
    }
    Ok(left)
}

/// Ends the iceoryx2 domains of GesTHOR runs that died without cleaning up (their
/// orchestrator was killed): every run whose node-counter segment in `/dev/shm` is older than
/// `min_age` and which has no live node. Returns the run ids cleaned.
pub fn sweep_dead_runs(min_age: Duration) -> Vec<String> {
    let marker = service::prefix("");
    let Ok(rd) = std::fs::read_dir("/dev/shm") else { return vec![] };
    let mut runs = std::collections::BTreeSet::new();
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix(marker.trim_end_matches('_')).and_then(|r| r.strip_prefix('_')) else {
            continue;
        };
        if !name.ends_with(".global_mgmt") {
            continue;
        }
        let old =
            e.metadata().and_then(|m| m.modified()).ok().and_then(|t| t.elapsed().ok()).is_some_and(|a| a >= min_age);
        if let Some(run) = rest.split('_').next().filter(|r| !r.is_empty())
            && old
        {
            runs.insert(run.to_string());
        }
    }
    runs.into_iter()
        .filter(|run| matches!(clean_dead_nodes(run), Ok(c) if c.alive == 0) && end_run_domain(run).is_ok())
        .collect()
}

/// How a worker loop ended without error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// The learner sent `SHUTDOWN`.
    Shutdown,
    /// A termination signal arrived.
    Terminated(Signal),
}

/// Who this worker is and how long it waits for its learner.
#[derive(Clone, Debug)]
pub struct WorkerOptions {
    pub run_id: String,
    pub worker_id: u32,
    pub generation: u32,
    pub width: u32,
    pub height: u32,
    /// How long to wait for the learner at the start.
    pub connect_timeout: Duration,
    /// After this long without an answer, check whether the learner still publishes actions.
    pub learner_check_after: Duration,
}

impl WorkerOptions {
    pub fn new(run_id: &str, worker_id: u32, generation: u32, width: u32, height: u32) -> Self {
        WorkerOptions {
            run_id: run_id.into(),
            worker_id,
            generation,
            width,
            height,
            connect_timeout: Duration::from_secs(120),
            learner_check_after: Duration::from_secs(5),
        }
    }
}

/// The ports of one worker process.
pub struct WorkerPorts {
    obs: ObsService,
    act: ActService,
    publisher: Publisher<IpcService, [u8], ObsHeader>,
    subscriber: Subscriber<IpcService, ActionMsg, ()>,
    obs_ready: Notifier<IpcService>,
    act_ready: Listener<IpcService>,
    // Dropped last: ports and services hold resources of the node.
    _node: Node<IpcService>,
}

impl WorkerPorts {
    /// Opens the worker's node, services and ports for payloads of `layout`.
    pub fn open(opts: &WorkerOptions, layout: &ObsLayout) -> Result<WorkerPorts, TransportError> {
        let k = opts.worker_id;
        let node = open_node(&opts.run_id, &format!("worker-{k}-g{}", opts.generation))?;
        let obs = open_obs_service(&node, &opts.run_id, k)?;
        let act = open_act_service(&node, &opts.run_id, k)?;
        let act_ready_service = open_act_ready(&node, &opts.run_id, k)?;
        // Subscribe to actions before any observation goes out, so no answer can be missed.
        let subscriber = act
            .subscriber_builder()
            .buffer_size(qos::ACT_SUBSCRIBER_BUFFER)
            .create()
            .map_err(ipc("creating the action subscriber"))?;
        let act_ready =
            act_ready_service.listener_builder().create().map_err(ipc("creating the act_ready listener"))?;
        let publisher = obs
            .publisher_builder()
            .initial_max_slice_len(layout.total_len as usize)
            .max_loaned_samples(qos::OBS_MAX_LOANED)
            .create()
            .map_err(ipc("creating the observation publisher"))?;
        let deadline = Instant::now() + opts.connect_timeout;
        let obs_ready = open_obs_ready(&node, &opts.run_id, deadline)?
            .notifier_builder()
            .create()
            .map_err(ipc("creating the obs_ready notifier"))?;
        Ok(WorkerPorts { obs, act, publisher, subscriber, obs_ready, act_ready, _node: node })
    }

    /// Sends an observation made elsewhere: a bridge forwarding a remote worker's message
    /// (`orchestrator up --listen`) into the learner's shared memory.
    pub fn forward(&self, header: &ObsHeader, payload: &[u8]) -> Result<(), TransportError> {
        let mut sample =
            self.publisher.loan_slice_uninit(payload.len()).map_err(ipc("loaning an observation sample"))?;
        for (dst, &b) in sample.payload_mut().iter_mut().zip(payload) {
            dst.write(b);
        }
        *sample.user_header_mut() = *header;
        // SAFETY: every byte of the payload was written just above.
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(ipc("sending an observation"))?;
        let _ = self.obs_ready.notify();
        // A subscriber that connected late gets the history sample.
        let _ = self.publisher.update_connections();
        Ok(())
    }

    /// The next action message on this worker's service, whichever step or generation it
    /// answers (non-blocking; a bridge forwards it as it is).
    pub fn try_action(&self) -> Result<Option<ActionMsg>, TransportError> {
        Ok(self.subscriber.receive().map_err(ipc("receiving actions"))?.map(|s| *s.payload()))
    }

    /// The event the learner raises with each action for this worker: a bridge waits on it in
    /// a wait set beside its other sources (drain it with `try_wait` before `try_action`).
    pub fn action_events(&self) -> &Listener<IpcService> {
        &self.act_ready
    }

    /// Whether the learner is there (subscribed to this worker's observations).
    pub fn learner_attached(&self) -> bool {
        self.obs.dynamic_config().number_of_subscribers() > 0
    }

    /// Waits until the learner subscribes to observations and publishes actions.
    fn wait_for_learner(&self, opts: &WorkerOptions) -> Result<Option<Signal>, TransportError> {
        let start = Instant::now();
        loop {
            if let Some(sig) = process::termination_signal() {
                return Ok(Some(sig));
            }
            let subs = self.obs.dynamic_config().number_of_subscribers();
            let pubs = self.act.dynamic_config().number_of_publishers();
            if subs >= 1 && pubs >= 1 {
                return Ok(None);
            }
            if start.elapsed() > opts.connect_timeout {
                return Err(TransportError::NoLearner {
                    service: service::obs(&opts.run_id, opts.worker_id),
                    secs: opts.connect_timeout.as_secs(),
                });
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Loans a sample, lets the stepper write the observation into it in place (reset when
    /// `actions` is `None`, else step), stamps the header, sends it.
    fn send_observation(
        &self,
        header: ObsHeader,
        stepper: &mut dyn Stepper,
        actions: Option<&[u8]>,
        timing: &mut WorkerTiming,
    ) -> Result<(), TransportError> {
        let t0 = Instant::now();
        let render_before = stepper.render_ns();
        let len = header.layout.total_len as usize;
        let mut sample = self.publisher.loan_slice_uninit(len).map_err(ipc("loaning an observation sample"))?;
        let t1 = Instant::now();
        {
            let payload = sample.payload_mut();
            // SAFETY: the payload lies in the publisher's shared-memory data segment, which is
            // mapped memory and so always holds initialised bytes (zeros when fresh, an older
            // observation when reused); u8 has no invalid values. Viewing it as `[u8]` lets the
            // stepper write the observation once, in place.
            let bytes = unsafe { std::slice::from_raw_parts_mut(payload.as_mut_ptr() as *mut u8, payload.len()) };
            match actions {
                None => stepper.reset(bytes),
                Some(a) => stepper.step(a, bytes),
            }
            .map_err(TransportError::Env)?;
        }
        let t2 = Instant::now();
        let render = stepper.render_ns().saturating_sub(render_before);
        timing.render_ns += render;
        timing.sim_ns += nanos(t2 - t1).saturating_sub(render);
        *sample.user_header_mut() = ObsHeader { finished: stepper.finished() as u32, ..header };
        // SAFETY: see above; every byte of the payload is initialised.
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(ipc("sending an observation"))?;
        // A failed wake-up only delays the learner until its next timeout; not fatal.
        let _ = self.obs_ready.notify();
        timing.send_ns += nanos(t1 - t0) + nanos(t2.elapsed());
        Ok(())
    }

    /// Waits for the answer to observation `step` of this generation. Stale answers (another
    /// step or generation) are dropped. `None` when a termination signal arrived.
    fn wait_for_action(&self, opts: &WorkerOptions, step: u64) -> Result<Option<ActionMsg>, TransportError> {
        let mut since_check = Instant::now();
        loop {
            while let Some(sample) = self.subscriber.receive().map_err(ipc("receiving actions"))? {
                let m = *sample.payload();
                let mine = m.magic == ACT_MAGIC && m.worker_id == opts.worker_id && m.generation == opts.generation;
                if mine && (m.step == step || m.command == command::SHUTDOWN) {
                    return Ok(Some(m));
                }
            }
            if let Some(_sig) = process::termination_signal() {
                return Ok(None);
            }
            // Wakes on the learner's notification, a signal (EINTR) or the timeout.
            let _ = self.act_ready.timed_wait(|_| {}, Duration::from_millis(100));
            // Delivers the history sample to a subscriber that connected late.
            let _ = self.publisher.update_connections();
            if since_check.elapsed() > opts.learner_check_after {
                if self.act.dynamic_config().number_of_publishers() == 0 {
                    return Err(TransportError::LearnerGone(service::act(&opts.run_id, opts.worker_id)));
                }
                since_check = Instant::now();
            }
        }
    }
}

/// The worker loop: reset, send, wait for actions, step, send, ... until `SHUTDOWN` or a
/// termination signal. Every observation is written once, by the stepper, into the loaned
/// shared-memory sample.
pub fn serve(stepper: &mut dyn Stepper, opts: &WorkerOptions) -> Result<Exit, TransportError> {
    let layout = stepper.layout();
    let e = stepper.num_envs();
    if e > shm_schema::MAX_ENVS {
        return Err(TransportError::Env(anyhow::anyhow!("{e} envs per worker; at most {}", shm_schema::MAX_ENVS)));
    }
    let ports = WorkerPorts::open(opts, &layout)?;
    if let Some(sig) = ports.wait_for_learner(opts)? {
        return Ok(Exit::Terminated(sig));
    }
    let header = ObsHeader {
        magic: OBS_MAGIC,
        version: SCHEMA_VERSION,
        worker_id: opts.worker_id,
        generation: opts.generation,
        step: 0,
        num_envs: e as u32,
        width: opts.width,
        height: opts.height,
        gesture_frames: GESTURE_FRAMES as u32,
        gesture_dims: GESTURE_DIMS as u32,
        finished: 0,
        layout,
        timing: WorkerTiming::default(),
    };
    let mut actions = vec![0u8; e];
    let mut step = 0u64;
    let mut timing = WorkerTiming::default();
    loop {
        if let Some(sig) = process::termination_signal() {
            return Ok(Exit::Terminated(sig));
        }
        let h = ObsHeader { step, timing, ..header };
        ports.send_observation(h, stepper, if step == 0 { None } else { Some(&actions) }, &mut timing)?;
        let waiting = Instant::now();
        let answer = ports.wait_for_action(opts, step)?;
        timing.wait_ns += nanos(waiting.elapsed());
        match answer {
            None => return Ok(Exit::Terminated(process::termination_signal().unwrap_or(Signal::SIGTERM))),
            Some(m) if m.command == command::SHUTDOWN => return Ok(Exit::Shutdown),
            Some(m) => actions.copy_from_slice(&m.actions[..e]),
        }
        step += 1;
    }
}

fn nanos(d: Duration) -> u64 {
    d.as_nanos().min(u64::MAX as u128) as u64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stepper::SyntheticStepper;
    use shm_schema::{ObsShape, ObsView};

    fn shm_files(prefix: &str) -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.starts_with(prefix))
                    .collect()
            })
            .unwrap_or_default()
    }

    /// A learner in a few lines: answers every observation, checks the counters, then sends
    /// SHUTDOWN; the worker loop (with the synthetic stepper) runs in a thread.
    #[test]
    fn worker_loop_answers_in_lockstep_and_shuts_down_clean() {
        let run = format!("t{}-loop", std::process::id());
        let node = open_node(&run, "test-learner").unwrap();
        let ready = create_obs_ready(&node, &run, 1).unwrap();
        let listener = ready.listener_builder().create().unwrap();
        // no file of the run in /dev/shm is open to other users (iceoryx2 makes its node
        // counter 0666)
        for f in shm_files(&service::prefix(&run)) {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(format!("/dev/shm/{f}")).unwrap().permissions().mode();
            assert_eq!(mode & 0o077, 0, "/dev/shm/{f} has mode {mode:o}");
        }
        let obs = open_obs_service(&node, &run, 0).unwrap();
        let act = open_act_service(&node, &run, 0).unwrap();
        let act_ready = open_act_ready(&node, &run, 0).unwrap().notifier_builder().create().unwrap();
        // The worker must not send before this subscriber exists: create it a little later.
        let opts = WorkerOptions::new(&run, 0, 3, 16, 12);
        let worker = std::thread::spawn({
            let opts = opts.clone();
            move || {
                let mut s = SyntheticStepper::new(0, 2, 16, 12, None, false);
                serve(&mut s, &opts)
            }
        });
        std::thread::sleep(Duration::from_millis(200));
        let sub = obs
            .subscriber_builder()
            .buffer_size(qos::OBS_SUBSCRIBER_BUFFER)
            .history_request(qos::OBS_HISTORY)
            .create()
            .unwrap();
        let publisher = act.publisher_builder().create().unwrap();
        let shape = ObsShape::new(2, 16, 12);
        let mut last_timing = WorkerTiming::default();
        for t in 0..25u64 {
            let sample = loop {
                if let Some(s) = sub.receive().unwrap() {
                    break s;
                }
                listener.timed_wait(|_| {}, Duration::from_secs(5)).unwrap();
            };
            let h = *sample.user_header();
            assert_eq!((h.magic, h.worker_id, h.generation, h.step), (OBS_MAGIC, 0, 3, t));
            // the profile's sums only grow; the synthetic stepper renders nothing
            let g = h.timing;
            assert!(
                g.sim_ns >= last_timing.sim_ns && g.send_ns >= last_timing.send_ns && g.wait_ns >= last_timing.wait_ns
            );
            assert_eq!(g.render_ns, 0);
            if t > 0 {
                assert!(g.sim_ns > 0 && g.wait_ns > 0, "{g:?}");
            }
            last_timing = g;
            let view = ObsView::new(ObsShape::of_header(&h).unwrap(), sample.payload()).unwrap();
            assert_eq!(*view.shape(), shape);
            assert!(view.records().iter().all(|r| r.env_step == t));
            let cmd = if t == 24 { command::SHUTDOWN } else { command::STEP };
            let msg =
                ActionMsg { worker_id: 0, generation: 3, command: cmd, step: t, num_envs: 2, ..Default::default() };
            // a stale answer (older generation) first: the worker must ignore it
            publisher.send_copy(ActionMsg { generation: 2, command: command::SHUTDOWN, ..msg }).unwrap();
            publisher.send_copy(msg).unwrap();
            act_ready.notify().unwrap();
        }
        assert_eq!(worker.join().unwrap().unwrap(), Exit::Shutdown);
        drop((sub, publisher, act_ready, listener, ready, obs, act));
        drop(node);
        assert_eq!(end_run_domain(&run).unwrap(), Vec::<std::path::PathBuf>::new(), "iceoryx2 left files behind");
        assert_eq!(shm_files(&service::prefix(&run)), Vec::<String>::new());
    }

    #[test]
    fn without_a_learner_the_worker_gives_up_with_a_clear_error() {
        let run = format!("t{}-alone", std::process::id());
        let node = open_node(&run, "test-learner").unwrap();
        let _ready = create_obs_ready(&node, &run, 1).unwrap();
        let mut opts = WorkerOptions::new(&run, 5, 0, 16, 16);
        opts.connect_timeout = Duration::from_millis(300);
        let mut s = SyntheticStepper::new(5, 1, 16, 16, None, false);
        let err = serve(&mut s, &opts).unwrap_err();
        assert!(matches!(err, TransportError::NoLearner { .. }), "{err}");
        assert!(err.to_string().contains("obs/5"), "{err}");
        drop((_ready, node));
        assert_eq!(end_run_domain(&run).unwrap(), Vec::<std::path::PathBuf>::new());
    }
}
