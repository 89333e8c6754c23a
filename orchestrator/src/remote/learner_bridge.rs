//! The learner host's side (`up --listen`): answers joins with free slots, stands in for each
//! remote slot's worker in the run's shared memory, forwards remote observations to the learner
//! and the learner's actions back.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use farm::transport::{WorkerOptions, WorkerPorts};
use shm_schema::ObsLayout;
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use super::bridge::{BridgeCounts, BridgeThread, Doorbell, wait, wait_set};
use super::join::{JOIN_KEY, JoinGrant, JoinRequest, proof, random_hex};
use super::session::{Security, session};
use super::wire::{
    act_key, decode_obs, encode_act, host_key_all, learner_key, obs_key_all, reopen_key, slot_of, token_of,
};
use super::{access, certs};

/// The learner host's side of a multi-host run.
pub struct ListenOptions {
    pub endpoint: String,
    /// The run folder of a run over TLS (its `tls/`, `certs`); `None`: plain TCP (`--insecure`).
    pub tls_run: Option<PathBuf>,
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
        let counts = Arc::new(BridgeCounts::default());
        // The first session opens here, so a listener that cannot start is this call's error.
        let (opened, ready) = std::sync::mpsc::channel();
        let thread = BridgeThread::spawn("learner bridge", {
            let counts = counts.clone();
            move |stop| learner_side(o, stop, &counts, opened)
        })?;
        match ready.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => anyhow::bail!("{e}"),
            Err(_) => return Err(thread.finish().err().unwrap_or_else(|| anyhow::anyhow!("the learner bridge ended"))),
        }
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

    /// The tokens holding slots now.
    fn tokens(&self) -> Vec<u64> {
        let mut t: Vec<u64> = self.held.iter().flatten().copied().collect();
        t.sort_unstable();
        t.dedup();
        t
    }

    fn holder(&self, slot: u32) -> Option<u64> {
        self.held.get(slot.checked_sub(self.first_slot)? as usize).copied().flatten()
    }
}

/// The learner's Zenoh side: opened at the start, and again whenever the hosts it trusts change
/// (Zenoh reads its TLS trust and access rules when a session opens).
struct Listener {
    session: zenoh::Session,
    _alive: zenoh::liveliness::LivelinessToken,
    joins: zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>,
    hosts: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    _obs: zenoh::pubsub::Subscriber<()>,
    obs: std::sync::mpsc::Receiver<zenoh::sample::Sample>,
    /// The trust file and the text it opened with (TLS runs).
    trust: Option<(PathBuf, String)>,
}

impl Listener {
    fn open(o: &ListenOptions, bell: &Doorbell) -> anyhow::Result<Listener> {
        let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
        let (security, trust) = match &o.tls_run {
            Some(run) => {
                let files = certs::learner_files(run, &o.run_id)?;
                let trust = (files.trusted.clone(), std::fs::read_to_string(&files.trusted)?);
                let access = Some(access::learner_rules(&o.run_id, &files.peer_names));
                (Security::Tls { files, access }, Some(trust))
            }
            None => (Security::Insecure, None),
        };
        let session = session(std::slice::from_ref(&o.endpoint), &[], &security)?;
        if let (Some(run), Some((_, text))) = (&o.tls_run, &trust) {
            certs::mark_applied(run, text)?;
        }
        let _alive =
            session.liveliness().declare_token(learner_key(&o.run_id)).wait().map_err(zerr("liveliness token"))?;
        let joins = session.declare_queryable(JOIN_KEY).wait().map_err(zerr("join queryable"))?;
        let hosts =
            session.liveliness().declare_subscriber(host_key_all(&o.run_id)).wait().map_err(zerr("host liveliness"))?;
        let (_obs, obs) = bell.subscribe(&session, obs_key_all(&o.run_id))?;
        Ok(Listener { session, _alive, joins, hosts, _obs, obs, trust })
    }

    /// Whether the run's trust file no longer says what this listener opened with.
    fn trust_changed(&self) -> bool {
        self.trust.as_ref().is_some_and(|(path, text)| std::fs::read_to_string(path).is_ok_and(|now| now != *text))
    }

    /// The hosts whose liveliness tokens this listener sees now.
    fn hosts_alive(&self, run_id: &str) -> Vec<u64> {
        let Ok(replies) = self.session.liveliness().get(host_key_all(run_id)).timeout(Duration::from_secs(2)).wait()
        else {
            return Vec::new();
        };
        std::iter::from_fn(|| replies.recv().ok())
            .filter_map(|r| r.result().ok().map(|s| s.key_expr().as_str().to_string()))
            .filter_map(|k| token_of(&k))
            .collect()
    }
}

