//! The handoff of a worker's exported frame memory (`env.frames = "device"`): once per
//! worker, a [`FrameHandoff`] and the memory's file descriptor travel to the learner over a Unix
//! socket (`SCM_RIGHTS`). From then on no frame bytes travel at all: the learner reads each env's
//! slot in place, as [`DeviceFrameLayout`] says.
//!
//! The message is fixed little-endian bytes behind a magic and a version, so that a reader built
//! from another commit fails with a clear error instead of misreading a Rust memory dump.

use std::io::{IoSlice, IoSliceMut, Read, Write};
use std::os::fd::{AsRawFd, BorrowedFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};

use nix::sys::socket::{ControlMessage, ControlMessageOwned, MsgFlags, recvmsg, sendmsg};
use shm_schema::DeviceFrameLayout;

/// The socket's file name in a run directory.
pub const FILE_NAME: &str = "frames.sock";

/// Opens every message.
pub const MAGIC: [u8; 4] = *b"GTFH";

/// Changes whenever the encoding does.
pub const VERSION: u32 = 1;

/// Bytes of one encoded message.
pub const MESSAGE_LEN: usize = 76;

/// `sockaddr_un.sun_path` holds 108 bytes with the closing NUL (Linux).
pub const MAX_PATH_BYTES: usize = 107;

/// One worker's exported frame memory, as the learner needs it to import and read it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHandoff {
    pub worker_id: u32,
    /// Which start of the worker this is: a restarted worker exports new memory, and the learner
    /// drops the old import when a higher generation arrives.
    pub generation: u32,
    /// The Vulkan device's UUID, so that the learner can check CUDA sees the same card.
    pub device_uuid: [u8; 16],
    /// The Vulkan memory type the memory came from (a Vulkan importer must name the same).
    pub memory_type: u32,
    pub layout: DeviceFrameLayout,
}

/// What can go wrong on the frame socket; each names what was expected.
#[derive(Debug, thiserror::Error)]
pub enum FrameSocketError {
    #[error(
        "frame socket path {path} is {len} bytes, a Unix socket path holds at most {MAX_PATH_BYTES}: use a shorter run directory"
    )]
    PathTooLong { path: PathBuf, len: usize },
    #[error("binding the frame socket {path}: {source}")]
    Bind { path: PathBuf, source: std::io::Error },
    #[error("connecting to the frame socket {path}: {source}")]
    Connect { path: PathBuf, source: std::io::Error },
    #[error("sending the frame handoff: {0}")]
    Send(std::io::Error),
    #[error("receiving the frame handoff: {0}")]
    Recv(std::io::Error),
    #[error("the peer closed the frame socket before sending a frame handoff")]
    Closed,
    #[error("frame handoff cut short: {got} of {MESSAGE_LEN} bytes arrived before the peer closed the socket")]
    ShortRead { got: usize },
    #[error("not a frame handoff: it starts with {got:02x?}, a frame handoff with \"GTFH\"")]
    BadMagic { got: [u8; 4] },
    #[error(
        "frame handoff version {got}, this build reads version {VERSION}: worker and learner come from different builds"
    )]
    BadVersion { got: u32 },
    #[error("a frame handoff arrived without its memory's file descriptor")]
    NoFd,
    #[error("a frame handoff arrived with {got} file descriptors, expected one")]
    ExtraFds { got: usize },
}

/// `run_dir/frames.sock`.
pub fn socket_path(run_dir: &Path) -> PathBuf {
    run_dir.join(FILE_NAME)
}

/// The learner's listening socket at `path`, after removing a socket file a previous run left
/// there (a Unix socket's file outlives its process; any other file there is an error).
pub fn bind(path: &Path) -> Result<UnixListener, FrameSocketError> {
    check_path_len(path)?;
    let bind_err = |source| FrameSocketError::Bind { path: path.to_owned(), source };
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        use std::os::unix::fs::FileTypeExt;
        if meta.file_type().is_socket() {
            std::fs::remove_file(path).map_err(bind_err)?;
        }
    }
    UnixListener::bind(path).map_err(bind_err)
}

/// A worker's connection to the learner's socket at `path`.
pub fn connect(path: &Path) -> Result<UnixStream, FrameSocketError> {
    check_path_len(path)?;
    UnixStream::connect(path).map_err(|source| FrameSocketError::Connect { path: path.to_owned(), source })
}

fn check_path_len(path: &Path) -> Result<(), FrameSocketError> {
    let len = path.as_os_str().len();
    if len > MAX_PATH_BYTES {
        return Err(FrameSocketError::PathTooLong { path: path.to_owned(), len });
    }
    Ok(())
}

