//! A checkpoint acting for one session: a `learner act` child fed the worker's observation bytes
//! through a pipe, answering each with the action, the policy's probabilities and its value. The
//! orchestrator links no torch: the learner stays the one role that runs the network.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use anyhow::Context;
use serde::Deserialize;

use farm::config::RunConfig;

use crate::supervise::binaries;

/// A checkpoint as the server knows it: its file, its run's config and a name for the page.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    pub name: String,
    pub file: PathBuf,
    pub cfg: RunConfig,
    /// The run's config file (what the learner builds the network from).
    pub config: PathBuf,
}

impl Checkpoint {
    /// A checkpoint file, a run directory (its newest complete checkpoint) or a shipped model,
    /// with its run's config; errors name what was given.
    pub fn open(given: &Path) -> anyhow::Result<Checkpoint> {
        let (file, run) = crate::commands::eval::locate(given)?;
        let config = run.join("config.toml");
        let cfg =
            RunConfig::load(&config).with_context(|| format!("--checkpoint {}: its run's config", given.display()))?;
        let stem = file.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let run_name = run.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        // a shipped model by its folder (models/both), a run's checkpoint by run and update
        let name = match farm::models::is_model(&run) {
            true => format!("{}/{run_name}", farm::models::DIR),
            false => format!("{run_name}/{stem}"),
        };
        Ok(Checkpoint { name, file, cfg, config })
    }
}

/// What the policy answered (the learner's `serve::pipe::Answer`).
#[derive(Clone, Debug, Deserialize)]
pub struct Answer {
    pub action: u8,
    pub probs: Vec<f32>,
    pub value: f32,
}

/// The running `learner act`; killed when dropped (a closed tab frees it).
pub struct Policy {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    name: String,
    line: String,
}

impl Policy {
    /// Starts the learner on `c` with `config` (the run's), and waits until the checkpoint has
    /// loaded.
    pub fn start(c: &Checkpoint, config: &Path) -> anyhow::Result<Policy> {
        Policy::start_with(c, config, false)
    }

    /// [`Policy::start`]; `greedy`: the most likely action at every step instead of a sample.
    pub fn start_with(c: &Checkpoint, config: &Path, greedy: bool) -> anyhow::Result<Policy> {
        let learner = binaries::sibling("learner")?;
        let mut child = Command::new(&learner)
            .args(["--device", "cpu", "act", "--config"])
            .arg(config)
            .arg("--checkpoint")
            .arg(&c.file)
            .args(greedy.then_some("--greedy"))
            .env("RUST_LOG", "warn")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", learner.display()))?;
        let stdin = child.stdin.take().expect("piped");
        let stdout = BufReader::new(child.stdout.take().expect("piped"));
        let mut p = Policy { child, stdin, stdout, name: c.name.clone(), line: String::new() };
        p.read_line().with_context(|| format!("checkpoint {}", c.file.display()))?;
        Ok(p)
    }

    /// The policy's answer to one observation payload.
    pub fn act(&mut self, payload: &[u8]) -> anyhow::Result<Answer> {
        let sent =
            self.stdin.write_all(&(payload.len() as u64).to_le_bytes()).and_then(|_| self.stdin.write_all(payload));
        if let Err(e) = sent.and_then(|_| self.stdin.flush()) {
            return Err(self.failure(&e.to_string()));
        }
        self.read_line()?;
        serde_json::from_str(&self.line).with_context(|| format!("{}: the policy answered `{}`", self.name, self.line))
    }

    fn read_line(&mut self) -> anyhow::Result<()> {
        self.line.clear();
        match self.stdout.read_line(&mut self.line) {
            Ok(n) if n > 0 => Ok(()),
            Ok(_) => Err(self.failure("it exited")),
            Err(e) => Err(self.failure(&e.to_string())),
        }
    }

    /// Why the learner stopped answering: its own last line when it has one.
    fn failure(&mut self, what: &str) -> anyhow::Error {
        let _ = self.child.kill();
        let mut err = String::new();
        if let Some(mut s) = self.child.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut s, &mut err);
        }
        let _ = self.child.wait();
        let last = err.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or(what);
        anyhow::anyhow!("{}: {}", self.name, last.trim_start_matches("learner: "))
    }
}

impl Drop for Policy {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
