//! The run directory: one folder per run holding its config, logs, metrics and checkpoints,
//! locked while a run is live so that two runs never write into the same one.
//!
//! ```text
//! RUN/
//!   .lock               flock'd by the live orchestrator (the kernel drops it when it dies)
//!   run.json            run id, pid, start time, command line (the Python reader finds the run id here)
//!   config.toml         the run configuration, dataset path made absolute
//!   logs/learner.log    stderr of the learner; logs/worker-K.log of worker K, every generation
//!   farm.jsonl          learner progress records
//!   episodes.jsonl      one line per finished episode
//!   farm_summary.json   totals written when the learner ends
//!   programs/           per-worker program lists (evaluation)
//! ```

use std::fs::File;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::Context;
use nix::fcntl::{Flock, FlockArg};
use serde::{Deserialize, Serialize};

/// What `run.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    pub run_id: String,
    pub pid: u32,
    /// Seconds since the Unix epoch.
    pub started: u64,
    pub workers: usize,
    pub policy: String,
    pub command: Vec<String>,
}

/// A locked run directory. The lock lasts as long as this value (and the process).
pub struct RunDir {
    pub path: PathBuf,
    pub run_id: String,
    _lock: Flock<File>,
}

impl RunDir {
    /// Creates (or reopens, for `--resume`) `path` and takes its lock. Fails with a clear
    /// message when another live run holds it; a lock left by a dead run is simply taken over.
    pub fn open(path: &Path) -> anyhow::Result<RunDir> {
        // Private to the user: checkpoints and logs are nobody else's to read or change.
        use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(path.join("logs"))
            .with_context(|| format!("creating run directory {}", path.display()))?;
        for d in [path.to_path_buf(), path.join("logs")] {
            std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o700))
                .with_context(|| format!("making {} private (0700)", d.display()))?;
        }
        let lock_path = path.join(".lock");
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&lock_path)
            .with_context(|| format!("opening {}", lock_path.display()))?;
        let mut lock = match Flock::lock(file, FlockArg::LockExclusiveNonblock) {
            Ok(l) => l,
            Err((mut f, errno)) => {
                let mut holder = String::new();
                let _ = f.read_to_string(&mut holder);
                anyhow::bail!(
                    "run directory {} is in use by a live run (orchestrator pid {}): {errno}; pick another --run-dir",
                    path.display(),
                    holder.trim()
                );
            }
        };
        lock.set_len(0)?;
        lock.rewind()?;
        write!(lock, "{}", std::process::id())?;
        lock.flush()?;
        let path = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
        let run_id = make_run_id(&path);
        Ok(RunDir { path, run_id, _lock: lock })
    }

    pub fn logs(&self) -> PathBuf {
        self.path.join("logs")
    }

    pub fn config_path(&self) -> PathBuf {
        self.path.join("config.toml")
    }

    pub fn write_info(&self, workers: usize, policy: &str) -> anyhow::Result<()> {
        // The previous session of this folder is dead (we hold its lock): whatever its
        // shared memory left (an orchestrator killed with SIGKILL) goes now, not a minute later.
        if let Some(prev) = self.previous_run_id()
            && prev != self.run_id
            && let Ok(left) = farm::transport::end_run_domain(&prev)
            && !left.is_empty()
        {
            eprintln!("[up] removed {} shared-memory file(s) of the previous session {prev}", left.len());
        }
        let info = RunInfo {
            run_id: self.run_id.clone(),
            pid: std::process::id(),
            started: now_secs(),
            workers,
            policy: policy.into(),
            command: std::env::args().collect(),
        };
        let p = self.path.join("run.json");
        farm::files::write_atomic(&p, serde_json::to_string_pretty(&info)?.as_bytes())
            .with_context(|| format!("writing {}", p.display()))
    }
}

