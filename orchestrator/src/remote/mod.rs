//! More than one machine: worker hosts join a run over Zenoh.
//!
//! The learner's host (`up --listen ENDPOINT --remote-workers R`) reserves R learner slots after
//! its local workers and runs a [`LearnerBridge`]: for each remote slot it stands in for a worker
//! towards the learner (an iceoryx2 publisher of `obs/<slot>` in the run's shared memory, a
//! subscriber of `act/<slot>`), so the learner reads remote frames exactly as local ones. A
//! worker host (`orchestrator workers --connect ENDPOINT`) asks to join (`gesthor/join`), is
//! granted a range of slots, the run's config and a generation base above any earlier process
//! in those slots, starts its workers as those slots in its own shared-memory domain, and runs a
//! [`HostBridge`] that stands in for the learner towards them. Between the two bridges:
//!
//! - `gesthor/<run>/obs/<slot>`: an observation (codec, grant token, header, payload; LZ4 or
//!   Zstandard if asked), host → learner;
//! - `gesthor/<run>/act/<slot>`: an action message (token, message), learner → host;
//! - liveliness tokens `gesthor/<run>/learner` and `gesthor/<run>/host/<token>`: a vanished
//!   host frees its slots (the learner sees them as missing workers, one batch timeout each
//!   round), a vanished learner ends the host's workers.
//!
//! A join proves knowledge of the run's secret (SHA-256 over the secret, the run id and a
//! nonce), and so does the grant; a host of another run or with another secret is refused with
//! a line on both sides. Messages carry the grant's token: a host whose slots were given to
//! another is ignored. The traffic itself is not encrypted (Zenoh's TLS transport would be).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use farm::learner_ports::LearnerPorts;
use farm::transport::{IpcService, WorkerOptions, WorkerPorts};
use iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSet, WaitSetBuilder};
use iceoryx2_bb_posix::socket_pair::StreamingSocket;
use shm_schema::{ActionMsg, ObsHeader, ObsLayout};
use zenoh::sample::Sample;

/// Zenoh's usual port.
pub const DEFAULT_PORT: u16 = 7447;
const JOIN_KEY: &str = "gesthor/join";
/// How often an idle bridge looks at joins, departures and its stop flag; messages wake it at
/// once.
const IDLE: Duration = Duration::from_millis(50);
/// How long a host waits for the learner's answer to a join.
const JOIN_TIMEOUT: Duration = Duration::from_secs(10);

fn obs_key(run: &str, slot: u32) -> String {
    format!("gesthor/{run}/obs/{slot}")
}
fn act_key(run: &str, slot: u32) -> String {
    format!("gesthor/{run}/act/{slot}")
}
fn learner_key(run: &str) -> String {
    format!("gesthor/{run}/learner")
}
fn host_key(run: &str, token: u64) -> String {
    format!("gesthor/{run}/host/{token:016x}")
}
/// The slot at the end of an obs/act key.
fn slot_of(key: &str) -> Option<u32> {
    key.rsplit('/').next()?.parse().ok()
}

/// A Zenoh peer that listens on or connects to the given endpoints only: no multicast
/// scouting, so nothing joins that was not pointed at.
pub fn session(listen: &[String], connect: &[String]) -> anyhow::Result<zenoh::Session> {
    let c = config(listen, connect)?;
    // Zenoh's runtime threads start here and inherit the hint of the thread that opens it.
    std::thread::scope(|s| {
        s.spawn(|| {
            short_slices();
            zenoh::open(c).wait()
        })
        .join()
        .expect("opening Zenoh does not panic")
    })
    .map_err(|e| anyhow::anyhow!("opening a Zenoh session (listen {listen:?}, connect {connect:?}): {e}"))
}