/// How long hosts have to come back after the listener reopened before their slots are freed.
const REJOIN_GRACE: Duration = Duration::from_secs(15);
/// How long a host's presence may vanish before the learner asks whether it is there (Zenoh
/// may replace a host's first link by a second one it was opening at the same time) and frees
/// its slots if not.
const LINK_GRACE: Duration = Duration::from_secs(3);

fn learner_side(
    o: ListenOptions,
    stop: &AtomicBool,
    counts: &BridgeCounts,
    opened: std::sync::mpsc::Sender<Result<(), String>>,
) -> anyhow::Result<()> {
    let bell = Doorbell::new()?;
    let l = match Listener::open(&o, &bell) {
        Ok(l) => {
            let _ = opened.send(Ok(()));
            l
        }
        Err(e) => {
            let _ = opened.send(Err(format!("{e:#}")));
            return Ok(());
        }
    };
    let Some(ports) = open_slots(&o, stop) else { return Ok(()) };
    // Wakes on a remote observation (the bell) or an answer of the learner (its event per slot).
    let ws = wait_set()?;
    let _bell = ws.attach_notification(&bell.door).map_err(|e| anyhow::anyhow!("watching the bell: {e:?}"))?;
    let _answers = ports
        .iter()
        .map(|p| ws.attach_notification(p.action_events()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("watching the learner's answers: {e:?}"))?;
    let mut side = Side::new(&o, l, counts);
    while !stop.load(Ordering::Relaxed) {
        wait(&ws)?;
        bell.answer();
        side.check_trust(&bell)?;
        side.settle_rejoins();
        side.admit_joins()?;
        side.track_hosts();
        side.forward_observations(&ports)?;
        side.answer(&ports)?;
    }
    Ok(())
}

/// One stand-in worker per remote slot, in the learner's shared memory. Its ports need the
/// learner's obs_ready, made when the learner starts: asks again each second until then (None
/// when the run ends first, should the learner never start).
fn open_slots(o: &ListenOptions, stop: &AtomicBool) -> Option<Vec<WorkerPorts>> {
    let open = || -> anyhow::Result<Vec<WorkerPorts>> {
        (o.first_slot..o.first_slot + o.slots)
            .map(|k| {
                let mut w = WorkerOptions::new(&o.run_id, k, 0, o.width, o.height);
                w.connect_timeout = Duration::from_secs(1);
                WorkerPorts::open(&w, &o.layout).with_context(|| format!("opening remote slot {k}"))
            })
            .collect()
    };
    loop {
        match open() {
            Ok(p) => return Some(p),
            Err(_) if !stop.load(Ordering::Relaxed) => continue,
            Err(_) => return None,
        }
    }
}

/// The learner's side of the bridge between its rounds: who holds which slot, which hosts are
/// leaving, and what went through each slot last.
struct Side<'a> {
    o: &'a ListenOptions,
    l: Listener,
    counts: &'a BridgeCounts,
    holders: Holders,
    trust_checked: Instant,
    /// When the TLS listener was last reopened (hosts it lost get `REJOIN_GRACE` to come back).
    reopened: Option<Instant>,
    /// Hosts whose presence vanished, since when: a link Zenoh replaces comes back at once.
    leaving: Vec<(u64, Instant)>,
    /// Per remote slot: the newest observation forwarded (generation, step) and the last answer
    /// sent, for a host that sends an observation again after a reopen (`host_bridge`).
    forwarded: Vec<Option<(u32, u64)>>,
    answers: Vec<Option<Vec<u8>>>,
}

