//! The Zenoh session of either side: a peer on the given endpoints only, over TLS with
//! certificates on both sides unless `--insecure`, and the scheduler hint its threads and the
//! bridges run with.

use zenoh::Wait;

use super::certs::TlsFiles;

/// How a session's links are secured.
#[derive(Clone, Debug)]
pub enum Security {
    /// Plain TCP (`--insecure`): whoever reaches the port can read and write the run.
    Insecure,
    /// TLS only, both sides showing a certificate the other trusts; `access` is Zenoh's
    /// `access_control` section (the learner's, [`super::access::learner_rules`]).
    Tls { files: TlsFiles, access: Option<serde_json::Value> },
}

/// The endpoint's protocol is the one `security` speaks: `tls/` for certificates, `tcp/` only
/// with `--insecure` (and then one warning line).
pub fn check_endpoint(endpoint: &str, insecure: bool, flag: &str) -> anyhow::Result<()> {
    match (endpoint.split_once('/').map(|(p, _)| p), insecure) {
        (Some("tls"), _) => Ok(()),
        (Some("tcp"), true) => {
            eprintln!(
                "warning: {flag} {endpoint} is plain TCP: anyone who reaches the port can read this run's frames and send it actions (loopback experiments only)"
            );
            Ok(())
        }
        (Some("tcp"), false) => anyhow::bail!(
            "{flag} {endpoint}: plain TCP is refused; use tls/{} (certificates on both sides), or --insecure for a loopback experiment",
            endpoint.split_once('/').map(|(_, a)| a).unwrap_or("HOST:PORT")
        ),
        _ => anyhow::bail!("{flag} {endpoint}: expected tls/HOST:PORT (or tcp/HOST:PORT with --insecure)"),
    }
}

/// Zenoh's usual port.
pub const DEFAULT_PORT: u16 = 7447;

/// A Zenoh peer that listens on or connects to the given endpoints only: no multicast
/// scouting, so nothing joins that was not pointed at.
pub fn session(listen: &[String], connect: &[String], security: &Security) -> anyhow::Result<zenoh::Session> {
    let c = config(listen, connect, security)?;
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
pub fn config(listen: &[String], connect: &[String], security: &Security) -> anyhow::Result<zenoh::Config> {
    let mut c = zenoh::Config::default();
    let list = |v: &[String]| serde_json::to_string(v).expect("strings serialise");
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v).map_err(|e| anyhow::anyhow!("zenoh config {k} = {v}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "listen/endpoints", &list(listen))?;
    set(&mut c, "connect/endpoints", &list(connect))?;
    if let Security::Tls { files, access } = security {
        let path = |p: &std::path::Path| serde_json::to_string(&p.to_string_lossy()).expect("strings serialise");
        set(&mut c, "transport/link/protocols", r#"["tls"]"#)?;
        set(&mut c, "transport/link/tls/root_ca_certificate", &path(&files.trusted))?;
        for side in ["listen", "connect"] {
            set(&mut c, &format!("transport/link/tls/{side}_certificate"), &path(&files.certificate))?;
            set(&mut c, &format!("transport/link/tls/{side}_private_key"), &path(&files.key))?;
        }
        set(&mut c, "transport/link/tls/enable_mtls", "true")?;
        // A link that connected as the learner closed its listener hangs until this passes:
        // retry sooner than Zenoh's 10 s.
        set(&mut c, "transport/unicast/open_timeout", "5000")?;
        // Each side trusts one CA that signed exactly one certificate, the other side's: the
        // chain names the peer; the address a host dials need not be in the learner's.
        set(&mut c, "transport/link/tls/verify_name_on_connect", "false")?;
        if let Some(acl) = access {
            set(&mut c, "access_control", &acl.to_string())?;
        }
    }
    Ok(c)
}

/// Asks the scheduler to run the calling thread, and the threads it starts from now on, soon
/// after they wake: Linux's latency hint for ordinary threads (a custom slice of 0.1 ms,
/// `sched_attr.sched_runtime`, Linux ≥ 6.12; no privilege needed; older kernels ignore it or
/// refuse, and then nothing changes). A remote step is a chain of about ten wake-ups (the
/// bridges and Zenoh's threads on both sides) against two for a local one, and on cores kept
/// busy by long slices (a learner's PPO threads) each wake-up can wait one out (docs/bench/log.md,
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

/// An identifier of this machine for the learner's log.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "host".into())
}