/// The configuration of [`session`].
pub fn config(listen: &[String], connect: &[String]) -> anyhow::Result<zenoh::Config> {
    let mut c = zenoh::Config::default();
    let list = |v: &[String]| serde_json::to_string(v).expect("strings serialise");
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v).map_err(|e| anyhow::anyhow!("zenoh config {k} = {v}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "listen/endpoints", &list(listen))?;
    set(&mut c, "connect/endpoints", &list(connect))?;
    Ok(c)
}

/// Asks the scheduler to run the calling thread, and the threads it starts from now on, soon
/// after they wake: Linux's latency hint for ordinary threads (a custom slice of 0.1 ms,
/// `sched_attr.sched_runtime`, Linux ≥ 6.12; no privilege needed; older kernels ignore it or
/// refuse, and then nothing changes). A remote step is a chain of about ten wake-ups (the
/// bridges and Zenoh's threads on both sides) against two for a local one, and on cores kept
/// busy by long slices (a learner's PPO threads) each wake-up can wait one out (BENCHMARKS.md,
/// "More than one machine"). These threads run for microseconds per message, so the hint costs
/// the workers nothing. The nice value and the policy stay as they are.
pub fn short_slices() {
    // struct sched_attr as of Linux 3.14 (SCHED_ATTR_SIZE_VER0).
    #[repr(C)]
    #[derive(Default)]
    struct SchedAttr {
        size: u32,
        policy: u32,
        flags: u64,
        nice: i32,
        priority: u32,
        runtime: u64,
        deadline: u64,
        period: u64,
    }
    let size = std::mem::size_of::<SchedAttr>();
    let mut a = SchedAttr::default();
    // SAFETY: both calls read or write at most `size` bytes of `a` for the calling thread (0).
    unsafe {
        if libc::syscall(libc::SYS_sched_getattr, 0, &mut a as *mut SchedAttr, size as u32, 0) != 0 {
            return;
        }
        if a.policy != libc::SCHED_OTHER as u32 {
            return;
        }
        a.size = size as u32;
        a.runtime = 100_000;
        let _ = libc::syscall(libc::SYS_sched_setattr, 0, &a as *const SchedAttr, 0);
    }
}

/// SHA-256 of the secret, who speaks, the run id and the nonce, in hex.
fn proof(secret: &str, role: &str, run_id: &str, nonce: &str) -> String {
    let mut h = Sha256::new();
    for part in [secret, role, run_id, nonce] {
        h.update((part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    farm::files::hex(&h.finalize())
}

/// `bytes` random bytes from the kernel, in hex (secrets, nonces, grant tokens).
pub fn random_hex(bytes: usize) -> String {
    let mut b = vec![0u8; bytes];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut b))
        .expect("/dev/urandom is readable");
    farm::files::hex(&b)
}

/// What a worker host asks.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JoinRequest {
    pub run_id: String,
    pub workers: u32,
    pub host: String,
    pub nonce: String,
    pub proof: String,
}

/// What the learner's host grants.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JoinGrant {
    pub first_slot: u32,
    pub first_generation: u32,
    pub token: u64,
    /// The run's effective configuration (the host's workers read it).
    pub config_toml: String,
    /// SHA-256 of the dataset's manifest: the host's copy must be the same dataset.
    pub manifest_digest: String,
    pub proof: String,
}

/// Encoding of an observation on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Codec {
    Raw = 0,
    Lz4 = 1,
    /// Zstandard at level 1: smaller than LZ4, slower to make.
    Zstd = 2,
}

/// No observation decompresses to more than this (a damaged or hostile size field stops here).
const MAX_PAYLOAD: usize = 1 << 28;

const HEADER_BYTES: usize = std::mem::size_of::<ObsHeader>();
const ACT_BYTES: usize = std::mem::size_of::<ActionMsg>();

fn as_bytes<T: Copy>(v: &T) -> &[u8] {
    // SAFETY: T is one of the schema's #[repr(C)] plain-data messages (integers, floats and
    // arrays of them, padding spelled out as fields), so every byte is initialised.
    unsafe { std::slice::from_raw_parts(v as *const T as *const u8, std::mem::size_of::<T>()) }
}

fn from_bytes<T: Copy>(b: &[u8]) -> T {
    assert_eq!(b.len(), std::mem::size_of::<T>());
    // SAFETY: the length matches and every bit pattern is a valid value of these plain-data
    // messages; the receiver checks magic, version and shape before trusting one.
    unsafe { std::ptr::read_unaligned(b.as_ptr() as *const T) }
}

/// `[codec][token][header][payload]`, the payload LZ4-compressed (size prepended) with `Lz4`.
pub fn encode_obs(codec: Codec, token: u64, header: &ObsHeader, payload: &[u8]) -> Vec<u8> {
    let body = match codec {
        Codec::Raw => std::borrow::Cow::Borrowed(payload),
        Codec::Lz4 => std::borrow::Cow::Owned(lz4_flex::compress_prepend_size(payload)),
        Codec::Zstd => std::borrow::Cow::Owned(zstd::bulk::compress(payload, 1).expect("compressing into a Vec")),
    };
    let mut out = Vec::with_capacity(9 + HEADER_BYTES + body.len());
    out.push(codec as u8);
    out.extend_from_slice(&token.to_le_bytes());
    out.extend_from_slice(as_bytes(header));
    out.extend_from_slice(&body);
    out
}

