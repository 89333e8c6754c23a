//! `orchestrator eval`: runs a split's programs on the farm, each exactly once, and writes the
//! tables of chapter 4 (T4.2–T4.7) as Markdown and CSV, with success by the target's nearness to
//! the start; `--compare` puts several evaluations side by side like T4.2 and by that nearness,
//! and each against the first episode by episode; `--trajectories` draws episodes like Figs 4.2/4.3.
//!
//! A checkpoint (or a run directory, whose latest *complete* checkpoint is used, so a training
//! that is still writing can be evaluated) is evaluated greedily in several passes: with all its
//! inputs, blind (visual inputs zeroed, T4.6), and with RGB or depth alone (T4.7) when it was
//! trained with both. Without a checkpoint the Random baseline runs. Episodes allow unlimited
//! stops; the metrics at 1, 2 and 3 stops read each episode up to its k-th stop.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;

use farm::metrics::EpisodeResult;

use crate::report::first_turn::FirstHeading;
use crate::report::nearness;
use crate::report::tables::{EvalMode, Evaluation};
use crate::supervise::launch::sweep_dead_runs;

mod args;
mod compare;
mod pass;
mod passes;
mod plan;

pub use args::EvalArgs;
use plan::Plan;
pub(crate) use plan::locate;
pub use plan::{assign, choose_programs};

pub use passes::read_episodes;
use passes::{first_headings, pass_trajectories};

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    if !a.compare.is_empty() {
        return compare::run(&compare::Comparison {
            dirs: a.compare.clone(),
            split: a.split.clone(),
            dataset: a.dataset.clone(),
            dts_threshold: a.dts_threshold,
            out: a.out.clone(),
        });
    }
    let plan = Plan::new(&a)?;
    std::fs::create_dir_all(&plan.out)?;
    eprintln!(
        "[eval] {}: {} programs of {} × {} pass(es) ({}) on {} workers{}",
        plan.label,
        plan.programs.len(),
        plan.split.name(),
        plan.modes.len(),
        plan.modes.iter().map(|m| m.name()).collect::<Vec<_>>().join(", "),
        a.workers,
        plan.checkpoint.as_ref().map(|c| format!(", checkpoint {}", c.display())).unwrap_or_default()
    );
    sweep_dead_runs();
    let mut passes = BTreeMap::new();
    let mut timing = Vec::new();
    for &mode in &plan.modes {
        let (eps, secs) = pass::run_pass(&plan, mode, a.workers)?;
        let steps: u64 = eps.iter().map(|e| e.steps as u64 + 1).sum();
        let n = eps.len() as f64;
        eprintln!(
            "[eval] {}: {n} episodes in {secs:.1} s ({:.1} episodes/s, {:.0} frames/s)",
            mode.name(),
            n / secs,
            steps as f64 / secs
        );
        timing.push((mode.name(), eps.len(), secs));
        passes.insert(mode, eps);
    }
    report(&plan, &a, passes, &timing)
}

/// The tables (Markdown and CSV), the trajectories asked for, the TensorBoard record; the
/// tables printed.
fn report(
    plan: &Plan,
    a: &EvalArgs,
    passes: BTreeMap<EvalMode, Vec<EpisodeResult>>,
    timing: &[(&str, usize, f64)],
) -> anyhow::Result<()> {
    let (label, index, out) = (&plan.label, &plan.index, &plan.out);
    let evaluation = Evaluation {
        label: label.clone(),
        split: plan.split.name(),
        programs: index,
        passes,
        dts_threshold: a.dts_threshold,
    };
    let md = tables_markdown(plan, a, &evaluation, timing)?;
    farm::files::write_atomic(&out.join("tables.md"), md.as_bytes())?;
    farm::files::write_atomic(&out.join("tables.csv"), evaluation.csv().as_bytes())?;
    let checkpoint = plan.checkpoint.as_deref();
    let maps = if a.trajectories > 0 {
        crate::report::trajectory::draw(&plan.cfg, &plan.ds, plan.split, &evaluation, checkpoint, out, a.trajectories)?
    } else {
        Vec::new()
    };
    // Beside the training curves when the checkpoint belongs to a run, at its frame count.
    let tb = plan.run_dir.as_ref().filter(|_| !plan.shipped).unwrap_or(out).join("tb");
    let step = match checkpoint {
        Some(c) => farm::checkpoints::frames(c).map_err(|e| anyhow::anyhow!("{}: {e}", c.display()))?,
        None => 0,
    };
    write_tensorboard(&tb, step, &evaluation, &md, &maps).with_context(|| format!("writing {}", tb.display()))?;
    println!("{md}");
    let (short, successes) = evaluation.shorter_than_l();
    if short > 0 {
        eprintln!(
            "[eval] warning: {short} of {successes} successful episodes were shorter than their l_i (a bug in SPL's lower bound)"
        );
    }
    eprintln!("[eval] tables in {}", out.display());
    Ok(())
}

