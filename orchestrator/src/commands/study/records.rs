//! A finished model's record: what the study's tables need of it — its result, the selected
//! checkpoint's evaluation tables and its training success against frames — small enough to
//! commit. A study given `--publish DIR` writes each model's record as soon as the model is
//! done, and takes a model whose record is there as done: a study of many hours continues on
//! another machine from a clone, without its run folders (checkpoints, episodes, logs).
//!
//! ```text
//! DIR/records/<name>/record.json   the run's config, the study's evaluation settings, the result
//!                    test.csv          the selected checkpoint's tables on test (normal, blind)
//!                    test-episodes.csv … each of its test episodes' outcome (pairing methods)
//!                    val.csv           … on val (the evaluation that selected it)
//!                    train.csv         … on train (T4.3)
//!                    curve.jsonl       training success against frames (learning_curves.png)
//! ```
//!
//! A record whose config or evaluation settings differ from the study's is one clear error,
//! never silently used or overwritten.

use std::path::{Path, PathBuf};

use anyhow::Context;
use farm::config::RunConfig;
use serde::{Deserialize, Serialize};

use super::summary::RunResult;

/// How the study evaluates its models: a record made with other settings is not this study's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Settings {
    pub checkpoints: u64,
    pub val_programs: usize,
    pub test_programs: usize,
}

#[derive(Serialize, Deserialize)]
struct Record {
    /// The run's effective config as TOML (Random's: its evaluation config).
    config: String,
    evaluation: Settings,
    /// Table paths relative to the record's folder.
    result: RunResult,
}

/// One row of `curve.jsonl`: what `summary::learning_curves` reads of a run's metrics.
#[derive(Serialize, Deserialize)]
struct CurvePoint {
    frames: f64,
    success_rate: Option<f64>,
}

const OUTCOMES: &str = "test-episodes.csv";

fn folder(publish: &Path, name: &str) -> PathBuf {
    publish.join("records").join(name)
}

/// The training curve of record `name`, when it has one.
pub fn curve(publish: &Path, name: &str) -> Option<PathBuf> {
    Some(folder(publish, name).join("curve.jsonl")).filter(|p| p.is_file())
}

/// The result recorded for `name`, its table paths under `publish`; None when there is no
/// record. A record of another config or other evaluation settings is an error naming it.
pub fn read(publish: &Path, name: &str, config: &RunConfig, settings: Settings) -> anyhow::Result<Option<RunResult>> {
    let dir = folder(publish, name);
    let path = dir.join("record.json");
    if !path.is_file() {
        return Ok(None);
    }
    let record = load(&path)?;
    let recorded = RunConfig::from_toml(&record.config, &format!("{} (field `config`)", path.display()))?;
    if let Some((ours, theirs)) = first_difference(&config.to_toml(), &recorded.to_toml()) {
        anyhow::bail!(
            "{}: field `config` is another run's (recorded `{theirs}`, this study `{ours}`); publish into another folder \
             or move the record away",
            path.display()
        );
    }
    anyhow::ensure!(
        record.evaluation == settings,
        "{}: field `evaluation` is {:?}, this study evaluates with {:?}; publish into another folder or move the \
         record away",
        path.display(),
        record.evaluation,
        settings
    );
    Ok(Some(rebased(record.result, &dir)))
}

/// Every model recorded under `publish`, this study's or not (its config unchecked), with its
/// training curve when it has one: what the published tables are made of.
pub fn all(publish: &Path) -> anyhow::Result<Vec<(RunResult, Option<PathBuf>)>> {
    let Ok(entries) = std::fs::read_dir(publish.join("records")) else { return Ok(Vec::new()) };
    let mut names: Vec<String> = entries
        .flatten()
        .filter(|e| e.path().join("record.json").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut out = Vec::with_capacity(names.len());
    for name in names {
        let dir = folder(publish, &name);
        let path = dir.join("record.json");
        let record = load(&path)?;
        out.push((rebased(record.result, &dir), curve(publish, &name)));
    }
    Ok(out)
}

/// The model recorded in folder `dir` (PUBLISH/records/NAME), its config unchecked.
pub fn one(dir: &Path) -> anyhow::Result<RunResult> {
    Ok(rebased(load(&dir.join("record.json"))?.result, dir))
}

fn load(path: &Path) -> anyhow::Result<Record> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not a study record", path.display()))
}

fn rebased(mut r: RunResult, dir: &Path) -> RunResult {
    r.test_tables = r.test_tables.map(|p| dir.join(p));
    r.val_tables = r.val_tables.map(|p| dir.join(p));
    r.train_tables = r.train_tables.map(|p| dir.join(p));
    r
}