/// The inverse of [`encode_obs`]; an error says what is wrong with the message.
pub fn decode_obs(bytes: &[u8]) -> Result<(u64, ObsHeader, std::borrow::Cow<'_, [u8]>), String> {
    if bytes.len() < 9 + HEADER_BYTES {
        return Err(format!("{} bytes, shorter than a header", bytes.len()));
    }
    let token = u64::from_le_bytes(bytes[1..9].try_into().expect("8 bytes"));
    let header: ObsHeader = from_bytes(&bytes[9..9 + HEADER_BYTES]);
    let body = &bytes[9 + HEADER_BYTES..];
    let payload = match bytes[0] {
        0 => std::borrow::Cow::Borrowed(body),
        1 => std::borrow::Cow::Owned(lz4_flex::decompress_size_prepended(body).map_err(|e| format!("lz4: {e}"))?),
        2 => std::borrow::Cow::Owned(zstd::bulk::decompress(body, MAX_PAYLOAD).map_err(|e| format!("zstd: {e}"))?),
        c => return Err(format!("unknown codec {c}")),
    };
    Ok((token, header, payload))
}

fn encode_act(token: u64, m: &ActionMsg) -> Vec<u8> {
    let mut out = token.to_le_bytes().to_vec();
    out.extend_from_slice(as_bytes(m));
    out
}

