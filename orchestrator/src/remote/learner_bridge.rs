//! The learner host's side (`up --listen`): answers joins with free slots, stands in for each
//! remote slot's worker in the run's shared memory, forwards remote observations to the learner
//! and the learner's actions back.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use farm::transport::{WorkerOptions, WorkerPorts};
use shm_schema::ObsLayout;
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use super::bridge::{BridgeCounts, BridgeThread, Doorbell, wait, wait_set};
use super::join::{JOIN_KEY, JoinGrant, JoinRequest, proof, random_hex};
use super::session::session;
use super::wire::{act_key, decode_obs, encode_act, learner_key, slot_of};

/// The learner host's side of a multi-host run.
pub struct ListenOptions {
    pub endpoint: String,
    pub run_id: String,
    pub secret: String,
    /// The learner's slots reserved for worker hosts.
    pub first_slot: u32,
    pub slots: u32,
    pub config_toml: String,
    pub manifest_digest: String,
    pub layout: ObsLayout,
    pub width: u32,
    pub height: u32,
}

/// A thread of `up --listen`: answers joins, forwards remote observations into the run's shared
/// memory and the learner's answers back.
pub struct LearnerBridge {
    thread: BridgeThread,
    pub counts: Arc<BridgeCounts>,
}

impl LearnerBridge {
    pub fn start(o: ListenOptions) -> anyhow::Result<LearnerBridge> {
        let session = session(std::slice::from_ref(&o.endpoint), &[])?;
        let counts = Arc::new(BridgeCounts::default());
        let thread = BridgeThread::spawn("learner bridge", {
            let counts = counts.clone();
            move |stop| learner_side(session, o, stop, &counts)
        })?;
        Ok(LearnerBridge { thread, counts })
    }

    /// Stops the thread; its error, if it ended on one.
    pub fn finish(self) -> anyhow::Result<()> {
        self.thread.finish()
    }

    /// Whether the thread has ended (on an error: `finish` returns it).
    pub fn ended(&self) -> bool {
        self.thread.ended()
    }
}

/// Slots held by hosts: the grant token per remote slot.
struct Holders {
    first_slot: u32,
    held: Vec<Option<u64>>,
    joins: u32,
}

impl Holders {
    /// The first `n` consecutive free slots, now held by `token`.
    fn take(&mut self, n: u32, token: u64) -> Option<u32> {
        let n = n as usize;
        if n == 0 || n > self.held.len() {
            return None;
        }
        let start = (0..=self.held.len() - n).find(|&i| self.held[i..i + n].iter().all(Option::is_none))?;
        for h in &mut self.held[start..start + n] {
            *h = Some(token);
        }
        Some(self.first_slot + start as u32)
    }

    fn release(&mut self, token: u64) -> usize {
        let mut n = 0;
        for h in self.held.iter_mut().filter(|h| **h == Some(token)) {
            *h = None;
            n += 1;
        }
        n
    }

    fn holder(&self, slot: u32) -> Option<u64> {
        self.held.get(slot.checked_sub(self.first_slot)? as usize).copied().flatten()
    }
}

