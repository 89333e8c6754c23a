//! A worker host's side (`orchestrator workers`): stands in for the learner towards the host's
//! own workers, sends their observations to the learner host and hands its actions back.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use farm::learner_ports::LearnerPorts;
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use super::bridge::{BridgeCounts, BridgeThread, Doorbell, wait, wait_set};
use super::join::JoinGrant;
use super::wire::{Codec, act_key_all, decode_act, encode_obs, host_key, learner_key, obs_key, reopen_key, slot_of};

/// How long a host waits for a learner that said it reopens its listener: longer than the
/// learner's own grace for hosts to come back (`learner_bridge::REJOIN_GRACE`).
const REOPEN_GRACE: Duration = Duration::from_secs(30);
/// How long a host waits for a learner whose presence vanished unannounced before it asks
/// whether the learner is there (Zenoh may replace a host's first link by a second one it was
/// opening at the same time), and ends if not.
const LINK_GRACE: Duration = Duration::from_secs(5);

/// The worker host's side: stands in for the learner towards its local workers.
pub struct HostOptions {
    pub run_id: String,
    /// This host's shared-memory domain (its workers' run id).
    pub local_run_id: String,
    pub grant: JoinGrant,
    pub workers: u32,
    pub codec: Codec,
}

/// A thread of `orchestrator workers`.
pub struct HostBridge {
    learner_gone: Arc<AtomicBool>,
    thread: BridgeThread,
    pub counts: Arc<BridgeCounts>,
}

impl HostBridge {
    pub fn start(session: zenoh::Session, o: HostOptions) -> anyhow::Result<HostBridge> {
        let learner_gone = Arc::new(AtomicBool::new(false));
        let counts = Arc::new(BridgeCounts::default());
        // iceoryx2 ports stay in the thread that made them; it says when they exist (the
        // workers, started after, wait for exactly these).
        let (opened, ready) = std::sync::mpsc::channel();
        let thread = BridgeThread::spawn("host bridge", {
            let (gone, counts) = (learner_gone.clone(), counts.clone());
            move |stop| {
                let slots: Vec<u32> = (o.grant.first_slot..o.grant.first_slot + o.workers).collect();
                let ports = match LearnerPorts::open_slots(&o.local_run_id, "bridge", &slots) {
                    Ok(p) => p,
                    Err(e) => {
                        let _ = opened.send(Err(e.to_string()));
                        return Ok(());
                    }
                };
                let _ = opened.send(Ok(()));
                host_side(session, o, ports, stop, &gone, &counts)
            }
        })?;
        match ready.recv() {
            Ok(Ok(())) => Ok(HostBridge { learner_gone, thread, counts }),
            Ok(Err(e)) => anyhow::bail!("opening the workers' ports: {e}"),
            Err(_) => anyhow::bail!("the host bridge ended before opening its ports"),
        }
    }

    /// The learner's host went away (its liveliness token vanished).
    pub fn learner_gone(&self) -> bool {
        self.learner_gone.load(Ordering::Relaxed)
    }

    pub fn ended(&self) -> bool {
        self.thread.ended()
    }

    pub fn finish(self) -> anyhow::Result<()> {
        self.thread.finish()
    }
}

/// Whether the learner's liveliness token answers a query now.
fn learner_alive(session: &zenoh::Session, run_id: &str) -> bool {
    let Ok(replies) = session.liveliness().get(learner_key(run_id)).timeout(Duration::from_secs(2)).wait() else {
        return false;
    };
    std::iter::from_fn(|| replies.recv().ok()).any(|r| r.result().is_ok())
}

fn host_side(
    session: zenoh::Session,
    o: HostOptions,
    ports: LearnerPorts,
    stop: &AtomicBool,
    gone: &AtomicBool,
    counts: &BridgeCounts,
) -> anyhow::Result<()> {
    let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
    let _alive = session
        .liveliness()
        .declare_token(host_key(&o.run_id, o.grant.token))
        .wait()
        .map_err(zerr("liveliness token"))?;
    let learner =
        session.liveliness().declare_subscriber(learner_key(&o.run_id)).wait().map_err(zerr("learner liveliness"))?;
    let bell = Doorbell::new()?;
    let (_acts, acts) = bell.subscribe(&session, act_key_all(&o.run_id))?;
    let (_reopen, reopen) = bell.subscribe(&session, reopen_key(&o.run_id))?;
    // Wakes on an answer from the learner (the bell) or an observation of a local worker.
    let ws = wait_set()?;
    let _bell = ws.attach_notification(&bell.door).map_err(|e| anyhow::anyhow!("watching the bell: {e:?}"))?;
    let _observations = ws
        .attach_notification(ports.observation_events())
        .map_err(|e| anyhow::anyhow!("watching the workers: {e:?}"))?;
    let mut side = Side::new(&session, &o, counts);
    while !stop.load(Ordering::Relaxed) {
        wait(&ws)?;
        bell.answer();
        let _ = ports.observation_events().try_wait(|_| {});
        while reopen.try_recv().is_ok() {
            side.told = true;
        }
        while let Ok(Some(s)) = learner.try_recv() {
            side.learner_presence(s.kind());
        }
        if side.learner_lost() {
            gone.store(true, Ordering::Relaxed);
        }
        side.send_observations(&ports)?;
        side.resend_unanswered()?;
        while let Ok(s) = acts.try_recv() {
            side.deliver(&s, &ports)?;
        }
    }
    Ok(())
}

