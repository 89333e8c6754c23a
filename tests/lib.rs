//! Helpers of the workspace-level tests: find the real executables, make (once) a small
//! dataset, start `orchestrator up` runs and watch them from outside, as a user would.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Mutex, MutexGuard, OnceLock};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

/// The folder holding `orchestrator`, `worker` and `learner`: `$GESTHOR_BIN_DIR`, else the
/// cargo profile folder this test executable lives under (`target/release/deps/..`).
pub fn bin_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("GESTHOR_BIN_DIR") {
        return PathBuf::from(d);
    }
    let exe = std::env::current_exe().expect("current exe");
    let deps = exe.parent().expect("deps folder");
    deps.parent().unwrap_or(deps).to_path_buf()
}

pub fn bin(name: &str) -> PathBuf {
    let p = bin_dir().join(name);
    assert!(
        p.is_file(),
        "{} is missing: run `cargo build --release --workspace` first (or set GESTHOR_BIN_DIR)",
        p.display()
    );
    p
}

/// One farm test at a time: they are multi-process and CPU-bound on a small machine.
pub fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// A small dataset for the tests, built once per build of the orchestrator with
/// `orchestrator dataset build` (about a second) and cached beside the binaries
/// (`target/release/gesthor-test-data/`), or `$GESTHOR_TEST_DATASET` when set.
pub fn dataset() -> PathBuf {
    static DATA: OnceLock<PathBuf> = OnceLock::new();
    DATA.get_or_init(|| match std::env::var_os("GESTHOR_TEST_DATASET") {
        Some(d) => PathBuf::from(d),
        None => built_dataset("gond", &["--train", "40", "--val-per-room", "1", "--test-per-room", "1", "--seed", "3"]),
    })
    .clone()
}

/// GOND as `dataset build` makes it by default (what the shipped models were evaluated on),
/// built once per build of the orchestrator (about 5 seconds) beside the binaries.
pub fn default_dataset() -> PathBuf {
    static DATA: OnceLock<PathBuf> = OnceLock::new();
    DATA.get_or_init(|| built_dataset("default", &[])).clone()
}