impl<'a> Side<'a> {
    fn new(o: &'a ListenOptions, l: Listener, counts: &'a BridgeCounts) -> Side<'a> {
        let n = o.slots as usize;
        Side {
            o,
            l,
            counts,
            holders: Holders { first_slot: o.first_slot, held: vec![None; n], joins: 0 },
            trust_checked: Instant::now(),
            reopened: None,
            leaving: Vec::new(),
            forwarded: vec![None; n],
            answers: vec![None; n],
        }
    }

    fn send_act(&self, k: u32, bytes: Vec<u8>) -> anyhow::Result<()> {
        self.l
            .session
            .put(act_key(&self.o.run_id, k), bytes)
            .congestion_control(CongestionControl::Block)
            // not batched: every step waits for this message
            .express(true)
            .wait()
            .map_err(|e| anyhow::anyhow!("sending actions: {e}"))
    }

    /// Once a second: when the run's trusted hosts changed, reopens the TLS listener with them.
    fn check_trust(&mut self, bell: &Doorbell) -> anyhow::Result<()> {
        if self.trust_checked.elapsed() <= Duration::from_secs(1) {
            return Ok(());
        }
        self.trust_checked = Instant::now();
        if !self.l.trust_changed() {
            return Ok(());
        }
        // Hosts wait for the learner to come back instead of ending their workers.
        let _ = self.l.session.put(reopen_key(&self.o.run_id), Vec::<u8>::new()).express(true).wait();
        // closing drops what is still queued: let the notice leave first
        std::thread::sleep(Duration::from_millis(300));
        let _ = self.l.session.close().wait();
        self.l = Listener::open(self.o, bell)?;
        self.reopened = Some(Instant::now());
        let (trusted, revoked) = certs::hosts(self.o.tls_run.as_deref().expect("a TLS run"))?;
        eprintln!(
            "[up] reopened the TLS listener; trusted hosts now: {} (revoked: {})",
            if trusted.is_empty() { "none".into() } else { trusted.join(", ") },
            if revoked.is_empty() { "none".into() } else { revoked.join(", ") },
        );
        Ok(())
    }

    /// After a reopen's grace: frees the slots of hosts that did not come back.
    fn settle_rejoins(&mut self) {
        if !self.reopened.is_some_and(|t| t.elapsed() > REJOIN_GRACE) {
            return;
        }
        self.reopened = None;
        let alive = self.l.hosts_alive(&self.o.run_id);
        for t in self.holders.tokens() {
            if !alive.contains(&t) {
                let n = self.holders.release(t);
                eprintln!("[up] a worker host did not come back after the reopen: {n} remote slot(s) free");
            }
        }
    }

    /// Grants or refuses each join request waiting.
    fn admit_joins(&mut self) -> anyhow::Result<()> {
        while let Ok(Some(q)) = self.l.joins.try_recv() {
            let payload = q.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
            match grant(self.o, &mut self.holders, &payload) {
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
        Ok(())
    }

    /// Follows the hosts' presence; frees the slots of a host gone for longer than `LINK_GRACE`.
    fn track_hosts(&mut self) {
        while let Ok(Some(s)) = self.l.hosts.try_recv() {
            let token = token_of(s.key_expr().as_str());
            match (s.kind(), token) {
                (SampleKind::Delete, Some(t)) => self.leaving.push((t, Instant::now())),
                (SampleKind::Put, Some(t)) => self.leaving.retain(|(l, _)| *l != t),
                _ => {}
            }
        }
        let expired: Vec<u64> =
            self.leaving.extract_if(.., |(_, since)| since.elapsed() > LINK_GRACE).map(|(t, _)| t).collect();
        // A link Zenoh replaced can report a host gone while it is there: ask.
        let alive = if expired.is_empty() { Vec::new() } else { self.l.hosts_alive(&self.o.run_id) };
        for t in expired.into_iter().filter(|t| !alive.contains(t)) {
            let n = self.holders.release(t);
            if n > 0 {
                eprintln!("[up] a worker host left: {n} remote slot(s) free until a host joins again");
            }
        }
    }

    /// Hands each remote observation of a slot's holder to the learner, once; the rest is refused.
    fn forward_observations(&mut self, ports: &[WorkerPorts]) -> anyhow::Result<()> {
        let o = self.o;
        while let Ok(s) = self.l.obs.try_recv() {
            let bytes = s.payload().to_bytes();
            match (slot_of(s.key_expr().as_str()), decode_obs(&bytes)) {
                (Some(k), Ok((token, header, payload)))
                    if self.holders.holder(k) == Some(token)
                        && header.worker_id == k
                        && payload.len() == o.layout.total_len as usize =>
                {
                    let i = (k - o.first_slot) as usize;
                    if self.forwarded[i].is_some_and(|(g, step)| g == header.generation && header.step <= step) {
                        // sent again after a reopen: the learner has it; its answer may be lost
                        if let Some(a) = &self.answers[i] {
                            self.send_act(k, a.clone())?;
                        }
                        continue;
                    }
                    self.forwarded[i] = Some((header.generation, header.step));
                    ports[i].forward(&header, &payload)?;
                    self.counts.observations.fetch_add(1, Ordering::Relaxed);
                    self.counts.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
                }
                _ => {
                    self.counts.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        Ok(())
    }

    /// Sends the learner's answers to the hosts holding their slots.
    fn answer(&mut self, ports: &[WorkerPorts]) -> anyhow::Result<()> {
        for (i, p) in ports.iter().enumerate() {
            let k = self.o.first_slot + i as u32;
            let _ = p.action_events().try_wait(|_| {});
            while let Some(m) = p.try_action()? {
                if let Some(token) = self.holders.holder(k) {
                    let bytes = encode_act(token, &m);
                    self.answers[i] = Some(bytes.clone());
                    self.send_act(k, bytes)?;
                    self.counts.actions.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        Ok(())
    }
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
            tls_run: None,
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