/// The evaluation's tables: T4.2–T4.7, the first turn and heading, success by the target's
/// nearness, the Random baseline's calibration, the passes' throughput.
fn tables_markdown(
    plan: &Plan,
    a: &EvalArgs,
    evaluation: &Evaluation,
    timing: &[(&str, usize, f64)],
) -> anyhow::Result<String> {
    let (label, index, fov) = (&plan.label, &plan.index, plan.cfg.env.fov_deg);
    let mut md = evaluation.markdown();
    // this evaluation's passes only: an explicit --out may still hold other passes of an earlier one
    let trajectories = pass_trajectories(&plan.out, evaluation.passes.keys().copied())?;
    if let Some((_, trajs)) = trajectories.iter().find(|(mode, _)| *mode == EvalMode::Normal) {
        md += &crate::report::first_turn::FirstTurns::of(trajs, index, fov).markdown();
    }
    if !trajectories.is_empty() {
        md += &FirstHeading::markdown(&first_headings(label, &trajectories, index, fov));
    }
    if let Some(eps) = evaluation.passes.get(&EvalMode::Normal) {
        let ranks = nearness::target_ranks(&plan.ds, index)?;
        md += &nearness::markdown(&[(label.clone(), eps.as_slice())], &ranks);
    }
    if plan.checkpoint.is_none() && !a.expert {
        md += "\n";
        md += &evaluation.calibration().unwrap_or_default();
    }
    md += "\n## Throughput\n\n| pass | episodes | seconds | episodes/s |\n|---|---:|---:|---:|\n";
    for (m, n, s) in timing {
        md += &format!("| {m} | {n} | {s:.1} | {:.2} |\n", *n as f64 / s);
    }
    if let Some(c) = &plan.checkpoint {
        md += &format!("\nCheckpoint: `{}`\n", c.display());
    }
    Ok(md)
}

/// The evaluation's SR/SPL/DTS at 1, 2, 3 and unlimited stops under `eval/<split>/` (other
/// passes under `eval/<split>/<pass>/`), its tables as text and the trajectory maps as images,
/// all at `step` (the checkpoint's frames). SR and SPL are fractions, as training's success
/// rate and SPL are, so the curves share an axis (the tables show percent).
fn write_tensorboard(tb: &Path, step: u64, ev: &Evaluation, md: &str, maps: &[PathBuf]) -> anyhow::Result<()> {
    let mut w = farm::tensorboard::EventWriter::create(tb, &format!("eval-{}", ev.split))?;
    let step = step as i64;
    let mut values: Vec<(String, f64)> = Vec::new();
    for &mode in ev.passes.keys() {
        let prefix = match mode {
            EvalMode::Normal => format!("eval/{}", ev.split),
            other => format!("eval/{}/{}", ev.split, other.name()),
        };
        for (k, stops) in [(Some(1), "1"), (Some(2), "2"), (Some(3), "3"), (None, "inf")] {
            let s = ev.scores(mode, k, |_| true).unwrap_or_default();
            values.push((format!("{prefix}/SR@{stops}"), s.sr / 100.0));
            values.push((format!("{prefix}/SPL@{stops}"), s.spl / 100.0));
            values.push((format!("{prefix}/DTS@{stops}"), s.dts));
        }
    }
    w.scalars(step, &values.iter().map(|(t, v)| (t.as_str(), *v)).collect::<Vec<_>>())?;
    w.text(&format!("eval/{}/tables", ev.split), step, md)?;
    for png in maps {
        let (width, height) = image::image_dimensions(png)?;
        let name = png.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        w.image_png(&format!("eval/{}/trajectories/{name}", ev.split), step, &std::fs::read(png)?, width, height)?;
    }
    Ok(())
}
