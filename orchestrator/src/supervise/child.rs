//! Child processes: spawned into their own process group with a parent-death signal armed
//! before `exec`, reaped with `waitpid`, signalled by group.

use std::ffi::OsString;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use farm::process::SUPERVISOR_PID_ENV;
use nix::sys::signal::{Signal, killpg};
use nix::sys::wait::{WaitPidFlag, WaitStatus, waitpid};
use nix::unistd::{Pid, getpid, getppid};

/// The environment a learner process starts with: torch's OpenMP threads (libgomp) spin briefly
/// at a barrier, then sleep, unless the user chose how they wait. Spinning long (libgomp's
/// default: 300,000 spins, milliseconds) costs nothing on idle cores but, where anything else runs
/// beside the learner (a build, a second training), the threads spin for a partner that is not
/// scheduled, and a training crawls. Sleeping at once pays a wake-up at each of the update's
/// many small operations; a short spin first keeps an idle machine's speed and a busy one's
/// (docs/bench/log.md, "OpenMP's bounded spin").
pub fn learner_env() -> Vec<(&'static str, String)> {
    omp_waiting(|name| std::env::var_os(name).is_some())
}

/// [`learner_env`]'s variables, given which of them the user has set.
fn omp_waiting(is_set: impl Fn(&str) -> bool) -> Vec<(&'static str, String)> {
    const WAIT: &str = "OMP_WAIT_POLICY";
    const SPINS: &str = "GOMP_SPINCOUNT";
    if is_set(WAIT) || is_set(SPINS) {
        return Vec::new();
    }
    vec![(WAIT, "PASSIVE".to_string()), (SPINS, "30000".to_string())]
}

/// How a child ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    Exited(i32),
    Killed(Signal),
}

impl Ended {
    pub fn success(self) -> bool {
        self == Ended::Exited(0)
    }
}

impl std::fmt::Display for Ended {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Ended::Exited(c) => write!(f, "exited with status {c}"),
            Ended::Killed(s) => write!(f, "was killed by {s}"),
        }
    }
}

/// A running child.
#[derive(Clone, Debug)]
pub struct Child {
    pub pid: Pid,
    pub started: Instant,
}

/// Starts `program args` with stdout and stderr appended to `log`, in a process group of its
/// own (a terminal's Ctrl-C reaches only the orchestrator, which then stops the children in
/// order), with `death_signal` delivered if the orchestrator dies.
pub fn spawn(
    program: &Path,
    args: &[OsString],
    env: &[(&str, String)],
    log: &Path,
    death_signal: Signal,
) -> std::io::Result<Child> {
    let out = std::fs::OpenOptions::new().create(true).append(true).open(log)?;
    let err = out.try_clone()?;
    let parent = getpid();
    let mut cmd = Command::new(program);
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(err)
        .process_group(0)
        .env(SUPERVISOR_PID_ENV, parent.to_string());
    cmd.envs(env.iter().map(|(k, v)| (k, v)));
    // SAFETY: runs in the forked child before exec; prctl and getppid are async-signal-safe
    // system calls, and nothing here allocates or takes locks.
    unsafe {
        cmd.pre_exec(move || {
            nix::sys::prctl::set_pdeathsig(death_signal).map_err(std::io::Error::from)?;
            if getppid() != parent {
                // The orchestrator died between fork and prctl: do not start at all.
                return Err(std::io::Error::other("the orchestrator is gone"));
            }
            Ok(())
        });
    }
    let child = cmd.spawn()?;
    Ok(Child { pid: Pid::from_raw(child.id() as i32), started: Instant::now() })
    // (The std handle is dropped without waiting: `reap` collects the exit status.)
}

/// The exit of `pid` if it has ended (the zombie is reaped), `None` while it runs.
pub fn reap(pid: Pid) -> Option<Ended> {
    match waitpid(pid, Some(WaitPidFlag::WNOHANG)) {
        Ok(WaitStatus::Exited(_, code)) => Some(Ended::Exited(code)),
        Ok(WaitStatus::Signaled(_, sig, _)) => Some(Ended::Killed(sig)),
        Ok(_) => None,
        // ECHILD: already reaped or not ours; treat as gone.
        Err(_) => Some(Ended::Exited(-1)),
    }
}

/// Sends `sig` to the child's process group (the child and anything it started).
pub fn signal(child: &Child, sig: Signal) {
    let _ = killpg(child.pid, sig);
}

/// The last `lines` lines of a log file, for error messages.
pub fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

/// CPU time (user + system) a process has used, in seconds, from `/proc/<pid>/stat`.
pub fn cpu_seconds(pid: Pid) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may contain spaces) start after the last ')'.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    Some(ticks as f64 / hz)
}

/// Busy and total CPU time of the whole machine so far, in seconds (`/proc/stat`), to tell how
/// much of a measurement window other processes took.
pub fn machine_cpu_seconds() -> Option<(f64, f64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat.lines().next()?.strip_prefix("cpu ")?;
    let v: Vec<u64> = line.split_whitespace().filter_map(|x| x.parse().ok()).collect();
    let total: u64 = v.iter().take(8).sum();
    let idle = v.get(3)? + v.get(4).unwrap_or(&0);
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    Some(((total - idle) as f64 / hz, total as f64 / hz))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_learner_spins_briefly_unless_the_user_chose_how_openmp_waits() {
        let chosen = |names: &'static [&'static str]| move |name: &str| names.contains(&name);
        let ours = omp_waiting(chosen(&[]));
        assert_eq!(ours, [("OMP_WAIT_POLICY", "PASSIVE".to_string()), ("GOMP_SPINCOUNT", "30000".to_string())]);
        // either of the user's overrules both of ours (libgomp reads the spin count over the policy)
        assert!(omp_waiting(chosen(&["OMP_WAIT_POLICY"])).is_empty());
        assert!(omp_waiting(chosen(&["GOMP_SPINCOUNT"])).is_empty());
    }

    #[test]
    fn spawn_reap_and_signal() {
        let d = tempfile::tempdir().unwrap();
        let log = d.path().join("x.log");
        let c = spawn(
            Path::new("/bin/sh"),
            &["-c".into(), "echo hello $X; exit 3".into()],
            &[("X", "world".into())],
            &log,
            Signal::SIGTERM,
        )
        .unwrap();
        let ended = loop {
            if let Some(e) = reap(c.pid) {
                break e;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        };
        assert_eq!(ended, Ended::Exited(3));
        assert_eq!(tail(&log, 5), "hello world");
        let c = spawn(Path::new("/bin/sleep"), &["30".into()], &[], &log, Signal::SIGTERM).unwrap();
        assert!(cpu_seconds(c.pid).is_some());
        let (busy, total) = machine_cpu_seconds().unwrap();
        assert!(busy <= total && total > 0.0);
        assert_eq!(reap(c.pid), None);
        signal(&c, Signal::SIGKILL);
        let ended = loop {
            if let Some(e) = reap(c.pid) {
                break e;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        };
        assert_eq!(ended, Ended::Killed(Signal::SIGKILL));
    }
}
