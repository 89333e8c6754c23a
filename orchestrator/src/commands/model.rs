//! `orchestrator model`: shipped models (`farm::models`). `ship` makes a study's checkpoint
//! into one: its weights alone, its run's config, the check (episodes it must reproduce,
//! evaluated now) and its card (from the study's record of it). `check` evaluates a shipped
//! model again and compares the episodes with those its check recorded.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};

use farm::config::RunConfig;
use farm::models::{self, Check, Outcome};
use worker::scene::Split;

use super::study::records;
use super::study::steps::Eval;
use super::study::summary::RunResult;
use crate::report::tables::{find, read_rows};

#[derive(Subcommand, Debug)]
pub enum ModelCmd {
    /// Make a checkpoint a shipped model: weights only, config, check and card in one folder.
    Ship(ShipArgs),
    /// Evaluate a shipped model on its check's programs and compare with the recorded episodes.
    Check(CheckArgs),
}

#[derive(Args, Debug)]
pub struct ShipArgs {
    /// The checkpoint file (the one the study selected).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// The study's record of it (PUBLISH/records/NAME): the card's results.
    #[arg(long)]
    pub record: PathBuf,
    /// The commit it was trained at, for the card.
    #[arg(long)]
    pub trained_at: String,
    /// The command that trains it again, for the card.
    #[arg(long)]
    pub retrain: String,
    /// The model's folder (e.g. models/both); replaced once the new model is whole.
    #[arg(long)]
    pub out: PathBuf,
    /// The check's split and number of programs (spread evenly over the split).
    #[arg(long, default_value = "val")]
    pub split: String,
    #[arg(long, default_value_t = 100)]
    pub programs: usize,
    /// How many of the check's episodes may differ on another machine, and how that was measured.
    #[arg(long, default_value_t = 0)]
    pub tolerance: usize,
    #[arg(long, default_value = "")]
    pub tolerance_why: String,
    /// GOND as `dataset build` makes it by default: the check's programs.
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
}

#[derive(Args, Debug)]
pub struct CheckArgs {
    /// The shipped model's folder (e.g. models/both).
    pub model: PathBuf,
    /// Where the evaluation goes (default: runs/eval-models/NAME/check).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// GOND as `dataset build` makes it by default: the check's programs.
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
}

/// The workers of a check's evaluation: the same count everywhere, so each worker runs the
/// same programs as when the check was recorded.
const WORKERS: usize = 4;

pub fn run(cmd: ModelCmd) -> anyhow::Result<()> {
    match cmd {
        ModelCmd::Ship(a) => ship(&a),
        ModelCmd::Check(a) => check(&a),
    }
}

fn ship(a: &ShipArgs) -> anyhow::Result<()> {
    let result = records::one(&a.record)?;
    let bytes = std::fs::read(&a.checkpoint).with_context(|| format!("reading {}", a.checkpoint.display()))?;
    let slim = models::policy_only(&bytes).map_err(|why| anyhow::anyhow!("{}: {why}", a.checkpoint.display()))?;
    let meta = farm::checkpoints::check_bytes(&slim).map_err(|why| anyhow::anyhow!("{why}"))?;
    let config =
        meta.get("config").with_context(|| format!("{}: no `config` in its metadata", a.checkpoint.display()))?;
    let cfg = RunConfig::from_toml(config, &format!("{} (metadata `config`)", a.checkpoint.display()))?;
    let split = Split::from_name(&a.split).with_context(|| format!("--split: `{}` is not a split", a.split))?;
    // made beside, moved into place whole: a model already there stays until the new one is done
    let made = a.out.with_extension("partial");
    if made.exists() {
        std::fs::remove_dir_all(&made).with_context(|| format!("clearing {}", made.display()))?;
    }
    farm::files::write_atomic(&made.join(models::CONFIG), config.as_bytes())?;
    farm::files::write_atomic(&made.join(models::WEIGHTS), &slim)?;
    let scratch = Path::new("runs/eval-models").join(a.out.file_name().unwrap_or_default()).join("ship");
    let episodes = evaluate(&made, &a.dataset, split, a.programs, &scratch)?;
    std::fs::remove_dir_all(&scratch).ok();
    let check = Check {
        split: a.split.clone(),
        max_programs: a.programs,
        episodes,
        tolerance: a.tolerance,
        tolerance_why: a.tolerance_why.clone(),
    };
    farm::files::write_atomic(&made.join(models::CHECK), serde_json::to_string_pretty(&check)?.as_bytes())?;
    let card = Card { a, cfg: &cfg, meta: &meta, result: &result, check: &check, bytes: slim.len() };
    farm::files::write_atomic(&made.join(models::CARD), card.markdown()?.as_bytes())?;
    if a.out.exists() {
        std::fs::remove_dir_all(&a.out).with_context(|| format!("replacing {}", a.out.display()))?;
    }
    std::fs::rename(&made, &a.out).with_context(|| format!("moving {} into place", made.display()))?;
    println!(
        "{}: {} MB, the check {} of {} at the first stop",
        a.out.display(),
        mb(slim.len()),
        check.successes(),
        check.episodes.len()
    );
    Ok(())
}