/// Sends `msg` with `fd` attached. The receiver gets its own descriptor of the same memory; the
/// sender may close `fd` afterwards.
pub fn send(stream: &UnixStream, msg: &FrameHandoff, fd: BorrowedFd<'_>) -> Result<(), FrameSocketError> {
    let bytes = encode(msg);
    let fds = [fd.as_raw_fd()];
    let cmsgs = [ControlMessage::ScmRights(&fds)];
    let sent = loop {
        match sendmsg::<()>(stream.as_raw_fd(), &[IoSlice::new(&bytes)], &cmsgs, MsgFlags::MSG_NOSIGNAL, None) {
            Err(nix::errno::Errno::EINTR) => continue,
            r => break r.map_err(|e| FrameSocketError::Send(e.into()))?,
        }
    };
    // A stream socket may take fewer bytes; the descriptor went with the first of them.
    (&*stream).write_all(&bytes[sent..]).map_err(FrameSocketError::Send)
}

/// Receives one message and its descriptor (close-on-exec, so that processes the learner starts
/// do not inherit the memory).
pub fn recv(stream: &UnixStream) -> Result<(FrameHandoff, OwnedFd), FrameSocketError> {
    let mut bytes = [0u8; MESSAGE_LEN];
    // Room for more descriptors than expected, so that extras arrive (and are closed) instead of
    // being cut off unseen.
    let mut cmsg_space = nix::cmsg_space!([RawFd; 4]);
    let (got, fds) = loop {
        let mut iov = [IoSliceMut::new(&mut bytes)];
        match recvmsg::<()>(stream.as_raw_fd(), &mut iov, Some(&mut cmsg_space), MsgFlags::MSG_CMSG_CLOEXEC) {
            Err(nix::errno::Errno::EINTR) => continue,
            Err(e) => return Err(FrameSocketError::Recv(e.into())),
            Ok(msg) => {
                let mut fds = Vec::new();
                for cmsg in msg.cmsgs().map_err(|e| FrameSocketError::Recv(e.into()))? {
                    if let ControlMessageOwned::ScmRights(raw) = cmsg {
                        // SAFETY: the kernel just installed these descriptors in this process for
                        // this message; nothing else owns them.
                        fds.extend(raw.into_iter().map(|r| unsafe { OwnedFd::from_raw_fd(r) }));
                    }
                }
                break (msg.bytes, fds);
            }
        }
    };
    if got == 0 && fds.is_empty() {
        return Err(FrameSocketError::Closed);
    }
    read_rest(stream, &mut bytes, got)?;
    let msg = decode(&bytes)?;
    let mut fds = fds.into_iter();
    match (fds.next(), fds.len()) {
        (None, _) => Err(FrameSocketError::NoFd),
        (Some(fd), 0) => Ok((msg, fd)),
        (Some(_), extra) => Err(FrameSocketError::ExtraFds { got: 1 + extra }),
    }
}

/// Completes a message the first `recvmsg` returned only part of.
fn read_rest(stream: &UnixStream, bytes: &mut [u8; MESSAGE_LEN], mut got: usize) -> Result<(), FrameSocketError> {
    while got < MESSAGE_LEN {
        match (&*stream).read(&mut bytes[got..]) {
            Ok(0) => return Err(FrameSocketError::ShortRead { got }),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(FrameSocketError::Recv(e)),
        }
    }
    Ok(())
}

/// magic, version, worker_id, generation, device_uuid, memory_type, then the layout's fields
/// in order.
fn encode(msg: &FrameHandoff) -> [u8; MESSAGE_LEN] {
    let l = &msg.layout;
    let mut out = [0u8; MESSAGE_LEN];
    let mut w = Writer { out: &mut out, at: 0 };
    w.put(&MAGIC);
    w.put(&VERSION.to_le_bytes());
    w.put(&msg.worker_id.to_le_bytes());
    w.put(&msg.generation.to_le_bytes());
    w.put(&msg.device_uuid);
    w.put(&msg.memory_type.to_le_bytes());
    for v in [l.slots, l.width, l.height, l.row_bytes] {
        w.put(&v.to_le_bytes());
    }
    for v in [l.layer_bytes, l.info_offset, l.size] {
        w.put(&v.to_le_bytes());
    }
    debug_assert_eq!(w.at, MESSAGE_LEN);
    out
}

fn decode(bytes: &[u8; MESSAGE_LEN]) -> Result<FrameHandoff, FrameSocketError> {
    let mut r = Reader { bytes, at: 0 };
    let magic: [u8; 4] = r.take();
    if magic != MAGIC {
        return Err(FrameSocketError::BadMagic { got: magic });
    }
    let version = r.u32();
    if version != VERSION {
        return Err(FrameSocketError::BadVersion { got: version });
    }
    let (worker_id, generation, device_uuid, memory_type) = (r.u32(), r.u32(), r.take(), r.u32());
    let layout = DeviceFrameLayout {
        slots: r.u32(),
        width: r.u32(),
        height: r.u32(),
        row_bytes: r.u32(),
        layer_bytes: r.u64(),
        info_offset: r.u64(),
        size: r.u64(),
    };
    Ok(FrameHandoff { worker_id, generation, device_uuid, memory_type, layout })
}

struct Writer<'a> {
    out: &'a mut [u8; MESSAGE_LEN],
    at: usize,
}

impl Writer<'_> {
    fn put(&mut self, b: &[u8]) {
        self.out[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
}

struct Reader<'a> {
    bytes: &'a [u8; MESSAGE_LEN],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let b = self.bytes[self.at..self.at + N].try_into().expect("N bytes");
        self.at += N;
        b
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
}

