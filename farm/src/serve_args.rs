//! `learner serve`'s arguments as one typed struct: the learner parses it, the orchestrator
//! renders it into the command line it starts the learner with. One definition serves both
//! sides, so a flag renamed or added on one side cannot be missed on the other.

use std::ffi::OsString;
use std::path::PathBuf;

use clap::{Args, ValueEnum};

/// The policy a farm's learner serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Policy {
    /// PPO: act and learn.
    Ppo,
    /// Uniformly random actions (seeded from the run seed).
    Random,
    /// The shortest-path expert (workers compute it).
    Expert,
}

impl Policy {
    pub fn name(self) -> &'static str {
        match self {
            Policy::Ppo => "ppo",
            Policy::Random => "random",
            Policy::Expert => "expert",
        }
    }
}

/// Visual inputs to zero during evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Blank {
    Rgb,
    Depth,
    Both,
}

impl Blank {
    pub fn name(self) -> &'static str {
        match self {
            Blank::Rgb => "rgb",
            Blank::Depth => "depth",
            Blank::Both => "both",
        }
    }
}

/// Defaults of the learner's options, for the learner's parser and for its starters alike.
pub const BATCH_TIMEOUT_MS: u64 = 1000;
pub const REPORT_EVERY_S: f64 = 2.0;
pub const START_WAIT_S: f64 = 60.0;

#[derive(Args, Clone, Debug, PartialEq)]
pub struct ServeArgs {
    /// Run configuration (TOML).
    #[arg(long)]
    pub config: PathBuf,
    /// Run id (names the shared-memory services).
    #[arg(long)]
    pub run_id: String,
    /// Worker slots 0..N to serve.
    #[arg(long)]
    pub workers: usize,
    /// Run directory: farm.jsonl, episodes.jsonl, farm_summary.json (and checkpoints).
    #[arg(long)]
    pub run_dir: PathBuf,
    #[arg(long, value_enum, default_value_t = Policy::Random)]
    pub policy: Policy,
    /// Stop after this many frames.
    #[arg(long)]
    pub max_frames: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long)]
    pub max_seconds: Option<f64>,
    /// Evaluation: stop when every worker has finished its programs.
    #[arg(long)]
    pub eval: bool,
    /// Fail on any lost, duplicated or malformed message (tests).
    #[arg(long)]
    pub check: bool,
    /// Continue from the run directory's latest checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Close a batch this many milliseconds after its first observation even if workers are missing.
    #[arg(long, default_value_t = BATCH_TIMEOUT_MS)]
    pub batch_timeout_ms: u64,
    /// Seconds between progress records.
    #[arg(long, default_value_t = REPORT_EVERY_S)]
    pub report_every: f64,
    /// Before the first batch, wait up to this many seconds for every worker to connect.
    #[arg(long, default_value_t = START_WAIT_S)]
    pub start_wait: f64,
    #[command(flatten)]
    pub options: LearnerOptions,
}

/// What a caller adds to a farm's learner beyond what the farm itself decides: the checkpoint
/// an evaluation serves and how, or stage timing for `orchestrator bench train --stages`.
#[derive(Args, Clone, Debug, Default, PartialEq)]
pub struct LearnerOptions {
    /// Evaluate this checkpoint (with `--policy ppo --eval`) instead of training.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Evaluation: zero these visual inputs (blind mode: both; T4.7 ablations: one).
    #[arg(long, value_enum)]
    pub blank: Option<Blank>,
    /// Evaluation: take the policy's most likely action instead of sampling it.
    #[arg(long)]
    pub greedy: bool,
    /// PPO training: time acting and updates stage by stage into the progress records, waiting
    /// for the device after each stage (slower; `orchestrator bench train --stages`).
    #[arg(long)]
    pub profile_stages: bool,
}

impl ServeArgs {
    /// The arguments with every option at its default.
    pub fn new(config: PathBuf, run_id: String, workers: usize, run_dir: PathBuf, policy: Policy) -> ServeArgs {
        ServeArgs {
            config,
            run_id,
            workers,
            run_dir,
            policy,
            max_frames: None,
            max_seconds: None,
            eval: false,
            check: false,
            resume: false,
            batch_timeout_ms: BATCH_TIMEOUT_MS,
            report_every: REPORT_EVERY_S,
            start_wait: START_WAIT_S,
            options: LearnerOptions::default(),
        }
    }

    /// The command line `learner serve` parses back into `self` (after the word `serve`).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut a = Line::default();
        a.value("--config", self.config.clone());
        a.value("--run-id", &self.run_id);
        a.value("--workers", self.workers.to_string());
        a.value("--run-dir", self.run_dir.clone());
        a.value("--policy", self.policy.name());
        a.maybe("--max-frames", self.max_frames);
        a.maybe("--max-seconds", self.max_seconds);
        a.flag("--eval", self.eval);
        a.flag("--check", self.check);
        a.flag("--resume", self.resume);
        a.value("--batch-timeout-ms", self.batch_timeout_ms.to_string());
        a.value("--report-every", self.report_every.to_string());
        a.value("--start-wait", self.start_wait.to_string());
        let o = &self.options;
        if let Some(p) = &o.checkpoint {
            a.value("--checkpoint", p.clone());
        }
        a.maybe("--blank", o.blank.map(Blank::name));
        a.flag("--greedy", o.greedy);
        a.flag("--profile-stages", o.profile_stages);
        a.0
    }
}

#[derive(Default)]
struct Line(Vec<OsString>);

impl Line {
    fn value(&mut self, flag: &str, v: impl Into<OsString>) {
        self.0.extend([flag.into(), v.into()]);
    }
    fn maybe(&mut self, flag: &str, v: Option<impl ToString>) {
        if let Some(v) = v {
            self.value(flag, v.to_string());
        }
    }
    fn flag(&mut self, flag: &str, on: bool) {
        if on {
            self.0.push(flag.into());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        a: ServeArgs,
    }

    fn round_trip(a: &ServeArgs) -> ServeArgs {
        let line = std::iter::once(OsString::from("serve")).chain(a.to_args());
        Cli::try_parse_from(line).expect("the rendered line parses").a
    }

    #[test]
    fn defaults_round_trip() {
        let a = ServeArgs::new("run/config.toml".into(), "r1".into(), 4, "run".into(), Policy::Random);
        assert_eq!(round_trip(&a), a);
    }

    #[test]
    fn every_field_round_trips() {
        let mut a = ServeArgs::new("a dir/c.toml".into(), "run-7".into(), 20, "/tmp/a run".into(), Policy::Ppo);
        a.max_frames = Some(1_000_000);
        a.max_seconds = Some(12.5);
        a.eval = true;
        a.check = true;
        a.resume = true;
        a.batch_timeout_ms = 250;
        a.report_every = 0.5;
        a.start_wait = 3.25;
        a.options = LearnerOptions {
            checkpoint: Some("ckpt/000976".into()),
            blank: Some(Blank::Depth),
            greedy: true,
            profile_stages: true,
        };
        assert_eq!(round_trip(&a), a);
        for (p, b) in [(Policy::Expert, Blank::Rgb), (Policy::Random, Blank::Both)] {
            a.policy = p;
            a.options.blank = Some(b);
            assert_eq!(round_trip(&a), a);
        }
    }
}