fn check(a: &CheckArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        models::is_model(&a.model),
        "{}: not a shipped model (no {} and {})",
        a.model.display(),
        models::WEIGHTS,
        models::CONFIG
    );
    let weights = a.model.join(models::WEIGHTS);
    farm::checkpoints::verify(&weights).map_err(|why| anyhow::anyhow!("{}: {why}", weights.display()))?;
    let file = a.model.join(models::CHECK);
    let text = std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    let recorded: Check =
        serde_json::from_str(&text).with_context(|| format!("{}: not a model's check", file.display()))?;
    let split = Split::from_name(&recorded.split)
        .with_context(|| format!("{}: field `split`: `{}` is not a split", file.display(), recorded.split))?;
    let name = a.model.file_name().unwrap_or_default();
    let out = a.out.clone().unwrap_or_else(|| Path::new("runs/eval-models").join(name).join("check"));
    let got = evaluate(&a.model, &a.dataset, split, recorded.max_programs, &out)?;
    let differences = recorded.differences(&got);
    let successes = got.iter().filter(|o| o.success_first_stop).count();
    for d in &differences {
        eprintln!("[model check] {d}");
    }
    println!(
        "{}: {} of {} episodes as recorded ({} may differ); {successes} successes at the first stop, {} recorded",
        a.model.display(),
        recorded.episodes.len() - differences.len(),
        recorded.episodes.len(),
        recorded.tolerance,
        recorded.successes()
    );
    anyhow::ensure!(
        differences.len() <= recorded.tolerance,
        "{}: {} episodes differ from its check, more than the {} it allows",
        a.model.display(),
        differences.len(),
        recorded.tolerance
    );
    Ok(())
}

/// The normal pass of `eval` on the model, `programs` of `split` in `dataset`, into `out`: each
/// episode's outcome.
fn evaluate(model: &Path, dataset: &Path, split: Split, programs: usize, out: &Path) -> anyhow::Result<Vec<Outcome>> {
    let eval = Eval {
        what: ["--checkpoint".into(), model.display().to_string(), "--dataset".into(), dataset.display().to_string()]
            .to_vec(),
        split,
        programs,
        modes: &["normal"],
        rooms: Vec::new(),
        out: out.to_path_buf(),
    };
    // `Eval::run` would take an earlier complete evaluation there as this one
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("clearing {}", out.display()))?;
    }
    eval.run(WORKERS)?;
    let eps = super::eval::read_episodes(&out.join("normal").join("episodes.jsonl"))?;
    let mut outcomes: Vec<Outcome> = eps.iter().map(Outcome::of).collect();
    outcomes.sort_by_key(|o| o.program);
    // each program once (a restarted worker may repeat one it had begun)
    outcomes.dedup_by_key(|o| o.program);
    Ok(outcomes)
}

fn mb(bytes: usize) -> String {
    format!("{:.1}", bytes as f64 / 1e6)
}

