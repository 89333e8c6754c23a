//! `eval --compare`: earlier evaluations of one split side by side — their scores, paired program
//! by program, by the target's nearness and by where each policy heads at its first move ahead.

use std::path::{Path, PathBuf};

use anyhow::Context;
use farm::config::RunConfig;
use farm::metrics::{EpisodeResult, scores};
use worker::program::Program;
use worker::scene::Split;

use super::passes::{first_headings, pass_trajectories, read_episodes};
use crate::report::first_turn::FirstHeading;
use crate::report::nearness;
use crate::report::tables::{EvalMode, TableRow, compare, find, paired, read_rows};

/// What `eval --compare` was given: the evaluation folders, the split they ran on, the dataset
/// holding its programs (default: the first evaluation's), the DTS threshold and the output
/// folder.
pub(super) struct Comparison {
    pub dirs: Vec<PathBuf>,
    pub split: String,
    pub dataset: Option<PathBuf>,
    pub dts_threshold: f64,
    pub out: Option<PathBuf>,
}

/// The normal pass of an earlier evaluation.
struct NormalPass {
    label: String,
    episodes: Vec<EpisodeResult>,
    dir: PathBuf,
    /// Its `config.toml`, when the pass has one.
    config: Option<RunConfig>,
}

/// Finds the normal pass of an earlier evaluation: its folder, or RUN/eval/<split>. An
/// evaluation of another split (its config's `run.split`) is refused: its programs are not the
/// split's.
fn normal_episodes(p: &Path, split: &str) -> anyhow::Result<NormalPass> {
    let candidates = [p.join("normal/episodes.jsonl"), p.join("eval").join(split).join("normal/episodes.jsonl")];
    let f = candidates
        .iter()
        .find(|c| c.is_file())
        .with_context(|| format!("{}: no evaluation found (looked for {})", p.display(), candidates[0].display()))?;
    let pass_dir = f.parent().unwrap_or(p).to_path_buf();
    let file = pass_dir.join("config.toml");
    let config = match file.is_file() {
        true => Some(RunConfig::load(&file).with_context(|| format!("{}: the evaluation's config", file.display()))?),
        false => None,
    };
    if let Some(ran_on) = config.as_ref().map(|c| c.run.split.name()).filter(|s| *s != split) {
        anyhow::bail!("{}: run.split: an evaluation on {ran_on}, compared on --split {split}", file.display());
    }
    let tables = pass_dir.parent().unwrap_or(p).join("tables.md");
    let label = std::fs::read_to_string(&tables)
        .ok()
        .and_then(|t| t.lines().next().and_then(evaluation_label))
        .filter(|l| !l.is_empty())
        .unwrap_or_else(|| p.display().to_string());
    Ok(NormalPass { label, episodes: read_episodes(f)?, dir: pass_dir, config })
}

/// The label of a `tables.md`'s first line, `# Evaluation: LABEL on SPLIT (N episodes)`.
fn evaluation_label(line: &str) -> Option<String> {
    let (label, _split) = line.strip_prefix("# Evaluation: ")?.rsplit_once(" (")?.0.rsplit_once(" on ")?;
    Some(label.to_string())
}

/// The compared split's programs (from `--dataset` or the dataset the first evaluation ran on),
/// each one's target nearness rank, and the field of view the first evaluation ran with.
struct ComparedSplit {
    dataset: PathBuf,
    programs: Vec<Program>,
    ranks: Vec<usize>,
    fov_deg: f32,
}

impl ComparedSplit {
    /// `None`, with a note, when the dataset is gone: the comparison goes on without the tables
    /// that need it. `first` is the first evaluation's normal pass.
    fn open(a: &Comparison, first: &NormalPass) -> Option<ComparedSplit> {
        let open = || -> anyhow::Result<ComparedSplit> {
            let split = Split::from_name(&a.split)
                .with_context(|| format!("--split: `{}` is not one of train, val, test", a.split))?;
            let no_config = || format!("{}: no config.toml", first.dir.display());
            let (dataset, fov_deg) = match (&a.dataset, &first.config) {
                (Some(d), Some(c)) => (d.clone(), c.env.fov_deg),
                (Some(d), None) => {
                    let fov = farm::config::EnvConfig::default().fov_deg;
                    eprintln!("[eval] {}: headings read with the default field of view, {fov}°", no_config());
                    (d.clone(), fov)
                }
                (None, Some(c)) => (c.run.dataset.clone(), c.env.fov_deg),
                (None, None) => anyhow::bail!("{}: pass --dataset", no_config()),
            };
            let (programs, ranks) = nearness::program_facts(&dataset, split).context("pass --dataset")?;
            Ok(ComparedSplit { dataset, programs, ranks, fov_deg })
        };
        open().map_err(|e| eprintln!("[eval] no tables by the target's nearness and heading: {e:#}")).ok()
    }

    /// Every program an evaluation names must be one of the split's: an evaluation of another
    /// dataset (or split) is named rather than read against the wrong programs.
    fn ensure_holds(&self, label: &str, split: &str, programs: impl IntoIterator<Item = u64>) -> anyhow::Result<()> {
        match programs.into_iter().find(|&p| p as usize >= self.programs.len()) {
            Some(p) => anyhow::bail!(
                "{label}: program {p} is not among the {} {split} programs of {} — the evaluation ran on another \
                 dataset; pass that one with --dataset",
                self.programs.len(),
                self.dataset.display()
            ),
            None => Ok(()),
        }
    }
}