/// The host's side of the bridge between its rounds: whether the learner is there, and what
/// went through each slot last.
struct Side<'a> {
    session: &'a zenoh::Session,
    o: &'a HostOptions,
    counts: &'a BridgeCounts,
    /// Since when the learner is away, how long it may be (longer after it said it reopens its
    /// listener with new trust), and since when it is back.
    away: Option<(Instant, Duration)>,
    back: Option<Instant>,
    /// The learner said it reopens its listener.
    told: bool,
    /// Per slot: the last observation sent (its generation, step and bytes) and whether an
    /// answer came; the newest answer delivered.
    last_obs: Vec<Option<(u32, u64, Vec<u8>)>>,
    answered: Vec<bool>,
    last_act: Vec<Option<(u32, u64)>>,
    resent: Instant,
}

impl<'a> Side<'a> {
    fn new(session: &'a zenoh::Session, o: &'a HostOptions, counts: &'a BridgeCounts) -> Side<'a> {
        let n = o.workers as usize;
        Side {
            session,
            o,
            counts,
            away: None,
            back: None,
            told: false,
            last_obs: vec![None; n],
            answered: vec![true; n],
            last_act: vec![None; n],
            resent: Instant::now(),
        }
    }

    fn put(&self, k: usize, bytes: Vec<u8>) -> anyhow::Result<()> {
        self.session
            .put(obs_key(&self.o.run_id, self.o.grant.first_slot + k as u32), bytes)
            .congestion_control(CongestionControl::Block)
            // not batched: every step waits for this message
            .express(true)
            .wait()
            .map_err(|e| anyhow::anyhow!("sending an observation: {e}"))
    }

    fn learner_presence(&mut self, kind: SampleKind) {
        match (kind, self.told) {
            (SampleKind::Delete, true) => self.away = Some((Instant::now(), REOPEN_GRACE)),
            (SampleKind::Delete, false) => self.away = Some((Instant::now(), LINK_GRACE)),
            // back: messages in flight may have been lost with the link
            (SampleKind::Put, _) => (self.away, self.back, self.told) = (None, Some(Instant::now()), false),
        }
    }

    /// Whether the learner has been away past its grace (and is not there when asked).
    fn learner_lost(&mut self) -> bool {
        let Some((t, grace)) = self.away else { return false };
        if t.elapsed() <= grace {
            return false;
        }
        self.away = None;
        // A link Zenoh replaced can report the learner gone while it is there: ask.
        if learner_alive(self.session, &self.o.run_id) {
            self.back = Some(Instant::now());
            return false;
        }
        if grace == REOPEN_GRACE {
            eprintln!(
                "[workers] the learner's host did not take this host back within {} s of reopening its listener (its certificate revoked?)",
                REOPEN_GRACE.as_secs()
            );
        }
        true
    }

    /// Sends each local worker's observations to the learner's host.
    fn send_observations(&mut self, ports: &LearnerPorts) -> anyhow::Result<()> {
        for k in 0..self.o.workers as usize {
            while let Some(m) = ports.receive(k)? {
                let bytes = encode_obs(self.o.codec, self.o.grant.token, m.header(), m.payload());
                let len = bytes.len();
                self.put(k, bytes.clone())?;
                self.last_obs[k] = Some((m.header().generation, m.header().step, bytes));
                self.answered[k] = false;
                self.counts.observations.fetch_add(1, Ordering::Relaxed);
                self.counts.bytes.fetch_add(len as u64, Ordering::Relaxed);
            }
        }
        Ok(())
    }

    /// Messages in flight when a link dropped are lost: after the learner is back, a slot still
    /// waiting sends its last observation again (each second, for ten), and the learner
    /// forwards it if it never came, or answers it again if its answer was what got lost.
    fn resend_unanswered(&mut self) -> anyhow::Result<()> {
        let Some(t) = self.back else { return Ok(()) };
        if t.elapsed() > Duration::from_secs(10) {
            self.back = None;
        } else if t.elapsed() > Duration::from_millis(500) && self.resent.elapsed() > Duration::from_secs(1) {
            self.resent = Instant::now();
            for k in (0..self.o.workers as usize).filter(|&k| !self.answered[k]) {
                if let Some((_, _, bytes)) = &self.last_obs[k] {
                    self.put(k, bytes.clone())?;
                }
            }
        }
        Ok(())
    }

    /// Hands an action for one of this host's slots to its worker, once.
    fn deliver(&mut self, s: &zenoh::sample::Sample, ports: &LearnerPorts) -> anyhow::Result<()> {
        let (first, token) = (self.o.grant.first_slot, self.o.grant.token);
        let slot = slot_of(s.key_expr().as_str());
        match (slot, decode_act(&s.payload().to_bytes())) {
            (Some(k), Some((t, m))) if t == token && (first..first + self.o.workers).contains(&k) => {
                let i = (k - first) as usize;
                // an answer sent again after a reopen that had already come
                if self.last_act[i].is_some_and(|(g, step)| g == m.generation && m.step <= step) {
                    return Ok(());
                }
                self.last_act[i] = Some((m.generation, m.step));
                self.answered[i] =
                    self.last_obs[i].as_ref().is_none_or(|(g, step, _)| *g == m.generation && *step <= m.step);
                ports.send(i, m)?;
                self.counts.actions.fetch_add(1, Ordering::Relaxed);
            }
            (Some(k), _) if !(first..first + self.o.workers).contains(&k) => {} // another host's slot
            _ => {
                self.counts.refused.fetch_add(1, Ordering::Relaxed);
            }
        }
        Ok(())
    }
}
