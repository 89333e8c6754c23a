//! The study's main table: T4.2 (SR, SPL, DTS at the first stop on test, mean ± std over seeds)
//! beside the dissertation's figures, which of T4.2's orderings hold on our test split, and the
//! figures beside it; the ablation tables T4.3–T4.7 are in `ablations`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use farm::config::Method;
use farm::metrics::FirstStops;
use farm::rooms::SceneType;
use serde::{Deserialize, Serialize};

use crate::report::tables::{TableRow, find, read_rows};

/// A model the study trains or evaluates, by config file stem: T4.2's methods, then T4.7's
/// variants of +Both that see one visual input (+Both itself is T4.7's RGB-D row).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StudyMethod {
    pub stem: &'static str,
    pub method: Method,
    pub label: &'static str,
    /// The visual inputs its config must switch on (`model.rgb`, `model.depth`).
    pub rgb: bool,
    pub depth: bool,
}

const fn m(stem: &'static str, method: Method, label: &'static str, rgb: bool, depth: bool) -> StudyMethod {
    StudyMethod { stem, method, label, rgb, depth }
}

/// T4.2's methods in the dissertation's order, then T4.7's variants.
pub const METHODS: [StudyMethod; 8] = [
    m("random", Method::Random, "Random", true, true),
    m("vision_only", Method::VisionOnly, "Vision Only", true, true),
    m("vis_sem", Method::VisSem, "VisSem", true, true),
    m("referencing", Method::Referencing, "+Referencing", true, true),
    m("intervention", Method::Intervention, "+Intervention", true, true),
    m("both", Method::Both, "+Both", true, true),
    m("rgb_sem_both", Method::Both, "RGB+Semantic+Both", true, false),
    m("depth_sem_both", Method::Both, "Depth+Semantic+Both", false, true),
];

/// The study method of a config stem.
pub fn method(stem: &str) -> Option<StudyMethod> {
    METHODS.into_iter().find(|m| m.stem == stem)
}

/// SR (%), SPL (%), DTS (m) at one number of stops.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub sr: f64,
    pub spl: f64,
    pub dts: f64,
}

impl From<&TableRow> for Metrics {
    fn from(r: &TableRow) -> Metrics {
        Metrics { sr: r.sr, spl: r.spl, dts: r.dts }
    }
}

/// T4.2 as the dissertation prints it (test split, first stop), by stem.
pub fn dissertation(stem: &str) -> Option<Metrics> {
    let (sr, spl, dts) = match stem {
        "random" => (8.7, 7.1, 2.908),
        "vision_only" => (0.36, 0.098, 2.719),
        "vis_sem" => (15.2, 9.1, 2.419),
        "referencing" => (19.2, 11.5, 2.313),
        "intervention" => (41.0, 24.8, 2.004),
        "both" => (49.2, 28.7, 1.976),
        _ => return None,
    };
    Some(Metrics { sr, spl, dts })
}

/// T4.2's pairwise orderings (better, worse) by stem, as its text and table state them.
pub const ORDERINGS: [(&str, &str); 6] = [
    ("both", "intervention"),
    ("intervention", "referencing"),
    ("referencing", "vis_sem"),
    ("vis_sem", "vision_only"),
    ("both", "vis_sem"),
    ("intervention", "vis_sem"),
];

/// What a selected checkpoint cost to train.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    pub frames: u64,
    /// Optimizer steps: updates × epochs × minibatches.
    pub adam_steps: u64,
    pub frames_per_update: u64,
}

/// The dissertation's training budget (T4.1, §4.3.2): 5M frames of 20 envs × 128 steps, each
/// update 4 epochs of 2 minibatches.
pub const DISSERTATION_BUDGET: Budget =
    Budget { frames: 5_000_000, adam_steps: 5_000_000 / (20 * 128) * 4 * 2, frames_per_update: 20 * 128 };

