//! The learner's side of the farm over iceoryx2: one subscriber (observations) and one
//! publisher (actions) per worker, a listener that wakes when any worker sent, and a notifier
//! per worker to wake it when its actions are out. Services are opened with the same functions
//! the workers use (`farm::transport`), so both sides agree on every setting.
//!
//! iceoryx2 stays in this file: what it receives leaves as an [`ObsMessage`], which holds the
//! sample (in shared memory, zero copy) and shows only the schema's types.
//!
//! A worker host's bridge (`orchestrator workers`) stands in for the learner towards its local
//! workers with the same ports ([`LearnerPorts::open_slots`]).

use std::time::Duration;

use crate::transport::{self as wt, ActService, EventService, IpcService, ObsService, TransportError};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use shm_schema::{ActionMsg, ObsHeader, ObsShape, ObsView, ViewError, qos};

/// One observation message of a worker, read in place: the sample stays borrowed from the
/// worker's pool in shared memory until this is dropped (then the worker may reuse it).
pub struct ObsMessage {
    sample: Sample<IpcService, [u8], ObsHeader>,
}

impl ObsMessage {
    pub fn header(&self) -> &ObsHeader {
        self.sample.user_header()
    }

    /// The raw payload (records, frames, gestures at the offsets of the header's layout).
    pub fn payload(&self) -> &[u8] {
        self.sample.payload()
    }

    /// Records, frames and gestures as typed slices, in the shape the header announces; an error
    /// when the header's layout or the payload's size does not hold up.
    pub fn view(&self) -> Result<ObsView<'_>, ViewError> {
        ObsShape::of_header(self.header()).and_then(|s| ObsView::new(s, self.payload()))
    }
}

impl std::fmt::Debug for ObsMessage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObsMessage").field("header", self.header()).finish_non_exhaustive()
    }
}

struct WorkerLink {
    obs: ObsService,
    _act: ActService,
    subscriber: Subscriber<IpcService, [u8], ObsHeader>,
    publisher: Publisher<IpcService, ActionMsg, ()>,
    act_ready: Notifier<IpcService>,
    _act_ready_service: EventService,
}

/// The learner's ports for `workers` workers of one run.
pub struct LearnerPorts {
    links: Vec<WorkerLink>,
    obs_ready: Listener<IpcService>,
    _obs_ready_service: EventService,
    // Dropped last.
    _node: Node<IpcService>,
}

fn ipc<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> TransportError + '_ {
    move |e| TransportError::Ipc { what: what.into(), detail: format!("{e:?}") }
}

impl LearnerPorts {
    /// Creates the run's `obs_ready` event (sized for `workers`), then subscribes to every
    /// worker's observations and publishes its actions. Workers wait for exactly these ports
    /// before they send anything (the start handshake).
    pub fn open(run_id: &str, workers: usize) -> Result<LearnerPorts, TransportError> {
        LearnerPorts::open_slots(run_id, "learner", &(0..workers as u32).collect::<Vec<_>>())
    }

    /// [`LearnerPorts::open`] for the workers `slots` only (a worker host's share of the
    /// learner's slots); link `k` of the result is worker `slots[k]`.
    pub fn open_slots(run_id: &str, node_name: &str, slots: &[u32]) -> Result<LearnerPorts, TransportError> {
        let workers = slots.len();
        let node = wt::open_node(run_id, node_name)?;
        let obs_ready_service = wt::create_obs_ready(&node, run_id, workers)?;
        let obs_ready =
            obs_ready_service.listener_builder().create().map_err(ipc("creating the obs_ready listener"))?;
        let mut links = Vec::with_capacity(workers);
        for &k in slots {
            let obs = wt::open_obs_service(&node, run_id, k)?;
            let act = wt::open_act_service(&node, run_id, k)?;
            let act_ready_service = wt::open_act_ready(&node, run_id, k)?;
            let subscriber = obs
                .subscriber_builder()
                .buffer_size(qos::OBS_SUBSCRIBER_BUFFER)
                .history_request(qos::OBS_HISTORY)
                .create()
                .map_err(ipc("creating an observation subscriber"))?;
            let publisher = act.publisher_builder().create().map_err(ipc("creating an action publisher"))?;
            let act_ready =
                act_ready_service.notifier_builder().create().map_err(ipc("creating an act_ready notifier"))?;
            links.push(WorkerLink {
                obs,
                _act: act,
                subscriber,
                publisher,
                act_ready,
                _act_ready_service: act_ready_service,
            });
        }
        Ok(LearnerPorts { links, obs_ready, _obs_ready_service: obs_ready_service, _node: node })
    }

    pub fn workers(&self) -> usize {
        self.links.len()
    }

    /// The next observation worker `k` sent, if any (non-blocking).
    pub fn receive(&self, k: usize) -> Result<Option<ObsMessage>, TransportError> {
        let sample = self.links[k].subscriber.receive().map_err(ipc("receiving an observation"))?;
        Ok(sample.map(|sample| ObsMessage { sample }))
    }

    /// Publishes `msg` to worker `k` and wakes it.
    pub fn send(&self, k: usize, msg: ActionMsg) -> Result<(), TransportError> {
        let link = &self.links[k];
        link.publisher.send_copy(msg).map_err(ipc("sending actions"))?;
        let _ = link.act_ready.notify();
        Ok(())
    }

    /// Sleeps until some worker announces an observation, a signal arrives, or `timeout` passes.
    pub fn wait(&self, timeout: Duration) {
        // Errors here are interruptions (a signal); the caller's loop looks at the flags.
        let _ = self.obs_ready.timed_wait(|_| {}, timeout);
    }

    /// The event every worker raises with each observation: a bridge waits on it in a wait set
    /// beside its other sources (drain it with `try_wait` before `receive`).
    pub fn observation_events(&self) -> &Listener<IpcService> {
        &self.obs_ready
    }

    /// Whether worker `k` currently has a publisher on its observation service (a live
    /// process, or a killed one whose ports are not yet cleaned up).
    pub fn worker_attached(&self, k: usize) -> bool {
        self.links[k].obs.dynamic_config().number_of_publishers() > 0
    }
}
