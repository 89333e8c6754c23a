//! What both bridges are made of: a thread with its stop flag, a wait set that blocks on the
//! farm's iceoryx2 events and on a doorbell rung by Zenoh's subscriber callbacks, and the counts
//! of what a bridge moved.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use farm::transport::IpcService;
use iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSet, WaitSetBuilder};
use iceoryx2_bb_posix::socket_pair::StreamingSocket;
use zenoh::Wait;
use zenoh::sample::Sample;

use super::session::short_slices;

/// How often an idle bridge looks at joins, departures and its stop flag; messages wake it at
/// once.
const IDLE: Duration = Duration::from_millis(50);

/// Messages a bridge moved, and refused.
#[derive(Debug, Default)]
pub struct BridgeCounts {
    pub observations: AtomicU64,
    pub bytes: AtomicU64,
    pub actions: AtomicU64,
    /// Messages of a host that holds no grant for their slot, or that do not decode.
    pub refused: AtomicU64,
}

/// Zenoh delivers in its own threads; a bridge's iceoryx2 ports stay in the bridge's thread.
/// So a subscriber hands each sample over a channel and rings this bell, a socket pair whose
/// reading end the bridge's wait set watches beside the iceoryx2 events: one blocking wait for
/// both sides, no polling.
pub(super) struct Doorbell {
    ring: Arc<Mutex<StreamingSocket>>,
    pub(super) door: StreamingSocket,
}

impl Doorbell {
    pub(super) fn new() -> anyhow::Result<Doorbell> {
        let (ring, door) = StreamingSocket::create_pair().map_err(|e| anyhow::anyhow!("a socket pair: {e:?}"))?;
        Ok(Doorbell { ring: Arc::new(Mutex::new(ring)), door })
    }

    /// A subscriber on `key` whose samples arrive on the returned channel, each ringing the bell.
    pub(super) fn subscribe(
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
    pub(super) fn answer(&self) {
        let mut buf = [0u8; 256];
        while matches!(self.door.try_receive(&mut buf), Ok(n) if n > 0) {}
    }
}

/// A wait set without signal handlers of its own (the processes have theirs).
pub(super) fn wait_set() -> anyhow::Result<WaitSet<IpcService>> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| anyhow::anyhow!("creating a wait set: {e:?}"))
}

/// Sleeps until something attached to `ws` fires or `IDLE` passes.
pub(super) fn wait(ws: &WaitSet<IpcService>) -> anyhow::Result<()> {
    ws.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, IDLE)
        .map(|_| ())
        .map_err(|e| anyhow::anyhow!("waiting in the bridge's wait set: {e:?}"))
}

/// A bridge's thread and the flag that stops it.
pub(super) struct BridgeThread {
    name: &'static str,
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<anyhow::Result<()>>,
}

impl BridgeThread {
    /// Runs `body` (which loops until the flag it is given is set) in a thread called `name`.
    pub(super) fn spawn(
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
    pub(super) fn ended(&self) -> bool {
        self.thread.is_finished()
    }

    /// Stops the thread; its error, if it ended on one.
    pub(super) fn finish(self) -> anyhow::Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap_or_else(|_| Err(anyhow::anyhow!("the {} panicked", self.name)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::remote::{Security, session};

    #[test]
    fn a_zenoh_message_wakes_a_bridge_waiting_on_its_wait_set() {
        let session = session(&[], &[], &Security::Insecure).unwrap();
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
}