/// One evaluated model of the study (a training run's selected checkpoint, or a Random seed),
/// with the evaluations the ablation tables read.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunResult {
    pub stem: String,
    /// Trained in the rooms of this type only (`--per-scene-type`), else in every training room.
    pub scene_type: Option<SceneType>,
    pub seed: u64,
    pub checkpoint: String,
    /// SR at the first stop on val of the selected checkpoint (NaN for Random; null in JSON).
    #[serde(deserialize_with = "nan_when_null")]
    pub val_sr1: f64,
    /// On test, at 1 stop and at unlimited stops.
    pub test_first: Metrics,
    pub test_unlimited: Metrics,
    /// `tables.csv` of the selected checkpoint on test, on val, and on train (T4.3); None in a
    /// record of a model trained before records kept them.
    pub test_tables: Option<PathBuf>,
    pub val_tables: Option<PathBuf>,
    pub train_tables: Option<PathBuf>,
    /// Where the first stops on test were (from the normal pass's episodes).
    pub first_stops: Option<FirstStops>,
    /// (frames, SR at the first stop on val) of every checkpoint evaluated for the selection.
    pub val_curve: Vec<(u64, f64)>,
    /// The selected checkpoint's training (None for Random).
    pub budget: Option<Budget>,
}

impl RunResult {
    /// Reads the test results of one model from its `tables.csv`.
    pub fn read(
        stem: &str,
        scene_type: Option<SceneType>,
        seed: u64,
        checkpoint: &Path,
        val_sr1: f64,
        test_tables: &Path,
    ) -> anyhow::Result<RunResult> {
        let rows = read_rows(test_tables)?;
        let episodes = test_tables.with_file_name("normal").join("episodes.jsonl");
        let first_stops = match episodes.is_file() {
            true => Some(FirstStops::of(&crate::commands::eval::read_episodes(&episodes)?, 1.0)),
            false => None,
        };
        Ok(RunResult {
            stem: stem.into(),
            scene_type,
            seed,
            checkpoint: checkpoint.display().to_string(),
            val_sr1,
            test_first: row(&rows, test_tables, "1")?,
            test_unlimited: row(&rows, test_tables, "inf")?,
            test_tables: Some(test_tables.into()),
            val_tables: None,
            train_tables: None,
            first_stops,
            val_curve: Vec::new(),
            budget: None,
        })
    }

    pub fn label(&self) -> &'static str {
        method(&self.stem).map_or("?", |m| m.label)
    }
}

fn nan_when_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The first-stop row (normal pass, all scene types and instance counts) of `eval`'s tables.csv.
pub fn first_stop(csv: &Path) -> anyhow::Result<Metrics> {
    row(&read_rows(csv)?, csv, "1")
}

/// The row at `stops` (normal pass, all scene types and instance counts) of `rows`, read from `csv`.
fn row(rows: &[TableRow], csv: &Path, stops: &str) -> anyhow::Result<Metrics> {
    let r = find(rows, "normal", "all", "all", stops)
        .ok_or_else(|| anyhow::anyhow!("{}: no row for the normal pass, all rooms, {stops} stop(s)", csv.display()))?;
    Ok(r.into())
}

/// Mean and sample standard deviation (0 for one value).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 { v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    (mean, var.sqrt())
}

/// The models of T4.2: trained in every training room.
fn of(results: &[RunResult], stem: &str, f: impl Fn(&RunResult) -> f64) -> Vec<f64> {
    results.iter().filter(|r| r.stem == stem && r.scene_type.is_none()).map(f).collect()
}

/// One method's test results over its seeds: (mean, std) of each metric.
struct Summary {
    seeds: usize,
    sr: (f64, f64),
    spl: (f64, f64),
    dts: (f64, f64),
    sr_inf: (f64, f64),
}

fn summary(results: &[RunResult], stem: &str) -> Option<Summary> {
    let sr = of(results, stem, |r| r.test_first.sr);
    (!sr.is_empty()).then(|| Summary {
        seeds: sr.len(),
        sr: mean_std(&sr),
        spl: mean_std(&of(results, stem, |r| r.test_first.spl)),
        dts: mean_std(&of(results, stem, |r| r.test_first.dts)),
        sr_inf: mean_std(&of(results, stem, |r| r.test_unlimited.sr)),
    })
}