fn learner_side(
    session: zenoh::Session,
    o: ListenOptions,
    stop: &AtomicBool,
    counts: &BridgeCounts,
) -> anyhow::Result<()> {
    let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
    let _alive = session.liveliness().declare_token(learner_key(&o.run_id)).wait().map_err(zerr("liveliness token"))?;
    let joins = session.declare_queryable(JOIN_KEY).wait().map_err(zerr("join queryable"))?;
    let hosts = session
        .liveliness()
        .declare_subscriber(format!("gesthor/{}/host/*", o.run_id))
        .wait()
        .map_err(zerr("host liveliness"))?;
    let bell = Doorbell::new()?;
    let (_obs, obs) = bell.subscribe(&session, format!("gesthor/{}/obs/*", o.run_id))?;
    // One stand-in worker per remote slot, in the learner's shared memory. Its ports need the
    // learner's obs_ready, made when the learner starts: ask again each second until then (or
    // until the run ends, should the learner never start).
    let open = || -> anyhow::Result<Vec<WorkerPorts>> {
        (o.first_slot..o.first_slot + o.slots)
            .map(|k| {
                let mut w = WorkerOptions::new(&o.run_id, k, 0, o.width, o.height);
                w.connect_timeout = Duration::from_secs(1);
                WorkerPorts::open(&w, &o.layout).with_context(|| format!("opening remote slot {k}"))
            })
            .collect()
    };
    let ports = loop {
        match open() {
            Ok(p) => break p,
            Err(_) if !stop.load(Ordering::Relaxed) => continue,
            Err(_) => return Ok(()),
        }
    };
    // Wakes on a remote observation (the bell) or an answer of the learner (its event per slot).
    let ws = wait_set()?;
    let _bell = ws.attach_notification(&bell.door).map_err(|e| anyhow::anyhow!("watching the bell: {e:?}"))?;
    let _answers = ports
        .iter()
        .map(|p| ws.attach_notification(p.action_events()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("watching the learner's answers: {e:?}"))?;
    let mut holders = Holders { first_slot: o.first_slot, held: vec![None; o.slots as usize], joins: 0 };
    while !stop.load(Ordering::Relaxed) {
        wait(&ws)?;
        bell.answer();
        while let Ok(Some(q)) = joins.try_recv() {
            let payload = q.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
            match grant(&o, &mut holders, &payload) {
                Ok((g, req)) => {
                    eprintln!(
                        "[up] worker host {} joined: {} workers as slots {}..{}",
                        req.host,
                        req.workers,
                        g.first_slot,
                        g.first_slot + req.workers - 1
                    );
                    let _ = q.reply(JOIN_KEY, serde_json::to_vec(&g)?).wait();
                }
                Err(why) => {
                    eprintln!("[up] refused a worker host: {why}");
                    let _ = q.reply_err(why.into_bytes()).wait();
                }
            }
        }
        while let Ok(Some(s)) = hosts.try_recv() {
            let token = s.key_expr().as_str().rsplit('/').next().and_then(|t| u64::from_str_radix(t, 16).ok());
            if let (SampleKind::Delete, Some(t)) = (s.kind(), token) {
                let n = holders.release(t);
                if n > 0 {
                    eprintln!("[up] a worker host left: {n} remote slot(s) free until a host joins again");
                }
            }
        }
        while let Ok(s) = obs.try_recv() {
            let bytes = s.payload().to_bytes();
            match (slot_of(s.key_expr().as_str()), decode_obs(&bytes)) {
                (Some(k), Ok((token, header, payload)))
                    if holders.holder(k) == Some(token)
                        && header.worker_id == k
                        && payload.len() == o.layout.total_len as usize =>
                {
                    ports[(k - o.first_slot) as usize].forward(&header, &payload)?;
                    counts.observations.fetch_add(1, Ordering::Relaxed);
                    counts.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
                }
                _ => {
                    counts.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        for (i, p) in ports.iter().enumerate() {
            let k = o.first_slot + i as u32;
            let _ = p.action_events().try_wait(|_| {});
            while let Some(m) = p.try_action()? {
                if let Some(token) = holders.holder(k) {
                    session
                        .put(act_key(&o.run_id, k), encode_act(token, &m))
                        .congestion_control(CongestionControl::Block)
                        // not batched: every step waits for this message
                        .express(true)
                        .wait()
                        .map_err(zerr("sending actions"))?;
                    counts.actions.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
    Ok(())
}

/// Checks a join request and grants slots, or says why not.
fn grant(o: &ListenOptions, holders: &mut Holders, payload: &[u8]) -> Result<(JoinGrant, JoinRequest), String> {
    let req: JoinRequest = serde_json::from_slice(payload).map_err(|e| format!("a malformed join request ({e})"))?;
    if req.run_id != o.run_id {
        return Err(format!("host {} asked for run {}, this is run {}", req.host, req.run_id, o.run_id));
    }
    if req.proof != proof(&o.secret, "host", &o.run_id, &req.nonce) {
        return Err(format!("host {} does not know this run's secret", req.host));
    }
    let token = u64::from_str_radix(&random_hex(8), 16).expect("hex");
    let first_slot = holders.take(req.workers, token).ok_or_else(|| {
        let free = holders.held.iter().filter(|h| h.is_none()).count();
        format!("host {} asked for {} workers; {free} of {} remote slots are free", req.host, req.workers, o.slots)
    })?;
    holders.joins += 1;
    let g = JoinGrant {
        first_slot,
        // above every generation an earlier host (or restart) used in these slots
        first_generation: holders.joins << 16,
        token,
        config_toml: o.config_toml.clone(),
        manifest_digest: o.manifest_digest.clone(),
        proof: proof(&o.secret, "learner", &o.run_id, &req.nonce),
    };
    Ok((g, req))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_are_granted_in_free_runs_and_freed_by_token() {
        let mut h = Holders { first_slot: 4, held: vec![None; 4], joins: 0 };
        assert_eq!(h.take(2, 1), Some(4));
        assert_eq!(h.take(3, 2), None, "two slots left");
        assert_eq!(h.take(2, 3), Some(6));
        assert_eq!((h.holder(5), h.holder(6), h.holder(3)), (Some(1), Some(3), None));
        assert_eq!(h.release(1), 2);
        assert_eq!(h.take(1, 4), Some(4));
    }

    #[test]
    fn a_join_needs_the_run_and_its_secret() {
        let o = ListenOptions {
            endpoint: String::new(),
            run_id: "r1".into(),
            secret: "s3cret".into(),
            first_slot: 2,
            slots: 2,
            config_toml: "[run]".into(),
            manifest_digest: "d".into(),
            layout: ObsLayout::new(1, 8, 8),
            width: 8,
            height: 8,
        };
        let mut h = Holders { first_slot: 2, held: vec![None; 2], joins: 0 };
        let req = |run: &str, secret: &str| {
            serde_json::to_vec(&JoinRequest {
                run_id: run.into(),
                workers: 1,
                host: "h".into(),
                nonce: "n".into(),
                proof: proof(secret, "host", run, "n"),
            })
            .unwrap()
        };
        assert!(grant(&o, &mut h, &req("r2", "s3cret")).unwrap_err().contains("this is run r1"));
        assert!(grant(&o, &mut h, &req("r1", "guess")).unwrap_err().contains("secret"));
        let (g, _) = grant(&o, &mut h, &req("r1", "s3cret")).unwrap();
        assert_eq!((g.first_slot, g.first_generation), (2, 1 << 16));
        assert_eq!(g.proof, proof("s3cret", "learner", "r1", "n"));
        let (g2, _) = grant(&o, &mut h, &req("r1", "s3cret")).unwrap();
        assert!(g2.first_generation > g.first_generation && g2.first_slot == 3);
    }
}
