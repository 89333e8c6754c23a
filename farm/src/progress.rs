//! One line of a run's `farm.jsonl`: the learner writes a [`Progress`] every report interval
//! (and a final one); the orchestrator reads the newest to show and decide. Fields missing from
//! a line read as their defaults.

use serde::{Deserialize, Serialize};

/// Running totals of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Counters {
    /// Env observations of envs that were running (idle envs of finished evaluations excluded).
    pub frames: u64,
    /// Observations (messages) accepted.
    pub messages: u64,
    pub rounds: u64,
    pub episodes: u64,
    pub successes: u64,
    /// Workers that came back with a new generation.
    pub restarts: u64,
    /// Messages or env steps skipped within a generation.
    pub lost: u64,
    /// Messages or env steps seen twice (or going backwards) within a generation.
    pub duplicates: u64,
    /// Messages with a bad header or layout.
    pub corrupt: u64,
    /// Messages of an older generation, dropped.
    pub stale: u64,
    /// Sum and count of step round trips: action sent → the worker's next observation received.
    pub latency_sum_s: f64,
    pub latency_count: u64,
    /// Time spent in the policy.
    pub policy_sum_s: f64,
}

/// One line of `farm.jsonl`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Progress {
    /// Seconds since the server started.
    pub t: f64,
    /// Frames per second over the last report window.
    pub fps: f64,
    /// Mean step round trip (ms) over the last window.
    pub latency_ms: Option<f64>,
    pub success_rate: Option<f64>,
    /// Workers seen at least once / answering at the moment.
    pub workers_seen: usize,
    pub workers_live: usize,
    #[serde(flatten)]
    pub totals: Counters,
    /// Set on the last line.
    pub stop_reason: Option<String>,
    /// Where the time went so far: the learner's timeline and its workers' loops.
    pub profile: crate::profile::Profile,
}