/// `orchestrator dataset build ARGS` into `gesthor-test-data/TAG-<build>`, unless there already.
fn built_dataset(tag: &str, args: &[&str]) -> PathBuf {
    // Keyed on the orchestrator build, so a changed dataset format is never read stale.
    let orch = bin("orchestrator");
    let meta = std::fs::metadata(&orch).unwrap();
    let stamp = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let root = bin_dir().join("gesthor-test-data");
    let dir = root.join(format!("{tag}-{stamp}-{}", meta.len()));
    if dir.join("manifest.json").is_file() {
        return dir;
    }
    let tmp = dir.with_extension(format!("partial{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let out = Command::new(&orch)
        .args(["dataset", "build", "--out"])
        .arg(&tmp)
        .args(args)
        .output()
        .expect("running orchestrator dataset build");
    assert!(
        out.status.success() && tmp.join("manifest.json").is_file(),
        "building the test dataset failed ({}):\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    match std::fs::rename(&tmp, &dir) {
        Ok(()) => {
            // datasets of older builds are of no use any more
            let prefix = format!("{tag}-");
            for e in std::fs::read_dir(&root).into_iter().flatten().flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if e.path() != dir && name.starts_with(&prefix) && !name.contains("partial") {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        // another test process got there first
        Err(_) if dir.join("manifest.json").is_file() => {
            let _ = std::fs::remove_dir_all(&tmp);
        }
        Err(e) => panic!("moving the test dataset into place: {e}"),
    }
    dir
}

/// Writes a small run config (64×64 frames, `envs` envs per worker) into `dir`.
pub fn tiny_config(dir: &Path, envs: usize) -> PathBuf {
    let p = dir.join("tiny.toml");
    let text = format!(
        "[run]\nmethod = \"both\"\nseed = 7\ndataset = \"{}\"\n\n[env]\nenvs_per_worker = {envs}\nwidth = 64\nheight = 64\n",
        dataset().display()
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// `dir/small.toml`: +Both with a small PPO network (trained small CNN, GRU 32) on 32×32 frames
/// of the test dataset, 2 envs per worker, rollouts of 16 steps; `ppo_tail` is appended inside
/// `[ppo]` (further keys, then other sections).
pub fn small_ppo_config(dir: &Path, ppo_tail: &str) -> PathBuf {
    let p = dir.join("small.toml");
    let text = format!(
        "[run]\nmethod = \"both\"\nseed = 7\ndataset = \"{}\"\n\n[env]\nenvs_per_worker = 2\nwidth = 32\nheight = 32\n\n\
         [model]\nencoder = \"small_cnn\"\nhidden = 32\ngru_layers = 1\n\n[ppo]\nrollout = 16\n{ppo_tail}",
        dataset().display()
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// A live `orchestrator up`, watched from outside. Killed (with its children) when dropped.
pub struct Run {
    pub dir: PathBuf,
    pub log: PathBuf,
    child: Option<Child>,
    pub status: Option<ExitStatus>,
}

impl Run {
    /// `orchestrator up --run-dir <dir> <args>`; its output goes to `<dir>.log`.
    pub fn start(dir: &Path, args: &[&str]) -> Run {
        let log = dir.with_extension("log");
        let out = std::fs::File::create(&log).unwrap();
        let child = Command::new(bin("orchestrator"))
            .arg("up")
            .arg("--run-dir")
            .arg(dir)
            .args(args)
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .spawn()
            .expect("starting orchestrator up");
        Run { dir: dir.to_path_buf(), log, child: Some(child), status: None }
    }

    pub fn pid(&self) -> Pid {
        Pid::from_raw(self.child.as_ref().expect("running").id() as i32)
    }

    pub fn output(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// What went wrong, for assertion messages: the orchestrator's output and the learner log.
    pub fn diagnostics(&self) -> String {
        let learner = std::fs::read_to_string(self.dir.join("logs/learner.log")).unwrap_or_default();
        let tail: Vec<&str> = learner.lines().rev().take(15).collect::<Vec<_>>().into_iter().rev().collect();
        format!("--- orchestrator ---\n{}\n--- learner.log (tail) ---\n{}", self.output(), tail.join("\n"))
    }

    pub fn run_id(&self) -> String {
        let text = std::fs::read_to_string(self.dir.join("run.json")).expect("run.json");
        let info: orchestrator::supervise::run_dir::RunInfo = serde_json::from_str(&text).unwrap();
        info.run_id
    }

    /// The learner's latest progress record.
    pub fn progress(&self) -> Option<Value> {
        let text = std::fs::read_to_string(self.dir.join("farm.jsonl")).ok()?;
        text.lines().rev().find_map(|l| serde_json::from_str(l).ok())
    }

    /// Waits until the latest progress record satisfies `pred`; panics with diagnostics.
    pub fn wait_progress(&mut self, timeout: Duration, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let start = Instant::now();
        loop {
            if let Some(p) = self.progress()
                && pred(&p)
            {
                return p;
            }
            if let Some(s) = self.try_wait() {
                panic!("the run ended ({s}) before {what}\n{}", self.diagnostics());
            }
            assert!(start.elapsed() < timeout, "no {what} within {timeout:?}\n{}", self.diagnostics());
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Waits until the orchestrator's output contains `text`; panics with diagnostics.
    pub fn wait_output(&mut self, timeout: Duration, text: &str) {
        let start = Instant::now();
        while !self.output().contains(text) {
            if let Some(s) = self.try_wait() {
                panic!("the run ended ({s}) before saying `{text}`\n{}", self.diagnostics());
            }
            assert!(start.elapsed() < timeout, "no `{text}` within {timeout:?}\n{}", self.diagnostics());
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    pub fn try_wait(&mut self) -> Option<ExitStatus> {
        if self.status.is_none()
            && let Some(c) = &mut self.child
            && let Ok(Some(s)) = c.try_wait()
        {
            self.status = Some(s);
            self.child = None;
        }
        self.status
    }

    /// Waits for the orchestrator to exit; panics after `timeout`.
    pub fn wait(&mut self, timeout: Duration) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(s) = self.try_wait() {
                return s;
            }
            assert!(start.elapsed() < timeout, "orchestrator still running after {timeout:?}\n{}", self.diagnostics());
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn signal(&self, sig: Signal) {
        kill(self.pid(), sig).unwrap();
    }

    /// Processes started for this run (learner and workers): their command line names the
    /// run directory's config copy.
    pub fn processes(&self) -> Vec<(i32, String)> {
        let dir = self.dir.canonicalize().unwrap_or(self.dir.clone());
        processes_mentioning(&dir.join("config.toml").display().to_string())
    }

    /// The pid of worker `k`'s current process.
    pub fn worker_pid(&self, k: u32) -> Option<i32> {
        let key = format!(" --worker-id {k} ");
        self.processes().into_iter().find(|(_, c)| c.contains(&key) && c.contains("worker ")).map(|(p, _)| p)
    }

    pub fn summary(&self) -> Value {
        let p = self.dir.join("farm_summary.json");
        serde_json::from_str(
            &std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}\n{}", p.display(), self.diagnostics())),
        )
        .unwrap()
    }

    pub fn episodes(&self) -> Vec<Value> {
        std::fs::read_to_string(self.dir.join("episodes.jsonl"))
            .unwrap_or_default()
            .lines()
            .map(|l| serde_json::from_str(l).expect("episode line"))
            .collect()
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(c) = &mut self.child {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

pub use orchestrator::commands::soak::processes_mentioning;

/// Files the run left in `/dev/shm` (and iceoryx2's folder).
pub fn shm_leftovers(run_id: &str) -> Vec<PathBuf> {
    farm::transport::run_files(run_id)
}

/// `(width, height)` from a PNG's IHDR, after checking the signature.
pub fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "not a PNG: {}", path.display());
    assert_eq!(&b[12..16], b"IHDR");
    (u32::from_be_bytes(b[16..20].try_into().unwrap()), u32::from_be_bytes(b[20..24].try_into().unwrap()))
}

/// `python3` with the project's Python packages (setup.sh's folder) on its path, when it can
/// import every one of `modules`; why not otherwise.
pub fn python_with(modules: &[&str]) -> Result<Command, String> {
    let mut path = std::env::var("PYTHONPATH").unwrap_or_default();
    if let Some(home) = std::env::var_os("HOME") {
        let deps = std::env::var_os("GESTHOR_DEPS")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(home).join(".cache/gesthor"));
        let py = deps.join("python");
        if py.is_dir() {
            path = if path.is_empty() { py.display().to_string() } else { format!("{path}:{}", py.display()) };
        }
    }
    let import = format!("import {}", modules.join(", "));
    let probe = Command::new("python3").env("PYTHONPATH", &path).args(["-c", &import]).output();
    let why = match probe {
        Err(e) => format!("no python3 ({e})"),
        Ok(o) if !o.status.success() => {
            format!("python3 cannot `{import}`: {}", String::from_utf8_lossy(&o.stderr).trim())
        }
        Ok(_) => {
            let mut c = Command::new("python3");
            c.env("PYTHONPATH", path);
            return Ok(c);
        }
    };
    // Where setup.sh installed the packages (its env.sh says so, and CI runs it), a test that
    // needs them fails instead of skipping.
    if std::env::var_os("CI").is_some() || std::env::var_os("GESTHOR_PYTHON_REQUIRED").is_some_and(|v| v == "1") {
        panic!("{why} (scripts/setup.sh installs the packages)");
    }
    Err(why)
}

/// The repository's root (the tests crate's parent folder).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// Whether `orchestrator gesture capture` finds its landmark model (MediaPipe, which setup.sh
/// installs into its `capture` folder); where setup.sh ran, a missing one fails the test.
pub fn capture_ready() -> bool {
    let path = std::env::var("GESTHOR_CAPTURE_PATH").unwrap_or_else(|_| {
        let deps = std::env::var_os("GESTHOR_DEPS")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/gesthor"));
        deps.join("capture").display().to_string()
    });
    let probe = Command::new("python3").env("PYTHONPATH", &path).args(["-c", "import mediapipe, cv2"]).output();
    if probe.as_ref().is_ok_and(|o| o.status.success()) {
        return true;
    }
    let why = match probe {
        Err(e) => format!("no python3 ({e})"),
        Ok(o) => String::from_utf8_lossy(&o.stderr).trim().lines().last().unwrap_or_default().to_string(),
    };
    if std::env::var_os("CI").is_some() || std::env::var_os("GESTHOR_PYTHON_REQUIRED").is_some_and(|v| v == "1") {
        panic!("MediaPipe is not importable from {path}: {why} (scripts/setup.sh installs it)");
    }
    eprintln!("skipped: MediaPipe is not importable from {path}: {why}");
    false
}