/// SR at the first stop in every pass the evaluations ran (blind, another room's gesture, …),
/// from each one's `tables.csv`; empty when they ran the normal pass alone.
fn passes_table(labels: &[String], normal_passes: &[PathBuf]) -> anyhow::Result<String> {
    let mut rows = Vec::with_capacity(labels.len());
    for pass in normal_passes {
        let csv = pass.parent().unwrap_or(pass).join("tables.csv");
        rows.push(if csv.is_file() { read_rows(&csv)? } else { Vec::new() });
    }
    let sr1 = |rows: &[TableRow], mode: EvalMode| find(rows, mode.name(), "all", "all", "1").map(|r| r.sr);
    let modes: Vec<EvalMode> =
        EvalMode::ALL.into_iter().filter(|&m| rows.iter().any(|r| sr1(r, m).is_some())).collect();
    if modes.iter().all(|&m| m == EvalMode::Normal) {
        return Ok(String::new());
    }
    let names: Vec<&str> = modes.iter().map(|m| m.name()).collect();
    let mut md = format!("\n## SR at the first stop, pass by pass (%)\n\n| method | {} |\n|---|", names.join(" | "));
    md += &"---:|".repeat(modes.len());
    for (label, r) in labels.iter().zip(&rows) {
        let cell = |&m: &EvalMode| sr1(r, m).map_or("".to_string(), |sr| format!("{sr:.1}"));
        md += &format!("\n| {label} | {} |", modes.iter().map(cell).collect::<Vec<_>>().join(" | "));
    }
    Ok(md + "\n")
}

/// The last `k` components of `dir`, joined by "/".
fn folder_name(dir: &Path, k: usize) -> String {
    let parts: Vec<String> = dir.components().rev().take(k).map(|c| c.as_os_str().to_string_lossy().into()).collect();
    parts.into_iter().rev().collect::<Vec<_>>().join("/")
}

pub(super) fn run(a: &Comparison) -> anyhow::Result<()> {
    let found = a.dirs.iter().map(|p| normal_episodes(p, &a.split)).collect::<anyhow::Result<Vec<_>>>()?;
    let facts = ComparedSplit::open(a, &found[0]);
    let passes: Vec<PathBuf> = found.iter().map(|n| n.dir.clone()).collect();
    let mut evaluations: Vec<(String, Vec<EpisodeResult>)> = found.into_iter().map(|n| (n.label, n.episodes)).collect();
    // one method evaluated twice (another gesture, another checkpoint, another seed): name each
    // by its folder, and by its parent's too where the folders share a name (RUN/test)
    let labels: Vec<String> = evaluations.iter().map(|(l, _)| l.clone()).collect();
    let names: Vec<String> = a.dirs.iter().map(|d| folder_name(d, 1)).collect();
    for (((label, _), dir), name) in evaluations.iter_mut().zip(&a.dirs).zip(&names) {
        if labels.iter().filter(|l| *l == label).count() > 1 {
            let shared = names.iter().filter(|n| *n == name).count() > 1;
            *label = format!("{label} ({})", if shared { folder_name(dir, 2) } else { name.clone() });
        }
    }
    let rows: Vec<_> = evaluations
        .iter()
        .map(|(label, eps)| (label.clone(), scores(eps, Some(1), a.dts_threshold), scores(eps, None, a.dts_threshold)))
        .collect();
    let mut md = format!("# Comparison on {} (first stop; ∞ = unlimited stops)\n\n{}", a.split, compare(&rows));
    let labels: Vec<String> = evaluations.iter().map(|(l, _)| l.clone()).collect();
    md += &passes_table(&labels, &passes)?;
    let refs: Vec<(String, &[EpisodeResult])> = evaluations.iter().map(|(l, e)| (l.clone(), e.as_slice())).collect();
    if evaluations.len() > 1 {
        md.push('\n');
        md.push_str(&paired(&refs));
    }
    if let Some(split) = &facts {
        for (label, eps) in &evaluations {
            split.ensure_holds(label, &a.split, eps.iter().map(|e| e.program))?;
        }
        md += &nearness::markdown(&refs, &split.ranks);
        let mut headings = Vec::new();
        for ((label, _), pass) in evaluations.iter().zip(&passes) {
            let trajectories = pass_trajectories(pass.parent().unwrap_or(pass), EvalMode::ALL)?;
            for (_, trajs) in &trajectories {
                split.ensure_holds(label, &a.split, trajs.iter().map(|t| t.program))?;
            }
            headings.extend(first_headings(label, &trajectories, &split.programs, split.fov_deg));
        }
        md += &FirstHeading::markdown(&headings);
    }
    if let Some(out) = &a.out {
        std::fs::create_dir_all(out)?;
        farm::files::write_atomic(&out.join("compare.md"), md.as_bytes())?;
    }
    println!("{md}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_evaluations_heading_names_its_label() {
        let h = evaluation_label;
        assert_eq!(h("# Evaluation: +Both on test (1000 episodes)"), Some("+Both".into()));
        assert_eq!(h("# Evaluation: Vision Only on val (500 episodes)"), Some("Vision Only".into()));
        assert_eq!(h("# Comparison on test"), None);
    }

    #[test]
    fn compared_folders_are_named_by_as_much_of_their_path_as_tells_them_apart() {
        let p = Path::new("/root/runs/both-seed2/test");
        assert_eq!((folder_name(p, 1), folder_name(p, 2)), ("test".to_string(), "both-seed2/test".to_string()));
        assert_eq!(folder_name(Path::new("test"), 2), "test");
    }
}
