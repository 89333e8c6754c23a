//! What every command that starts a crew does first (`up`, `eval`, `bench farm`): make the
//! dataset path (and a trained network's encoder weights) absolute and check them, create and
//! lock the run directory with its config copy, and sweep the shared memory of runs whose
//! orchestrator was killed.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use farm::config::{Encoder, RunConfig};
use worker::dataset::Dataset;
use worker::scene::Split;

use super::run_dir::RunDir;
use farm::serve_args::Policy;

/// Makes the dataset path absolute (children may run elsewhere), checks it is a dataset and
/// verifies it; the opened dataset, unless `synthetic` (no dataset is read then).
pub fn resolve_dataset(cfg: &mut RunConfig, synthetic: bool) -> anyhow::Result<Option<Dataset>> {
    if cfg.run.dataset.is_relative() {
        cfg.run.dataset = std::env::current_dir()?.join(&cfg.run.dataset);
    }
    let manifest = cfg.run.dataset.join("manifest.json");
    if synthetic {
        return Ok(None);
    }
    if !manifest.is_file() {
        anyhow::bail!(
            "no dataset at {} (missing {}); build one with `orchestrator dataset build --out {}` or set run.dataset in the config",
            cfg.run.dataset.display(),
            manifest.display(),
            cfg.run.dataset.display()
        );
    }
    verify_dataset(&cfg.run.dataset).map(Some)
}

/// Checks every byte of a dataset against its manifest's checksums (and the JSON indexes
/// against the records) once, before any worker reads it: a damaged file is one clear error
/// naming it instead of episodes built from flipped bits. docs/bench/log.md
/// ("Reliability") has the cost.
pub fn verify_dataset(dir: &Path) -> anyhow::Result<Dataset> {
    let t = std::time::Instant::now();
    let ds = Dataset::open(dir, worker::dataset::Verify::Full)
        .with_context(|| format!("dataset {} failed its integrity check (rebuild it)", dir.display()))?;
    let secs = t.elapsed().as_secs_f64();
    if secs > 2.0 {
        let programs: usize = Split::ALL.iter().filter_map(|&s| ds.split(s)).map(|f| f.len()).sum();
        eprintln!("[dataset] {} verified: {programs} programs in {secs:.1} s", dir.display());
    }
    Ok(ds)
}

/// For a network on the frozen pretrained encoder: makes the weights path absolute and checks the
/// file is there, before anything starts (the learner would find out only after the workers).
pub fn resolve_encoder(cfg: &mut RunConfig) -> anyhow::Result<()> {
    let Some(path) = cfg.model.encoder_weights.as_mut().filter(|_| cfg.model.encoder == Encoder::Pretrained) else {
        return Ok(());
    };
    if path.is_relative() {
        *path = std::env::current_dir()?.join(&*path);
    }
    if !path.is_file() {
        let out = path.with_extension("");
        anyhow::bail!(
            "no pretrained encoder at {} (model.encoder_weights); make it with `orchestrator encoder pretrain --out {}` \
             (scripts/run.sh does), or choose model.encoder = \"small_cnn\"",
            path.display(),
            out.display()
        );
    }
    Ok(())
}

/// Creates and locks the run directory, writes the config copy and `run.json`.
pub fn prepare_run(
    run_dir: &Path,
    cfg: &RunConfig,
    resume: bool,
    workers: usize,
    policy: Policy,
) -> anyhow::Result<(RunDir, PathBuf)> {
    let dir = RunDir::open(run_dir)?;
    let config_path = dir.config_path();
    if !resume {
        farm::files::write_atomic(&config_path, cfg.to_toml().as_bytes())
            .with_context(|| format!("writing {}", config_path.display()))?;
    }
    dir.write_info(workers, policy.name())?;
    Ok((dir, config_path))
}

/// Ends the shared-memory domains of runs whose orchestrator was killed (older than a minute,
/// no live process).
pub fn sweep_dead_runs() {
    let swept = farm::transport::sweep_dead_runs(Duration::from_secs(60));
    if !swept.is_empty() {
        eprintln!("[up] removed the shared memory of {} dead run(s): {}", swept.len(), swept.join(", "));
    }
}