fn decode_act(bytes: &[u8]) -> Option<(u64, ActionMsg)> {
    (bytes.len() == 8 + ACT_BYTES)
        .then(|| (u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")), from_bytes(&bytes[8..])))
}

/// Messages a bridge moved, and refused.
#[derive(Debug, Default)]
pub struct BridgeCounts {
    pub observations: AtomicU64,
    pub bytes: AtomicU64,
    pub actions: AtomicU64,
    /// Messages of a host that holds no grant for their slot, or that do not decode.
    pub refused: AtomicU64,
}

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

/// Zenoh delivers in its own threads; a bridge's iceoryx2 ports stay in the bridge's thread.
/// So a subscriber hands each sample over a channel and rings this bell, a socket pair whose
/// reading end the bridge's wait set watches beside the iceoryx2 events: one blocking wait for
/// both sides, no polling.
struct Doorbell {
    ring: Arc<Mutex<StreamingSocket>>,
    door: StreamingSocket,
}

impl Doorbell {
    fn new() -> anyhow::Result<Doorbell> {
        let (ring, door) = StreamingSocket::create_pair().map_err(|e| anyhow::anyhow!("a socket pair: {e:?}"))?;
        Ok(Doorbell { ring: Arc::new(Mutex::new(ring)), door })
    }

    /// A subscriber on `key` whose samples arrive on the returned channel, each ringing the bell.
    fn subscribe(
        &self,
        session: &zenoh::Session,
        key: String,
    ) -> anyhow::Result<(zenoh::pubsub::Subscriber<()>, Receiver<Sample>)> {
        // Bounded like Zenoh's own default handler: a flood waits in Zenoh, not in memory.
        let (tx, rx) = std::sync::mpsc::sync_channel(256);
        let ring = self.ring.clone();
        let sub = session
            .declare_subscriber(key.clone())
            .callback(move |s| {
                if tx.send(s).is_ok() {
                    // A full socket already holds a ring: nothing is lost by ignoring that.
                    let _ = ring.lock().map(|r| r.try_send(&[1]));
                }
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscribing to {key}: {e}"))?;
        Ok((sub, rx))
    }

    /// Empties the bell; call before draining the channels, so a ring after that is kept.
    fn answer(&self) {
        let mut buf = [0u8; 256];
        while matches!(self.door.try_receive(&mut buf), Ok(n) if n > 0) {}
    }
}

/// A wait set without signal handlers of its own (the processes have theirs).
fn wait_set() -> anyhow::Result<WaitSet<IpcService>> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| anyhow::anyhow!("creating a wait set: {e:?}"))
}

/// Sleeps until something attached to `ws` fires or `IDLE` passes.
fn wait(ws: &WaitSet<IpcService>) -> anyhow::Result<()> {
    ws.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, IDLE)
        .map(|_| ())
        .map_err(|e| anyhow::anyhow!("waiting in the bridge's wait set: {e:?}"))
}

/// A bridge's thread and the flag that stops it.
struct BridgeThread {
    name: &'static str,
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<anyhow::Result<()>>,
}

impl BridgeThread {
    /// Runs `body` (which loops until the flag it is given is set) in a thread called `name`.
    fn spawn(
        name: &'static str,
        body: impl FnOnce(&AtomicBool) -> anyhow::Result<()> + Send + 'static,
    ) -> anyhow::Result<BridgeThread> {
        let stop = Arc::new(AtomicBool::new(false));
        let thread = std::thread::Builder::new().name(name.into()).spawn({
            let stop = stop.clone();
            move || {
                short_slices();
                body(&stop)
            }
        })?;
        Ok(BridgeThread { name, stop, thread })
    }

    /// Whether the thread has ended (on an error: `finish` returns it).
    fn ended(&self) -> bool {
        self.thread.is_finished()
    }

    /// Stops the thread; its error, if it ended on one.
    fn finish(self) -> anyhow::Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap_or_else(|_| Err(anyhow::anyhow!("the {} panicked", self.name)))
    }
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

/// Asks the run's learner host to take `workers` workers; the grant, or the refusal as an error.
pub fn join(
    session: &zenoh::Session,
    run_id: &str,
    secret: &str,
    workers: u32,
    host: &str,
) -> anyhow::Result<JoinGrant> {
    let nonce = random_hex(16);
    let req = JoinRequest {
        run_id: run_id.into(),
        workers,
        host: host.into(),
        proof: proof(secret, "host", run_id, &nonce),
        nonce: nonce.clone(),
    };
    let replies = session
        .get(JOIN_KEY)
        .payload(serde_json::to_vec(&req)?)
        .timeout(JOIN_TIMEOUT)
        .wait()
        .map_err(|e| anyhow::anyhow!("asking to join: {e}"))?;
    let reply = replies
        .recv_timeout(JOIN_TIMEOUT + Duration::from_secs(1))
        .ok()
        .flatten()
        .with_context(|| format!("no learner answered within {} s", JOIN_TIMEOUT.as_secs()))?;
    match reply.result() {
        Ok(sample) => {
            let g: JoinGrant =
                serde_json::from_slice(&sample.payload().to_bytes()).context("the learner's grant does not parse")?;
            anyhow::ensure!(
                g.proof == proof(secret, "learner", run_id, &nonce),
                "the learner that answered does not know this run's secret"
            );
            Ok(g)
        }
        Err(e) => anyhow::bail!("the learner refused: {}", String::from_utf8_lossy(&e.payload().to_bytes())),
    }
}

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

/// An identifier of this machine for the learner's log.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "host".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_zenoh_message_wakes_a_bridge_waiting_on_its_wait_set() {
        let session = session(&[], &[]).unwrap();
        let bell = Doorbell::new().unwrap();
        let (_sub, rx) = bell.subscribe(&session, "gesthor/test/bell".into()).unwrap();
        let ws = wait_set().unwrap();
        let guard = ws.attach_notification(&bell.door).unwrap();
        session.put("gesthor/test/bell", vec![7u8; 3]).wait().unwrap();
        // Only a ring calls back; the long timeout only keeps a broken bell from hanging the suite.
        let mut rang = false;
        ws.wait_and_process_once_with_timeout(
            |id| {
                rang |= id.has_event_from(&guard);
                CallbackProgression::Continue
            },
            Duration::from_secs(60),
        )
        .unwrap();
        assert!(rang, "the bell woke the wait set");
        bell.answer();
        assert_eq!(&rx.try_recv().unwrap().payload().to_bytes()[..], &[7, 7, 7]);
        // Answered and drained: the next wait sleeps its whole timeout.
        let mut again = false;
        ws.wait_and_process_once_with_timeout(
            |_| {
                again = true;
                CallbackProgression::Continue
            },
            Duration::from_millis(1),
        )
        .unwrap();
        assert!(!again, "an answered bell does not ring again");
    }

    #[test]
    fn observations_and_actions_survive_the_wire() {
        let header = ObsHeader { magic: shm_schema::OBS_MAGIC, worker_id: 5, step: 77, ..Default::default() };
        let payload: Vec<u8> = (0..10_000u32).map(|i| (i % 7) as u8).collect();
        for codec in [Codec::Raw, Codec::Lz4, Codec::Zstd] {
            let bytes = encode_obs(codec, 42, &header, &payload);
            let (token, h, p) = decode_obs(&bytes).unwrap();
            assert_eq!((token, h, &p[..]), (42, header, &payload[..]), "{codec:?}");
        }
        for codec in [Codec::Lz4, Codec::Zstd] {
            assert!(encode_obs(codec, 1, &header, &payload).len() < payload.len() / 4, "{codec:?} compresses");
        }
        assert!(decode_obs(&[0; 20]).is_err());
        let m = ActionMsg { worker_id: 5, generation: 65536, step: 77, ..Default::default() };
        assert_eq!(decode_act(&encode_act(9, &m)), Some((9, m)));
    }

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