/// Success on training episodes against frames, per method: the mean over the seeds' runs
/// (update by update; every seed makes the same updates) of a 10-update moving mean, in %.
/// `runs` are (stem, metrics JSONL) of the runs trained in every training room.
pub fn learning_curves(runs: &[(String, PathBuf)]) -> anyhow::Result<Vec<crate::report::plot::Series>> {
    #[derive(serde::Deserialize)]
    struct Row {
        frames: f64,
        success_rate: Option<f64>,
    }
    let mut out = Vec::new();
    for m in METHODS {
        let mut seeds: Vec<Vec<(f64, f64)>> = Vec::new();
        for (_, metrics) in runs.iter().filter(|(x, _)| x == m.stem) {
            let rows: Vec<Row> = farm::files::read_jsonl(metrics)?;
            let smooth: Vec<(f64, f64)> = (0..rows.len())
                .map(|i| {
                    let w: Vec<f64> = rows[i.saturating_sub(9)..=i].iter().filter_map(|r| r.success_rate).collect();
                    (rows[i].frames, if w.is_empty() { 0.0 } else { 100.0 * w.iter().sum::<f64>() / w.len() as f64 })
                })
                .collect();
            seeds.push(smooth);
        }
        let Some(n) = seeds.iter().map(Vec::len).min() else { continue };
        let mean = (0..n).map(|i| (seeds[0][i].0, seeds.iter().map(|s| s[i].1).sum::<f64>() / seeds.len() as f64));
        out.push((m.label.to_string(), mean.collect()));
    }
    Ok(out)
}

/// Writes `T4.2.md`, `T4.2.csv`, `study.json` and three figures into `out`: SR and SPL at the
/// first stop with the seeds' spread (`sr_spl.png`), every method's training success against
/// frames (`learning_curves.png`, from `runs` as in [`learning_curves`]) and each run's val SR
/// at the first stop against frames (`val_curves.png`). `pending` names the runs still to do.
pub fn write(out: &Path, results: &[RunResult], runs: &[(String, PathBuf)], pending: &[String]) -> anyhow::Result<()> {
    let summaries: Vec<(StudyMethod, Summary)> =
        METHODS.into_iter().filter_map(|m| summary(results, m.stem).map(|s| (m, s))).collect();
    let with_val_curves = figures(out, results, runs, &summaries)?;
    let (mut md, csv) = t42(&summaries);
    orderings(&mut md, &summaries);
    runs_table(&mut md, out, results);
    first_stops(&mut md, results);
    budget(&mut md, results);
    still_to_do(&mut md, pending);
    let _ = writeln!(md, "\n![SR and SPL](sr_spl.png)\n\n![learning curves](learning_curves.png)");
    if with_val_curves {
        let _ = writeln!(md, "\n![val SR against frames](val_curves.png)");
    }
    farm::files::write_atomic(&out.join("T4.2.md"), md.as_bytes())?;
    farm::files::write_atomic(&out.join("T4.2.csv"), csv.as_bytes())?;
    study_json(out, results)
}

/// sr_spl.png, learning_curves.png (with training curves) and val_curves.png (with val curves
/// of more than one checkpoint; whether it was drawn).
fn figures(
    out: &Path,
    results: &[RunResult],
    runs: &[(String, PathBuf)],
    summaries: &[(StudyMethod, Summary)],
) -> anyhow::Result<bool> {
    let groups: Vec<(String, Vec<(f64, f64)>)> =
        summaries.iter().map(|(m, s)| (m.label.to_string(), vec![s.sr, s.spl])).collect();
    crate::report::plot::grouped_bars(
        &out.join("sr_spl.png"),
        "Test, first stop: mean ± std over seeds",
        "%",
        &["SR", "SPL"],
        &groups,
    )?;
    let curves = learning_curves(runs)?;
    if !curves.is_empty() {
        crate::report::plot::lines(
            &out.join("learning_curves.png"),
            "Success on training episodes (10-update mean, mean over seeds)",
            "frames",
            "success (%)",
            &curves,
        )?;
    }
    // one colour per method, its seeds as line styles: a study holds up to a dozen such runs
    let val_curves: Vec<crate::report::plot::LineGroup> = METHODS
        .into_iter()
        .filter_map(|m| {
            let mut seeds: Vec<&RunResult> = results
                .iter()
                .filter(|r| r.stem == m.stem && r.val_curve.len() > 1 && r.scene_type.is_none())
                .collect();
            seeds.sort_by_key(|r| r.seed);
            let curves = seeds.iter().map(|r| r.val_curve.iter().map(|&(f, sr)| (f as f64, sr)).collect()).collect();
            let n = match seeds.len() {
                0 => return None,
                1 => "1 seed".to_string(),
                n => format!("{n} seeds"),
            };
            Some((format!("{} ({n})", m.label), curves))
        })
        .collect();
    if !val_curves.is_empty() {
        let styles =
            if val_curves.iter().any(|g| g.1.len() > 1) { " (seeds 1, 2, 3: solid, dashed, dotted)" } else { "" };
        crate::report::plot::grouped_lines(
            &out.join("val_curves.png"),
            &format!("Val, first stop: SR of each evaluated checkpoint{styles}"),
            "frames",
            "SR at the first stop (%)",
            &val_curves,
        )?;
    }
    Ok(!val_curves.is_empty())
}