impl RunDir {
    /// The run id in `run.json` before this session rewrites it.
    fn previous_run_id(&self) -> Option<String> {
        let text = std::fs::read_to_string(self.path.join("run.json")).ok()?;
        serde_json::from_str::<RunInfo>(&text).ok().map(|i| i.run_id)
    }
}

/// The `run.json` of run folder `run`.
pub fn read_info(run: &Path) -> anyhow::Result<RunInfo> {
    let p = run.join("run.json");
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("{}: not a run folder (no run.json)", run.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not a run.json of this version", p.display()))
}

/// The `run.json` that process `pid` wrote into `run`, once it is there (a folder used before
/// holds an older one, of another process); an error after `patience`.
pub fn wait_for_info(run: &Path, pid: u32, patience: std::time::Duration) -> anyhow::Result<RunInfo> {
    let t = std::time::Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(run.join("run.json"))
            && let Ok(info) = serde_json::from_str::<RunInfo>(&text)
            && info.pid == pid
        {
            return Ok(info);
        }
        anyhow::ensure!(t.elapsed() < patience, "the run in {} did not start within {patience:?}", run.display());
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}

pub fn now_secs() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0)
}

/// A run id unique on this host: the folder's name (shortened to a slug) and a hash of its
/// full path, this process and the time. It names the shared-memory services and files.
pub fn make_run_id(path: &Path) -> String {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let mut slug: String =
        name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '-' }).collect();
    slug = slug.trim_matches('-').chars().take(20).collect();
    if slug.is_empty() {
        slug = "run".into();
    }
    let nanos = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
    let mut key: Vec<u64> = path.to_string_lossy().bytes().map(u64::from).collect();
    key.extend([std::process::id() as u64, nanos]);
    let h = farm::seed::mix(0x6E57_0000, &key);
    format!("{slug}-{:08x}", h as u32)
}

/// A default run folder under `runs/`: `runs/<prefix>-YYYYMMDD-HHMMSS` (UTC).
pub fn default_path(prefix: &str) -> PathBuf {
    PathBuf::from("runs").join(format!("{prefix}-{}", utc_stamp(now_secs())))
}

/// `YYYYMMDD-HHMMSS` of a Unix time, UTC (days → civil date after H. Hinnant's algorithm).
pub fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!("{y:04}{m:02}{d:02}-{:02}{:02}{:02}", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_live_run_is_refused_and_a_dead_runs_lock_is_taken_over() {
        let d = tempfile::tempdir().unwrap();
        let first = RunDir::open(d.path()).unwrap();
        let err = RunDir::open(d.path()).err().unwrap().to_string();
        assert!(err.contains("in use by a live run") && err.contains(&std::process::id().to_string()), "{err}");
        drop(first); // the process of the first run "died": its lock is gone
        let again = RunDir::open(d.path()).unwrap();
        assert!(again.logs().is_dir());
    }

    #[test]
    fn run_directories_are_private() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempfile::tempdir().unwrap();
        let run = d.path().join("runs").join("x");
        let r = RunDir::open(&run).unwrap();
        for p in [&run, &r.logs()] {
            assert_eq!(std::fs::metadata(p).unwrap().permissions().mode() & 0o777, 0o700, "{}", p.display());
        }
        // an existing world-readable one (an older run resumed) is made private too
        drop(r);
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o755)).unwrap();
        let _r = RunDir::open(&run).unwrap();
        assert_eq!(std::fs::metadata(&run).unwrap().permissions().mode() & 0o777, 0o700);
    }

    #[test]
    fn run_ids_are_slugs_and_differ() {
        let a = make_run_id(Path::new("/x/My Run_01"));
        let b = make_run_id(Path::new("/y/My Run_01"));
        assert!(a.starts_with("my-run-01-"), "{a}");
        assert_ne!(a, b);
        assert!(a.chars().all(|c| c.is_ascii_alphanumeric() || c == '-'));
    }

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        assert_eq!(utc_stamp(1_795_000_000), "20261118-110640");
    }
}
