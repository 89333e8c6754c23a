//! Process plumbing shared by the farm's roles (worker, learner, orchestrator): termination
//! requests by signal, and the parent-death signal that keeps a child from outliving its
//! supervisor.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicI32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};

/// Environment variable the orchestrator sets to its own pid in every child, so that a child can
/// tell whether its supervisor died before the parent-death signal was armed.
pub const SUPERVISOR_PID_ENV: &str = "GESTHOR_SUPERVISOR_PID";

static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);
static SIGNAL_COUNT: AtomicI32 = AtomicI32::new(0);
/// Nanoseconds after [`EPOCH`] at which the role's time budget ends (0: none).
static DEADLINE_NS: AtomicU64 = AtomicU64::new(0);
static EPOCH: OnceLock<Instant> = OnceLock::new();

/// Sets the role's time budget: [`deadline_passed`] is true `after` from now.
pub fn set_deadline(after: Duration) {
    let epoch = *EPOCH.get_or_init(Instant::now);
    let at = epoch.elapsed() + after;
    DEADLINE_NS.store((at.as_nanos() as u64).max(1), Ordering::SeqCst);
}

/// Whether the time budget set by [`set_deadline`] has run out.
pub fn deadline_passed() -> bool {
    let at = DEADLINE_NS.load(Ordering::SeqCst);
    at != 0 && EPOCH.get().is_some_and(|e| e.elapsed().as_nanos() as u64 >= at)
}

/// Whether the role should stop what it is doing: a termination signal, or the time budget spent.
pub fn stop_requested() -> bool {
    termination_signal().is_some() || deadline_passed()
}

extern "C" fn on_signal(sig: std::ffi::c_int) {
    // Only atomics: async-signal-safe.
    LAST_SIGNAL.store(sig, Ordering::SeqCst);
    SIGNAL_COUNT.fetch_add(1, Ordering::SeqCst);
}

/// Routes SIGINT and SIGTERM to a flag that the role's loop polls ([`termination_signal`]).
/// Installed without `SA_RESTART`, so a blocking wait returns early when a signal arrives.
pub fn install_termination_handler() -> nix::Result<()> {
    let action = SigAction::new(SigHandler::Handler(on_signal), SaFlags::empty(), SigSet::empty());
    for sig in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only touches atomics.
        unsafe { sigaction(sig, &action) }?;
    }
    Ok(())
}

/// The last termination signal received, if any.
pub fn termination_signal() -> Option<Signal> {
    match LAST_SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Signal::try_from(s).ok(),
    }
}

/// How many termination signals arrived (a second Ctrl-C means "now").
pub fn termination_count() -> i32 {
    SIGNAL_COUNT.load(Ordering::SeqCst)
}

/// The exit status a process reports when it stops because of `sig` (shell convention 128+n).
pub fn signal_exit_code(sig: Signal) -> i32 {
    128 + sig as i32
}

/// Asks the kernel to send `sig` to this process when its parent dies, and exits at once if
/// the supervisor named in [`SUPERVISOR_PID_ENV`] is already gone (the race between fork and
/// `prctl`). The orchestrator also arms this in its `pre_exec` hook; arming it again is harmless.
pub fn die_with_parent(sig: Signal) -> nix::Result<()> {
    nix::sys::prctl::set_pdeathsig(sig)?;
    if let Some(pid) = std::env::var(SUPERVISOR_PID_ENV).ok().and_then(|s| s.parse::<i32>().ok())
        && nix::unistd::getppid().as_raw() != pid
    {
        eprintln!("supervisor (pid {pid}) is gone; exiting");
        std::process::exit(signal_exit_code(sig));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_codes_follow_the_shell_convention() {
        // (Raising a real signal here would set the process-wide flag for every other test of
        // this binary; the integration tests in tests/ signal real processes instead.)
        assert_eq!(signal_exit_code(Signal::SIGTERM), 143);
    }

    #[test]
    fn a_time_budget_runs_out() {
        set_deadline(Duration::from_secs(3600));
        assert!(!deadline_passed());
        set_deadline(Duration::ZERO);
        assert!(deadline_passed() && stop_requested());
        assert_eq!(signal_exit_code(Signal::SIGINT), 130);
        assert_eq!(termination_signal(), None);
    }
}
