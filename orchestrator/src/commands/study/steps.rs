//! A step of the study: a child `orchestrator up` or `orchestrator eval` (this binary) run to
//! its end, with the study's termination signals forwarded to it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use farm::rooms::Split;
use nix::sys::signal::Signal;

use super::progress::{Kind, Lane};
use crate::supervise::child;

/// Runs `orchestrator ARGS` (this binary) to the end; a child stopped by a signal stops the study.
pub fn orchestrator(args: &[String], log: &Path) -> anyhow::Result<()> {
    // a signal that came between two steps (or while another lane's step ran) starts no other
    stopped()?;
    if let Some(parent) = log.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let exe = std::env::current_exe().context("finding the orchestrator binary")?;
    let argv: Vec<std::ffi::OsString> = args.iter().map(Into::into).collect();
    // Like `up`'s own children: a study killed outright stops its step too (SIGTERM: `up` then
    // writes its checkpoint), so no orphan keeps writing into the folder the rerun continues;
    // and the step, in a process group of its own, gets each termination signal the study gets,
    // once: a `kill` of the study alone stops the step (it used to run to its end), and a Ctrl-C,
    // which reaches only the study's group, still arrives once, as from a terminal (a second
    // Ctrl-C means "now" to `up`, so it must not arrive twice). Each lane (`--parallel`) counts
    // its own, so every step in flight gets each signal once.
    let step =
        child::spawn(&exe, &argv, &[], log, Signal::SIGTERM).with_context(|| format!("starting {}", exe.display()))?;
    let mut forwarded = 0;
    let ended = loop {
        if let Some(ended) = child::reap(step.pid) {
            break ended;
        }
        while forwarded < farm::process::termination_count() {
            if let Some(sig) = farm::process::termination_signal() {
                child::signal(&step, sig);
            }
            forwarded += 1;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    stopped()?;
    anyhow::ensure!(ended.success(), "`orchestrator {}` failed ({ended}); see {}", args.join(" "), log.display());
    Ok(())
}

pub fn s(p: &Path) -> String {
    p.display().to_string()
}

/// An error once a termination signal has come: the study stops, to be continued by the same
/// command.
pub fn stopped() -> anyhow::Result<()> {
    anyhow::ensure!(
        farm::process::termination_count() == 0,
        "stopped by a signal; run the same command again to continue"
    );
    Ok(())
}

/// One `orchestrator eval` of the study.
pub struct Eval<'a> {
    /// `--checkpoint FILE` or `--config FILE`, and any other arguments of `eval`.
    pub what: Vec<String>,
    pub split: Split,
    pub programs: usize,
    pub modes: &'a [&'a str],
    /// Only these rooms (empty: the split's all).
    pub rooms: Vec<String>,
    pub out: PathBuf,
}

impl Eval<'_> {
    pub fn work(&self) -> f64 {
        (self.programs * self.modes.len()) as f64
    }

    /// Its tables are there, with a row of every pass.
    fn complete(&self) -> bool {
        crate::report::tables::read_rows(&self.out.join("tables.csv"))
            .is_ok_and(|rows| self.modes.iter().all(|m| rows.iter().any(|r| r.mode == *m)))
    }

    /// Runs it unless complete (a partial one is redone); whether it ran.
    pub fn run(&self, workers: usize) -> anyhow::Result<bool> {
        if self.complete() {
            return Ok(false);
        }
        if self.out.exists() {
            std::fs::remove_dir_all(&self.out).with_context(|| format!("clearing {}", self.out.display()))?;
        }
        let mut args: Vec<String> = vec!["eval".into()];
        args.extend(self.what.iter().cloned());
        args.extend(
            [
                "--split",
                self.split.name(),
                "--max-programs",
                &self.programs.to_string(),
                "--modes",
                &self.modes.join(","),
                "--workers",
                &workers.to_string(),
                "--out",
                &s(&self.out),
            ]
            .map(String::from),
        );
        if !self.rooms.is_empty() {
            args.extend(["--scenes".into(), self.rooms.join(",")]);
        }
        orchestrator(&args, &self.out.with_extension("log"))?;
        Ok(true)
    }
}

/// Runs `e` with `workers` workers and counts it as a step of `lane`.
pub fn evaluate(workers: usize, e: &Eval, lane: &Lane, what: &str) -> anyhow::Result<bool> {
    lane.doing(what);
    let t = Instant::now();
    let ran = e.run(workers)?;
    lane.step(Kind::Eval, e.work(), ran.then(|| t.elapsed().as_secs_f64()), what);
    Ok(ran)
}
