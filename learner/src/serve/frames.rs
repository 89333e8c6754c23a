//! The learner's end of `env.frames = "device"`: a Unix socket in the run folder where every
//! worker process hands over the GPU memory it draws its frames into (one file descriptor, once
//! per process), and the imports made of them, one per worker slot. A restarted worker hands
//! over new memory with its new generation; an observation is read only from the memory of
//! the generation that sent it.

use std::collections::HashMap;
use std::os::fd::OwnedFd;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use anyhow::Context;
use farm::frame_socket::{self, FrameHandoff};
use tch::Device;

use crate::device_frames::ImportedFrames;

/// How long an observation waits for its worker's frames to be handed over (the worker sends
/// them before its first observation; the accepting thread may lag behind).
const HANDOFF_WAIT: Duration = Duration::from_secs(60);

/// The frame socket and the imports of every worker slot.
pub struct FrameImports {
    path: PathBuf,
    device: Device,
    arrivals: mpsc::Receiver<anyhow::Result<(FrameHandoff, OwnedFd)>>,
    /// Handed over but not yet needed, by (worker, generation).
    pending: HashMap<(u32, u32), (FrameHandoff, OwnedFd)>,
    /// By worker slot: the generation imported and its frames.
    imported: HashMap<u32, (u32, ImportedFrames)>,
}

impl FrameImports {
    /// Binds the frame socket of `run_dir` (replacing one a dead run left) and accepts workers on
    /// a thread of its own; frames are imported onto `device` when first needed.
    pub fn listen(run_dir: &Path, device: Device) -> anyhow::Result<FrameImports> {
        let path = frame_socket::socket_path(run_dir);
        let listener = frame_socket::bind(&path)?;
        let (tx, arrivals) = mpsc::channel();
        std::thread::Builder::new().name("frame-socket".into()).spawn(move || accept(listener, tx))?;
        Ok(FrameImports { path, device, arrivals, pending: HashMap::new(), imported: HashMap::new() })
    }

    /// Makes sure worker `worker`'s frames of `generation` are imported, waiting for them to be
    /// handed over if need be.
    pub fn ensure(&mut self, worker: u32, generation: u32) -> anyhow::Result<()> {
        if self.imported.get(&worker).is_some_and(|(g, _)| *g == generation) {
            return Ok(());
        }
        let deadline = std::time::Instant::now() + HANDOFF_WAIT;
        while !self.pending.contains_key(&(worker, generation)) {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.arrivals.recv_timeout(left) {
                Ok(Ok((h, fd))) => {
                    self.pending.insert((h.worker_id, h.generation), (h, fd));
                }
                // a worker killed while handing over (its restart hands over again): not fatal
                Ok(Err(e)) => tracing::warn!("{e:#}"),
                Err(_) => anyhow::bail!(
                    "worker {worker} (generation {generation}) has not handed its frames over {} within {} s",
                    self.path.display(),
                    HANDOFF_WAIT.as_secs()
                ),
            }
        }
        let (h, fd) = self.pending.remove(&(worker, generation)).expect("waited for it");
        // older generations of this slot will never be read
        self.pending.retain(|&(w, g), _| w != worker || g > generation);
        let frames = ImportedFrames::import(fd, h.layout, h.device_uuid, h.memory_type, self.device)
            .with_context(|| format!("importing worker {worker}'s frames (generation {generation})"))?;
        tracing::info!(
            "worker {worker} (generation {generation}): {} frames of {}x{} imported from its GPU memory",
            h.layout.slots,
            h.layout.width,
            h.layout.height
        );
        self.imported.insert(worker, (generation, frames));
        Ok(())
    }

    /// Worker `worker`'s imported frames (after [`FrameImports::ensure`]).
    pub fn frames(&self, worker: u32) -> Option<&ImportedFrames> {
        self.imported.get(&worker).map(|(_, f)| f)
    }

    /// Waits until every copy out of the imported frames is done (a no-op without a GPU).
    pub fn finish_copies(&self) {
        // one device for all: one synchronize serves every worker's frames
        if let Some((_, f)) = self.imported.values().next() {
            f.finish_copies();
        }
    }
}

impl Drop for FrameImports {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Accepts workers until the learner ends; each connection hands over one message.
fn accept(listener: UnixListener, tx: mpsc::Sender<anyhow::Result<(FrameHandoff, OwnedFd)>>) {
    for stream in listener.incoming() {
        let got = stream
            .context("accepting a worker on the frame socket")
            .and_then(|s: UnixStream| frame_socket::recv(&s).context("a worker's frame handoff"));
        if tx.send(got).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use shm_schema::DeviceFrameLayout;

    use super::*;
    use crate::device_frames::TestExport;

    /// A connection that closes without handing anything over (a worker killed at that moment)
    /// is logged, not fatal: the next handoff is imported.
    #[test]
    fn a_broken_handoff_does_not_stop_the_next() {
        let mut layout = DeviceFrameLayout::new(2, 8, 8);
        let Some(export) = TestExport::new_or_skip(layout.size) else { return };
        layout.size = export.size;
        let dir = tempfile::tempdir().unwrap();
        let mut imports = FrameImports::listen(dir.path(), Device::Cpu).unwrap();
        drop(frame_socket::connect(&frame_socket::socket_path(dir.path())).unwrap());
        let handoff = FrameHandoff {
            worker_id: 0,
            generation: 0,
            device_uuid: export.uuid,
            memory_type: export.memory_type,
            layout,
        };
        let stream = frame_socket::connect(&frame_socket::socket_path(dir.path())).unwrap();
        frame_socket::send(&stream, &handoff, std::os::fd::AsFd::as_fd(&export.fd())).unwrap();
        imports.ensure(0, 0).unwrap();
        assert_eq!(imports.frames(0).unwrap().rgb(&[1, 0]).size(), [2, 8, 8, 3]);
        assert!(imports.frames(1).is_none());
        drop(imports);
        assert!(!frame_socket::socket_path(dir.path()).exists(), "the socket is removed with the imports");
    }
}
