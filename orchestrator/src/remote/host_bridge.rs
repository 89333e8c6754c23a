//! A worker host's side (`orchestrator workers`): stands in for the learner towards the host's
//! own workers, sends their observations to the learner host and hands its actions back.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use farm::learner_ports::LearnerPorts;
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use super::bridge::{BridgeCounts, BridgeThread, Doorbell, wait, wait_set};
use super::join::JoinGrant;
use super::wire::{Codec, decode_act, encode_obs, host_key, learner_key, obs_key, slot_of};

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

fn host_side(
    session: zenoh::Session,
    o: HostOptions,
    ports: LearnerPorts,
    stop: &AtomicBool,
    gone: &AtomicBool,
    counts: &BridgeCounts,
) -> anyhow::Result<()> {
    let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
    let token = o.grant.token;
    let _alive =
        session.liveliness().declare_token(host_key(&o.run_id, token)).wait().map_err(zerr("liveliness token"))?;
    let learner =
        session.liveliness().declare_subscriber(learner_key(&o.run_id)).wait().map_err(zerr("learner liveliness"))?;
    let bell = Doorbell::new()?;
    let (_acts, acts) = bell.subscribe(&session, format!("gesthor/{}/act/*", o.run_id))?;
    // Wakes on an answer from the learner (the bell) or an observation of a local worker.
    let ws = wait_set()?;
    let _bell = ws.attach_notification(&bell.door).map_err(|e| anyhow::anyhow!("watching the bell: {e:?}"))?;
    let _observations = ws
        .attach_notification(ports.observation_events())
        .map_err(|e| anyhow::anyhow!("watching the workers: {e:?}"))?;
    let first = o.grant.first_slot;
    while !stop.load(Ordering::Relaxed) {
        wait(&ws)?;
        bell.answer();
        let _ = ports.observation_events().try_wait(|_| {});
        while let Ok(Some(s)) = learner.try_recv() {
            if s.kind() == SampleKind::Delete {
                gone.store(true, Ordering::Relaxed);
            }
        }
        for k in 0..o.workers as usize {
            while let Some(m) = ports.receive(k)? {
                let bytes = encode_obs(o.codec, token, m.header(), m.payload());
                let n = bytes.len();
                session
                    .put(obs_key(&o.run_id, first + k as u32), bytes)
                    .congestion_control(CongestionControl::Block)
                    // not batched: every step waits for this message
                    .express(true)
                    .wait()
                    .map_err(zerr("sending an observation"))?;
                counts.observations.fetch_add(1, Ordering::Relaxed);
                counts.bytes.fetch_add(n as u64, Ordering::Relaxed);
            }
        }
        while let Ok(s) = acts.try_recv() {
            let slot = slot_of(s.key_expr().as_str());
            match (slot, decode_act(&s.payload().to_bytes())) {
                (Some(k), Some((t, m))) if t == token && (first..first + o.workers).contains(&k) => {
                    ports.send((k - first) as usize, m)?;
                    counts.actions.fetch_add(1, Ordering::Relaxed);
                }
                (Some(k), _) if !(first..first + o.workers).contains(&k) => {} // another host's slot
                _ => {
                    counts.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
    Ok(())
}
