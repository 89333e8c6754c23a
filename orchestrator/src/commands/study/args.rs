//! `orchestrator study`'s arguments.

use std::path::PathBuf;

use clap::Args;

#[derive(Args, Debug, Clone)]
pub struct StudyArgs {
    /// Folder of run configs named after the methods (vision_only, vis_sem, referencing,
    /// intervention, both, random; T4.7's rgb_sem_both and depth_sem_both), e.g. configs/tiny.
    #[arg(long)]
    pub configs: PathBuf,
    /// Seeds per method (1..=N, each the config's seed plus k − 1).
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Frames to train each run for.
    #[arg(long)]
    pub frames: u64,
    /// The study folder (created; an existing one is continued).
    #[arg(long)]
    pub out: PathBuf,
    /// Only these methods (config file stems), comma-separated, trained in this order (seed by
    /// seed); default: every one present, in T4.2's order.
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Also train VisSem, +Referencing and +Intervention once per scene type, in that type's
    /// rooms only, as the dissertation does for T4.3/T4.4 (12 more runs per seed).
    #[arg(long)]
    pub per_scene_type: bool,
    #[arg(long, default_value_t = 4, value_parser = crate::commands::values::workers)]
    pub workers: usize,
    /// Checkpoints per run to choose from on val (evenly spaced; the last one always).
    #[arg(long, default_value_t = 5)]
    pub checkpoints: u64,
    /// Val programs per checkpoint evaluation (spread over the val rooms); as many train
    /// programs evaluate the selected checkpoint on train (T4.3).
    #[arg(long, default_value_t = 500)]
    pub val_programs: usize,
    /// Test programs per evaluation (spread over the test rooms).
    #[arg(long, default_value_t = 1000)]
    pub test_programs: usize,
    /// Override a config value, e.g. `--set ppo.lr=1e-4` (repeatable; checked as the file is;
    /// the effective config is the one written into each run directory).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Train and evaluate every method on this dataset instead of the configs' `run.dataset`
    /// (e.g. one built with `dataset build --pointing realistic`).
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Also write the tables and figures here (e.g. docs/study), with each finished model's
    /// record (its result, evaluation tables and training curve; no checkpoints): a model
    /// recorded here is taken as done, so a clone continues the study without OUT.
    #[arg(long)]
    pub publish: Option<PathBuf>,
    /// Models trained at once, each its own crew of --workers workers and a learner, all on this
    /// machine's cores and GPU, publishing into the one --out (and --publish); 1: one after
    /// another. It changes only the wall time: each model keeps its config, seed and frame
    /// budget. On a machine of few cores (two) more than 1 mostly makes the crews compete for
    /// the same cores.
    #[arg(long, default_value_t = 1, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub parallel: usize,
}