/// T4.2 itself, as Markdown (the file's start) and CSV.
fn t42(summaries: &[(StudyMethod, Summary)]) -> (String, String) {
    let mut md = String::new();
    let mut csv = String::from(
        "method,seeds,sr_mean,sr_std,spl_mean,spl_std,dts_mean,dts_std,sr_inf_mean,dissertation_sr,dissertation_spl,dissertation_dts\n",
    );
    let _ = writeln!(
        md,
        "# T4.2: navigation on test at the first stop\n\nOurs: mean ± std over seeds, each the checkpoint with the best SR at the first stop \
         on val; separately trained models per method, each in every training room. Dissertation: its Table 4.2 (T4.7's \
         variants of +Both are in T4.7.md).\n"
    );
    let _ = writeln!(
        md,
        "| method | seeds | SR (%) | SPL (%) | DTS (m) | SR ∞ (%) | dissertation SR / SPL / DTS |\n|---|---:|---:|---:|---:|---:|---:|"
    );
    for (m, s) in summaries {
        let Some(d) = dissertation(m.stem) else { continue };
        let (((srm, srs), (splm, spls)), ((dtsm, dtss), (infm, infs))) = ((s.sr, s.spl), (s.dts, s.sr_inf));
        let _ = writeln!(
            md,
            "| {} | {} | {srm:.1} ± {srs:.1} | {splm:.1} ± {spls:.1} | {dtsm:.2} ± {dtss:.2} | {infm:.1} ± {infs:.1} | {:?} / {:?} / {:?} |",
            m.label, s.seeds, d.sr, d.spl, d.dts
        );
        let _ = writeln!(
            csv,
            "{},{},{srm:.3},{srs:.3},{splm:.3},{spls:.3},{dtsm:.4},{dtss:.4},{infm:.3},{:?},{:?},{:?}",
            m.label, s.seeds, d.sr, d.spl, d.dts
        );
    }
    (md, csv)
}

/// Which of T4.2's orderings hold on our test split.
fn orderings(md: &mut String, summaries: &[(StudyMethod, Summary)]) {
    let _ = writeln!(
        md,
        "\n## T4.2's orderings on our test split\n\nHolds when our mean SR at the first stop is higher by more than the larger of the two \
         methods' standard deviations over seeds.\n\n| ordering | ours (SR %) | holds |\n|---|---:|:---:|"
    );
    for (a, b) in ORDERINGS {
        let (Some(x), Some(y)) =
            (summaries.iter().find(|(m, _)| m.stem == a), summaries.iter().find(|(m, _)| m.stem == b))
        else {
            continue;
        };
        let ((ma, sa), (mb, sb)) = (x.1.sr, y.1.sr);
        let verdict = if ma - mb > sa.max(sb) {
            "yes"
        } else if ma > mb {
            "within the spread"
        } else {
            "no"
        };
        let _ = writeln!(md, "| {} > {} | {ma:.1} ± {sa:.1} vs {mb:.1} ± {sb:.1} | {verdict} |", x.0.label, y.0.label);
    }
}

/// Every model: its selected checkpoint, val and test SR.
fn runs_table(md: &mut String, out: &Path, results: &[RunResult]) {
    let _ = writeln!(
        md,
        "\n## Runs\n\n| method | rooms | seed | selected checkpoint | val SR 1 stop (%) | test SR 1 stop (%) |\n|---|---|---:|---|---:|---:|"
    );
    // the dissertation's order, then seed: the same table whichever study command wrote it
    let mut ordered: Vec<&RunResult> = results.iter().collect();
    ordered.sort_by_key(|r| (METHODS.iter().position(|m| m.stem == r.stem), r.scene_type.map(|t| t.name()), r.seed));
    for r in ordered {
        let val = if r.val_sr1.is_nan() { "-".into() } else { format!("{:.1}", r.val_sr1) };
        let rooms = r.scene_type.map_or("all", |t| t.name());
        // inside the study folder, wherever that is
        let checkpoint =
            Path::new(&r.checkpoint).strip_prefix(out).map_or(r.checkpoint.clone(), |p| p.display().to_string());
        let _ =
            writeln!(md, "| {} | {rooms} | {} | {checkpoint} | {val} | {:.1} |", r.label(), r.seed, r.test_first.sr);
    }
}