#[cfg(test)]
mod tests {
    use std::fs::File;
    use std::os::fd::AsFd;
    use std::os::unix::fs::{FileExt, MetadataExt};

    use nix::sys::memfd::{MFdFlags, memfd_create};

    use super::*;

    fn handoff() -> FrameHandoff {
        let uuid: [u8; 16] = std::array::from_fn(|i| 0xA0 + i as u8);
        FrameHandoff {
            worker_id: 3,
            generation: 7,
            device_uuid: uuid,
            memory_type: 2,
            layout: DeviceFrameLayout::new(8, 40, 24),
        }
    }

    #[test]
    fn message_round_trips_through_its_bytes() {
        let m = handoff();
        let bytes = encode(&m);
        assert_eq!(&bytes[..4], b"GTFH");
        assert_eq!(decode(&bytes).unwrap(), m);
    }

    #[test]
    fn the_fd_arrives_as_another_descriptor_of_the_same_memory() {
        let memfd = File::from(memfd_create("frames-test", MFdFlags::MFD_CLOEXEC).unwrap());
        memfd.set_len(4096).unwrap();
        let pattern: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
        memfd.write_all_at(&pattern, 0).unwrap();

        let (a, b) = UnixStream::pair().unwrap();
        let msg = handoff();
        let receiver = std::thread::spawn(move || recv(&b).unwrap());
        send(&a, &msg, memfd.as_fd()).unwrap();
        let (got, fd) = receiver.join().unwrap();
        assert_eq!(got, msg);
        assert_ne!(fd.as_raw_fd(), memfd.as_raw_fd());

        let received = File::from(fd);
        let (m0, m1) = (memfd.metadata().unwrap(), received.metadata().unwrap());
        assert_eq!((m0.dev(), m0.ino()), (m1.dev(), m1.ino()));
        let mut back = vec![0u8; 4096];
        received.read_exact_at(&mut back, 0).unwrap();
        assert_eq!(back, pattern);
        // and the other way: a write through the received descriptor shows through the first
        received.write_all_at(b"learner", 100).unwrap();
        let mut seen = [0u8; 7];
        memfd.read_exact_at(&mut seen, 100).unwrap();
        assert_eq!(&seen, b"learner");
    }

    #[test]
    fn a_corrupted_message_is_refused() {
        let memfd = memfd_create("frames-test", MFdFlags::MFD_CLOEXEC).unwrap();
        let (a, b) = UnixStream::pair().unwrap();
        let mut bytes = encode(&handoff());
        bytes[0] ^= 0xFF;
        let fds = [memfd.as_raw_fd()];
        sendmsg::<()>(
            a.as_raw_fd(),
            &[IoSlice::new(&bytes)],
            &[ControlMessage::ScmRights(&fds)],
            MsgFlags::empty(),
            None,
        )
        .unwrap();
        let e = recv(&b).unwrap_err();
        assert!(matches!(e, FrameSocketError::BadMagic { .. }), "{e}");

        let mut bytes = encode(&handoff());
        bytes[4] = 9;
        (&a).write_all(&bytes).unwrap();
        let e = recv(&b).unwrap_err();
        assert!(matches!(e, FrameSocketError::BadVersion { got: 9 }), "{e}");
        assert!(e.to_string().contains("different builds"), "{e}");
    }

    #[test]
    fn a_message_without_fd_or_cut_short_is_refused() {
        let (a, b) = UnixStream::pair().unwrap();
        (&a).write_all(&encode(&handoff())).unwrap();
        let e = recv(&b).unwrap_err();
        assert!(matches!(e, FrameSocketError::NoFd), "{e}");

        (&a).write_all(&encode(&handoff())[..30]).unwrap();
        drop(a);
        let e = recv(&b).unwrap_err();
        assert!(matches!(e, FrameSocketError::ShortRead { got: 30 }), "{e}");
        assert!(matches!(recv(&b).unwrap_err(), FrameSocketError::Closed));
    }

    #[test]
    fn a_long_socket_path_is_refused_when_binding() {
        let dir = tempfile::tempdir().unwrap();
        let path = socket_path(dir.path());
        assert_eq!(path.file_name().unwrap(), FILE_NAME);
        let listener = bind(&path).unwrap();
        drop(listener);
        // the file the first bind left is replaced, as after a crash
        let listener = bind(&path).unwrap();
        let client = connect(&path).unwrap();
        let (server, _) = listener.accept().unwrap();
        let memfd = memfd_create("frames-test", MFdFlags::MFD_CLOEXEC).unwrap();
        send(&client, &handoff(), memfd.as_fd()).unwrap();
        assert_eq!(recv(&server).unwrap().0, handoff());

        let long = dir.path().join("x".repeat(120)).join(FILE_NAME);
        let e = bind(&long).unwrap_err();
        assert!(matches!(e, FrameSocketError::PathTooLong { .. }), "{e}");
        assert!(e.to_string().contains("at most 107"), "{e}");
    }
}