/// The card: what the model is, how it was made, how well it does, how to check and remake it.
struct Card<'a> {
    a: &'a ShipArgs,
    cfg: &'a RunConfig,
    meta: &'a std::collections::HashMap<String, String>,
    result: &'a RunResult,
    check: &'a Check,
    bytes: usize,
}

impl Card<'_> {
    fn markdown(&self) -> anyhow::Result<String> {
        let (a, cfg, r) = (self.a, self.cfg, self.result);
        let frames: u64 = self.meta.get("frames").and_then(|f| f.parse().ok()).unwrap_or_default();
        let updates = self.meta.get("updates").cloned().unwrap_or_default();
        let method = cfg.run.method.label();
        let mut md = format!(
            "# {dir}: {method}, seed {seed}, {frames} frames\n\n\
             The default's {method} (`configs/tiny`, seed {seed}) after {frames} frames: the checkpoint the study \
             selected by its SR at the first stop on val ({ckpt}). Weights only, without the optimizer's state \
             ({size} MB); `--checkpoint {dir}` wherever a checkpoint is taken.\n\n\
             | | |\n|---|---|\n\
             | config | [config.toml](config.toml): `configs/tiny/{stem}.toml`, `run.seed = {seed}` |\n\
             | trained at | {commit}, {workers} envs a round |\n\
             | frames | {frames} ({updates} PPO updates) |\n\n",
            seed = cfg.run.seed,
            ckpt = Path::new(&r.checkpoint).file_name().unwrap_or_default().to_string_lossy(),
            size = mb(self.bytes),
            dir = a.out.display(),
            stem = r.stem,
            commit = a.trained_at,
            workers = r.budget.as_ref().map_or(0, |b| b.frames_per_update / cfg.ppo.rollout as u64),
        );
        md += &self.results()?;
        md += &format!(
            "\n## The check\n\n`orchestrator model check {dir}` runs it on {n} {split} programs (spread evenly) and \
             compares each episode with [check.json](check.json): {s} of {n} succeed at the first stop. At most \
             {tol} may differ: {why}\n\n## Train it again\n\n```sh\n{retrain}\n```\n",
            dir = a.out.display(),
            n = self.check.episodes.len(),
            split = self.check.split,
            s = self.check.successes(),
            tol = self.check.tolerance,
            why = self.check.tolerance_why,
            retrain = a.retrain,
        );
        Ok(md)
    }

    /// Its T4.2 row and the pointing check, from the study's record.
    fn results(&self) -> anyhow::Result<String> {
        let r = self.result;
        let rows = match &r.test_tables {
            Some(t) => read_rows(t)?,
            None => Vec::new(),
        };
        let sr = |mode: &str, stops: &str| {
            find(&rows, mode, "all", "all", stops).map_or("–".to_string(), |row| format!("{:.1}", row.sr))
        };
        let mut md = format!(
            "## Results\n\nThe study's evaluation of it (record: `{}`), on 1,000 test programs.\n\n\
             | val SR 1 | SR 1 | SPL 1 | DTS 1 (m) | SR ∞ | blind SR 1 |\n|---:|---:|---:|---:|---:|---:|\n\
             | {:.1} | {:.1} | {:.1} | {:.3} | {:.1} | {} |\n",
            self.a.record.display(),
            r.val_sr1,
            r.test_first.sr,
            r.test_first.spl,
            r.test_first.dts,
            r.test_unlimited.sr,
            sr("blind", "1")
        );
        if find(&rows, "other_gesture", "all", "all", "1").is_some() {
            md += &format!(
                "\nThe pointing check: each test program again with another room's referencing gesture.\n\n\
                 | | own gesture | another room's |\n|---|---:|---:|\n| SR 1 | {} | {} |\n| SR ∞ | {} | {} |\n",
                sr("normal", "1"),
                sr("other_gesture", "1"),
                sr("normal", "inf"),
                sr("other_gesture", "inf")
            );
        }
        Ok(md)
    }
}