/// Whether each method stops near the target or like a timer.
fn first_stops(md: &mut String, results: &[RunResult]) {
    let _ = writeln!(
        md,
        "\n## When to stop (test, first stop)\n\nA policy that knows where the target is stops near it: the share of \
         first stops within 1 m of the target (in view or not) and SR at the first stop over SR with unlimited stops \
         (the dissertation's T4.4 gives 0.16–0.46) say whether it does; a policy that stops like a timer has a low share \
         and a low ratio. Mean ± std over seeds.\n\n\
         | method | seeds | first stops within 1 m (%) | SR 1 / SR ∞ | episodes with a stop (%) | mean step of the first stop |\n\
         |---|---:|---:|---:|---:|---:|"
    );
    for m in METHODS {
        let f: Vec<FirstStops> = results
            .iter()
            .filter(|r| r.stem == m.stem && r.scene_type.is_none())
            .filter_map(|r| r.first_stops)
            .collect();
        if f.is_empty() {
            continue;
        }
        let ms = |g: &dyn Fn(&FirstStops) -> f64| mean_std(&f.iter().map(g).collect::<Vec<_>>());
        let (near, ratio) = (ms(&|f| f.near_share()), ms(&|f| f.ratio()));
        let (stopped, step) = (ms(&|f| f.stopped_share()), ms(&|f| f.mean_step));
        let _ = writeln!(
            md,
            "| {} | {} | {:.1} ± {:.1} | {:.2} ± {:.2} | {:.1} ± {:.1} | {:.1} ± {:.1} |",
            m.label,
            f.len(),
            near.0,
            near.1,
            ratio.0,
            ratio.1,
            stopped.0,
            stopped.1,
            step.0,
            step.1
        );
    }
}

/// The selected checkpoints' frames and Adam steps beside the dissertation's.
fn budget(md: &mut String, results: &[RunResult]) {
    let d = DISSERTATION_BUDGET;
    let _ = writeln!(
        md,
        "\n## Training budget of the selected checkpoints\n\nAdam steps = PPO updates × epochs × minibatches. The \
         dissertation: {} frames, {} frames per update, {} Adam steps (T4.1: 4 epochs × 2 minibatches).\n\n\
         | method | seed | frames | frames per update | Adam steps | frames / dissertation's | Adam steps / dissertation's |\n\
         |---|---:|---:|---:|---:|---:|---:|",
        d.frames, d.frames_per_update, d.adam_steps
    );
    for r in results.iter().filter(|r| r.scene_type.is_none()) {
        let Some(b) = r.budget else { continue };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {:.2} | {:.2} |",
            r.label(),
            r.seed,
            b.frames,
            b.frames_per_update,
            b.adam_steps,
            b.frames as f64 / d.frames as f64,
            b.adam_steps as f64 / d.adam_steps as f64
        );
    }
}

fn still_to_do(md: &mut String, pending: &[String]) {
    if !pending.is_empty() {
        let _ = writeln!(
            md,
            "\n## Still to do\n\nThese tables hold the models finished so far; the same study command continues with:\n"
        );
        for p in pending {
            let _ = writeln!(md, "- {p}");
        }
    }
}