/// Writes the record of a finished model: `r`'s tables and the run's `metrics.jsonl` (when
/// given) copied in; returns `r` with its table paths in the record.
pub fn write(
    publish: &Path,
    name: &str,
    config: &RunConfig,
    settings: Settings,
    r: &RunResult,
    metrics: Option<&Path>,
) -> anyhow::Result<RunResult> {
    let dir = folder(publish, name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut rel = r.clone();
    let copy = |from: &Option<PathBuf>, to: &str| -> anyhow::Result<Option<PathBuf>> {
        let Some(from) = from else { return Ok(None) };
        let bytes = std::fs::read(from).with_context(|| format!("reading {}", from.display()))?;
        farm::files::write_atomic(&dir.join(to), &bytes)?;
        Ok(Some(PathBuf::from(to)))
    };
    rel.test_tables = copy(&r.test_tables, "test.csv")?;
    rel.val_tables = copy(&r.val_tables, "val.csv")?;
    rel.train_tables = copy(&r.train_tables, "train.csv")?;
    if let Some(test) = r.test_tables.as_deref().and_then(evaluation_dir) {
        write_outcomes(&dir, test)?;
    }
    if let Some(m) = metrics {
        let rows: Vec<CurvePoint> = farm::files::read_jsonl(m)?;
        let lines: Vec<String> = rows.iter().map(serde_json::to_string).collect::<Result<_, _>>()?;
        farm::files::write_atomic(&dir.join("curve.jsonl"), (lines.join("\n") + "\n").as_bytes())?;
    }
    let record = Record { config: config.to_toml(), evaluation: settings, result: rel };
    farm::files::write_atomic(&dir.join("record.json"), serde_json::to_string_pretty(&record)?.as_bytes())?;
    Ok(RunResult {
        test_tables: r.test_tables.as_ref().map(|_| dir.join("test.csv")),
        val_tables: r.val_tables.as_ref().map(|_| dir.join("val.csv")),
        train_tables: r.train_tables.as_ref().map(|_| dir.join("train.csv")),
        ..r.clone()
    })
}

/// The evaluation folder whose `tables.csv` `tables` is, when its passes are there (a record's
/// copy has none).
fn evaluation_dir(tables: &Path) -> Option<&Path> {
    tables.parent().filter(|d| tables.file_name() == Some("tables.csv".as_ref()) && d.join("normal").is_dir())
}

fn write_outcomes(record: &Path, evaluation: &Path) -> anyhow::Result<()> {
    let outcomes = crate::report::outcomes::of_evaluation(evaluation)?;
    Ok(farm::files::write_atomic(&record.join(OUTCOMES), crate::report::outcomes::to_csv(&outcomes).as_bytes())?)
}

/// The test outcomes of `r` (a record's or a run folder's result), when they were kept.
pub fn outcomes(r: &RunResult) -> anyhow::Result<Option<Vec<crate::report::outcomes::Outcome>>> {
    let Some(tables) = &r.test_tables else { return Ok(None) };
    let beside = tables.with_file_name(OUTCOMES);
    if beside.is_file() {
        return crate::report::outcomes::read_csv(&beside).map(Some);
    }
    evaluation_dir(tables).map(crate::report::outcomes::of_evaluation).transpose()
}

/// Adds the test outcomes to record `name` made before records kept them, from the run folder's
/// test evaluation `test` when that is of the recorded checkpoint.
pub fn add_outcomes(publish: &Path, name: &str, r: &RunResult, test: &Path) -> anyhow::Result<()> {
    let dir = folder(publish, name);
    let evaluated = std::fs::read_to_string(test.join("checkpoint")).unwrap_or_default();
    if dir.join(OUTCOMES).is_file() || !test.join("normal").is_dir() || !evaluated.trim().ends_with(&r.checkpoint) {
        return Ok(());
    }
    write_outcomes(&dir, test)
}

/// The first line where two configs differ, as (a's, b's).
fn first_difference(a: &str, b: &str) -> Option<(String, String)> {
    let (mut x, mut y) = (a.lines(), b.lines());
    loop {
        match (x.next(), y.next()) {
            (None, None) => return None,
            (p, q) if p == q => continue,
            (p, q) => return Some((p.unwrap_or("(end)").trim().into(), q.unwrap_or("(end)").trim().into())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> Settings {
        Settings { checkpoints: 4, val_programs: 500, test_programs: 1000 }
    }

    #[test]
    fn a_record_round_trips_and_refuses_another_config_or_evaluation() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("run");
        std::fs::create_dir_all(&run).unwrap();
        let mut r = crate::commands::study::summary::tests::result(&run, "both", 1, 31.5);
        r.val_sr1 = 30.0;
        std::fs::write(run.join("metrics.jsonl"), "{\"frames\":4096,\"success_rate\":0.25,\"loss\":1.0}\n").unwrap();
        let cfg =
            RunConfig::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/tiny/both.toml"))).unwrap();
        let publish = dir.path().join("docs");
        assert!(read(&publish, "both-seed1", &cfg, settings()).unwrap().is_none(), "no record yet");
        let written = write(&publish, "both-seed1", &cfg, settings(), &r, Some(&run.join("metrics.jsonl"))).unwrap();
        // the run folder can go: the record alone serves the tables
        std::fs::remove_dir_all(&run).unwrap();
        let back = read(&publish, "both-seed1", &cfg, settings()).unwrap().expect("recorded");
        assert_eq!(back.test_tables, written.test_tables);
        assert!(back.test_tables.as_ref().unwrap().is_file() && back.train_tables.as_ref().unwrap().is_file());
        assert_eq!((back.test_first, back.val_sr1, back.seed), (r.test_first, 30.0, 1));
        let curve = std::fs::read_to_string(curve(&publish, "both-seed1").unwrap()).unwrap();
        assert_eq!(curve.trim(), r#"{"frames":4096.0,"success_rate":0.25}"#, "the curve keeps what the figure reads");

        let mut other = cfg.clone();
        other.run.total_frames = 5_000_000;
        let e = read(&publish, "both-seed1", &other, settings()).unwrap_err().to_string();
        assert!(e.contains("record.json") && e.contains("`config`") && e.contains("5000000"), "{e}");
        let e =
            read(&publish, "both-seed1", &cfg, Settings { val_programs: 100, ..settings() }).unwrap_err().to_string();
        assert!(e.contains("`evaluation`"), "{e}");
    }

    /// A run's test evaluation as `eval` leaves it: tables and the normal pass's episodes.
    fn test_evaluation(run: &Path, r: &RunResult) -> PathBuf {
        let test = run.join("test");
        std::fs::create_dir_all(test.join("normal")).unwrap();
        std::fs::copy(r.test_tables.as_ref().unwrap(), test.join("tables.csv")).unwrap();
        let episodes: Vec<String> = [(3, true), (4, false)]
            .map(|(p, ok)| serde_json::to_string(&crate::report::tables::tests::result(p, ok)).unwrap())
            .into();
        std::fs::write(test.join("normal/episodes.jsonl"), episodes.join("\n") + "\n").unwrap();
        test
    }

    #[test]
    fn a_record_keeps_its_test_episodes_and_an_older_record_gets_them_from_its_run() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("runs/both-seed1");
        std::fs::create_dir_all(&run).unwrap();
        let cfg =
            RunConfig::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/tiny/both.toml"))).unwrap();
        let publish = dir.path().join("docs");
        let mut r = crate::commands::study::summary::tests::result(dir.path(), "both", 1, 31.5);
        let test = test_evaluation(&run, &r);
        let older = write(&publish, "old-seed1", &cfg, settings(), &r, None).unwrap();
        assert!(outcomes(&older).unwrap().is_none(), "made from tables alone: no episodes to keep");

        r.test_tables = Some(test.join("tables.csv"));
        write(&publish, "both-seed1", &cfg, settings(), &r, None).unwrap();
        std::fs::write(test.join("checkpoint"), format!("/study/{}", r.checkpoint)).unwrap();
        add_outcomes(&publish, "old-seed1", &older, &test).unwrap();
        std::fs::remove_dir_all(&run).unwrap();
        for name in ["both-seed1", "old-seed1"] {
            let back = read(&publish, name, &cfg, settings()).unwrap().unwrap();
            let o = outcomes(&back).unwrap().expect("kept in the record");
            let got: Vec<(u64, bool)> = o.iter().map(|o| (o.program, o.success_first)).collect();
            assert_eq!(got, [(3, true), (4, false)], "{name}");
        }
    }

    #[test]
    fn random_records_keep_their_missing_val_sr() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = crate::commands::study::summary::tests::result(dir.path(), "random", 2, 9.7);
        (r.val_sr1, r.val_tables, r.train_tables) = (f64::NAN, None, None);
        let cfg =
            RunConfig::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/tiny/random.toml"))).unwrap();
        write(dir.path(), "random-seed2", &cfg, settings(), &r, None).unwrap();
        let back = read(dir.path(), "random-seed2", &cfg, settings()).unwrap().unwrap();
        assert!(back.val_sr1.is_nan() && back.val_tables.is_none() && curve(dir.path(), "random-seed2").is_none());
    }
}
