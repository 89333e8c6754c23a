//! `orchestrator eval`'s arguments.

use std::path::PathBuf;

use clap::Args;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A checkpoint file, a run directory (its latest complete checkpoint), or a shipped model
    /// (`models/both`; its evaluations go to runs/eval-models/NAME). Without it, the
    /// Random baseline is evaluated.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Evaluate the shortest-path expert instead of a checkpoint (an upper bound, and a check of
    /// the metrics: SR 100%, SPL close to 1).
    #[arg(long, conflicts_with = "checkpoint")]
    pub expert: bool,
    /// Take the checkpoint's most likely action at every step instead of sampling from the
    /// policy as in training (a greedy policy that never ranks Stop first never succeeds).
    #[arg(long)]
    pub greedy: bool,
    /// Only the programs of these rooms (e.g. a run's training rooms), comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Fold to evaluate on.
    #[arg(long, default_value = "test")]
    pub split: String,
    #[arg(long, default_value_t = 4, value_parser = crate::commands::values::workers)]
    pub workers: usize,
    /// Run configuration when there is no run directory to take it from (Random baseline).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dataset (default: the configuration's).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Evaluate only this many programs, spread evenly over the split (every room keeps its share).
    #[arg(long)]
    pub max_programs: Option<usize>,
    /// Passes to run: normal, blind, rgb_only, depth_only (default: all the checkpoint allows
    /// of these), other_gesture (every program shows another room's referencing gesture: is
    /// where the arm points read? Compared with normal program by program).
    #[arg(long, value_delimiter = ',')]
    pub modes: Vec<String>,
    /// DTS threshold in metres (the dissertation writes 1.5 m; success uses 1 m).
    #[arg(long, default_value_t = 1.5)]
    pub dts_threshold: f64,
    /// Where to write the tables (default: RUN/eval/<split>, or runs/eval-random|eval-expert/<split>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Name of the method in the tables (default: from the run's config).
    #[arg(long)]
    pub label: Option<String>,
    /// Draw this many episodes (trajectory map PNG + robot-view GIF) from the normal pass.
    #[arg(long, default_value_t = 0)]
    pub trajectories: usize,
    /// Override a config value, e.g. `--set ppo.lr=1e-4` (repeatable; checked as the file is;
    /// the effective config is the one written into the run directory).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Put earlier evaluations side by side instead (their output folders, or run directories);
    /// each after the first is also compared with it episode by episode (McNemar's test).
    #[arg(long, num_args = 1..)]
    pub compare: Vec<PathBuf>,
}