/// study.json: every model's result, its paths relative to the folder.
fn study_json(out: &Path, results: &[RunResult]) -> anyhow::Result<()> {
    // paths inside the folder relative to it, so that it reads the same wherever it is copied
    let inside = |p: &Path| p.strip_prefix(out).map_or(p.to_path_buf(), Path::to_path_buf);
    let relative: Vec<RunResult> = results
        .iter()
        .map(|r| RunResult {
            checkpoint: inside(Path::new(&r.checkpoint)).display().to_string(),
            test_tables: r.test_tables.as_deref().map(inside),
            val_tables: r.val_tables.as_deref().map(inside),
            train_tables: r.train_tables.as_deref().map(inside),
            ..r.clone()
        })
        .collect();
    farm::files::write_atomic(&out.join("study.json"), serde_json::to_string_pretty(&relative)?.as_bytes())?;
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn mean_and_sample_std() {
        assert_eq!(mean_std(&[2.0]), (2.0, 0.0));
        let (m, s) = mean_std(&[1.0, 3.0]);
        assert_eq!(m, 2.0);
        assert!((s - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn reads_the_first_stop_row_and_names_the_file_when_it_cannot() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tables.csv");
        std::fs::write(
            &p,
            "label,split,mode,scene_type,instances,stops,episodes,sr,spl,dts\n\
             +Both,test,normal,Kitchen,all,1,250,9.0,8.0,1.0\n\
             +Both,test,normal,all,all,1,1000,3.700,3.138,1.1750\n\
             +Both,test,normal,all,all,inf,1000,52.300,37.434,0.2572\n",
        )
        .unwrap();
        assert_eq!(first_stop(&p).unwrap(), Metrics { sr: 3.7, spl: 3.138, dts: 1.175 });
        let rows = read_rows(&p).unwrap();
        assert_eq!(row(&rows, &p, "inf").unwrap().sr, 52.3);
        let e = row(&rows, &p, "2").unwrap_err().to_string();
        assert!(e.contains("tables.csv") && e.contains("2 stop"), "{e}");
    }

    /// A model's result whose every table row has SR `sr` (SPL sr / 2) and 50 at ∞, one less
    /// (and 40 at ∞) with another room's gesture.
    pub(crate) fn result(dir: &Path, stem: &str, seed: u64, sr: f64) -> RunResult {
        let mut csv = String::from("label,split,mode,scene_type,instances,stops,episodes,sr,spl,dts\n");
        for mode in ["normal", "blind", "other_gesture"] {
            let (sr, inf) = if mode == "other_gesture" { (sr - 1.0, 40.0) } else { (sr, 50.0) };
            for t in ["all", "Kitchen", "LivingRoom", "Bedroom", "Bathroom"] {
                for i in ["all", "1", "2", "3+"] {
                    for k in ["1", "2", "3", "inf"] {
                        let (x, y) = if k == "inf" { (inf, 30.0) } else { (sr, sr / 2.0) };
                        let _ = writeln!(csv, "x,test,{mode},{t},{i},{k},10,{x},{y},1.0");
                    }
                }
            }
        }
        let p = dir.join(format!("{stem}-{seed}.csv"));
        std::fs::write(&p, csv).unwrap();
        let mut r = RunResult::read(stem, None, seed, Path::new("c"), 1.0, &p).unwrap();
        (r.val_tables, r.train_tables) = (Some(p.clone()), Some(p));
        r
    }

    #[test]
    fn the_table_puts_the_dissertation_beside_ours_and_judges_orderings() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // as a study's commands may find them: the table's order is the dissertation's, then seed
        let results = [
            result(d, "vis_sem", 2, 5.0),
            result(d, "both", 2, 12.0),
            result(d, "vis_sem", 1, 4.0),
            result(d, "both", 1, 10.0),
        ];
        write(d, &results, &[], &["+Both seed 3".into()]).unwrap();
        assert!(d.join("sr_spl.png").is_file());
        let md = std::fs::read_to_string(d.join("T4.2.md")).unwrap();
        assert!(md.contains("| +Both | 2 | 11.0 ± 1.4 |") && md.contains("49.2 / 28.7 / 1.976"), "{md}");
        assert!(md.contains("| +Both > VisSem | 11.0 ± 1.4 vs 4.5 ± 0.7 | yes |"), "{md}");
        assert!(md.contains("## Still to do") && md.contains("- +Both seed 3"), "{md}");
        let at = |row: &str| md.find(row).unwrap_or_else(|| panic!("{row} in {md}"));
        assert!(at("| VisSem | all | 1 |") < at("| VisSem | all | 2 |"), "{md}");
        assert!(at("| VisSem | all | 2 |") < at("| +Both | all | 1 |"), "{md}");
        assert!(at("| +Both | all | 1 |") < at("| +Both | all | 2 |"), "{md}");
        let csv = std::fs::read_to_string(d.join("T4.2.csv")).unwrap();
        assert_eq!(csv.lines().count(), 3);
    }
}
