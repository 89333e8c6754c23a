//! The study's ablation tables beside the dissertation's: T4.3 (per scene type on train, val and
//! test), T4.4 (per scene type on test at 1, 2, 3 and unlimited stops), T4.5 (by instances of the
//! target category), T4.6 (blind mode) and T4.7 (visual inputs), each as Markdown and CSV, read
//! from the `eval` tables of the study's selected checkpoints.
//!
//! Every cell is ours as mean ± std over the seeds with the dissertation's figure in brackets.
//! T4.3/T4.4 use models trained per scene type where the study made them (`--per-scene-type`),
//! as the dissertation does; otherwise they break down the models trained in every room, and
//! their "models" column says so.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use farm::rooms::SceneType;

use super::summary::{RunResult, mean_std, method};
use crate::report::tables::{TableRow, find, read_rows};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fold {
    Train,
    Val,
    Test,
}

impl Fold {
    fn name(self) -> &'static str {
        match self {
            Fold::Train => "train",
            Fold::Val => "val",
            Fold::Test => "test",
        }
    }

    fn tables(self, r: &RunResult) -> Option<&PathBuf> {
        match self {
            Fold::Train => r.train_tables.as_ref(),
            Fold::Val => r.val_tables.as_ref(),
            Fold::Test => r.test_tables.as_ref(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Metric {
    Sr,
    Spl,
    Dts,
}

impl Metric {
    fn name(self) -> &'static str {
        match self {
            Metric::Sr => "SR",
            Metric::Spl => "SPL",
            Metric::Dts => "DTS",
        }
    }

    fn of(self, r: &TableRow) -> f64 {
        match self {
            Metric::Sr => r.sr,
            Metric::Spl => r.spl,
            Metric::Dts => r.dts,
        }
    }
}

/// One column of a table: which evaluation, pass and row of it, and which metric.
struct Column {
    head: String,
    fold: Fold,
    mode: &'static str,
    instances: &'static str,
    stops: &'static str,
    metric: Metric,
}

fn col(
    head: impl Into<String>,
    fold: Fold,
    mode: &'static str,
    instances: &'static str,
    stops: &'static str,
    metric: Metric,
) -> Column {
    Column { head: head.into(), fold, mode, instances, stops, metric }
}

/// One line of a table: a method (and, for T4.3/T4.4, a scene type) with the dissertation's
/// figures in the columns' order.
struct Line {
    scene_type: Option<SceneType>,
    stem: &'static str,
    label: &'static str,
    dissertation: &'static [f64],
}

/// Every evaluation table the results name, read once.
struct Loaded<'a> {
    results: &'a [RunResult],
    rows: HashMap<PathBuf, Vec<TableRow>>,
}

impl<'a> Loaded<'a> {
    fn new(results: &'a [RunResult]) -> anyhow::Result<Loaded<'a>> {
        let mut rows = HashMap::new();
        for r in results {
            for p in [r.test_tables.as_ref(), r.val_tables.as_ref(), r.train_tables.as_ref()].into_iter().flatten() {
                if !rows.contains_key(p) {
                    rows.insert(p.clone(), read_rows(p)?);
                }
            }
        }
        Ok(Loaded { results, rows })
    }

    /// The models behind a line: those trained in its scene type's rooms when there are any,
    /// else those trained in every room; with what the "models" column says of them.
    fn models(&self, line: &Line) -> (Vec<&'a RunResult>, &'static str) {
        let of = |t: Option<SceneType>| -> Vec<&'a RunResult> {
            self.results.iter().filter(|r| r.stem == line.stem && r.scene_type == t).collect()
        };
        let Some(t) = line.scene_type else { return (of(None), "all types") };
        let own = of(Some(t));
        if own.is_empty() { (of(None), "all types, broken down") } else { (own, "one per type") }
    }

    /// The column's value for each of `models` (the line's seeds) that has it.
    fn values(&self, line: &Line, models: &[&RunResult], c: &Column) -> Vec<f64> {
        let scene = line.scene_type.map_or("all", |t| t.name());
        models
            .iter()
            .filter_map(|r| c.fold.tables(r).and_then(|p| self.rows.get(p)))
            .filter_map(|rows| find(rows, line.mode(c), scene, c.instances, c.stops).map(|row| c.metric.of(row)))
            .collect()
    }
}

impl Line {
    /// The pass a column reads for this line: Random sees nothing to zero, so its blind pass is
    /// its normal one.
    fn mode(&self, c: &Column) -> &'static str {
        if self.stem == "random" { "normal" } else { c.mode }
    }
}

/// A table as Markdown (ours ± std with the dissertation in brackets) and long-format CSV; None
/// when no line has any value.
fn table(name: &str, caption: &str, lines: &[Line], columns: &[Column], data: &Loaded) -> Option<(String, String)> {
    let per_type = lines.iter().any(|l| l.scene_type.is_some());
    let mut md = format!("# {name}\n\n{caption}\n\n");
    let lead = if per_type { "| scene type | method | models |" } else { "| method |" };
    let _ = write!(md, "{lead}");
    for c in columns {
        let _ = write!(md, " {} |", c.head);
    }
    let _ = write!(md, "\n|{}", if per_type { "---|---|---|" } else { "---|" });
    md.push_str(&"---:|".repeat(columns.len()));
    md.push('\n');
    let mut csv =
        String::from("table,scene_type,method,models,split,mode,instances,stops,metric,seeds,mean,std,dissertation\n");
    let (mut any, mut dash) = (false, false);
    for line in lines {
        let (runs, models) = data.models(line);
        let cells: Vec<Vec<f64>> = columns.iter().map(|c| data.values(line, &runs, c)).collect();
        if cells.iter().all(Vec::is_empty) {
            continue;
        }
        any = true;
        let label = line.label;
        match line.scene_type {
            Some(t) => {
                let _ = write!(md, "| {} | {label} | {models} |", t.name());
            }
            None => {
                let _ = write!(md, "| {label} |");
            }
        }
        for (i, (c, v)) in columns.iter().zip(&cells).enumerate() {
            let digits = if c.metric == Metric::Dts { 2 } else { 1 };
            // a table beyond the dissertation's has no figure in brackets
            let (d, bracket) = match line.dissertation.get(i) {
                Some(d) => (format!("{d:?}"), format!(" ({d:?})")),
                None => (String::new(), String::new()),
            };
            if v.is_empty() {
                let _ = write!(md, " -{bracket} |");
                dash = true;
                continue;
            }
            let (mean, std) = mean_std(v);
            let _ = write!(md, " {mean:.digits$} ± {std:.digits$}{bracket} |");
            let _ = writeln!(
                csv,
                "{name},{},{label},{models},{},{},{},{},{},{},{mean:.4},{std:.4},{d}",
                line.scene_type.map_or("all", |t| t.name()),
                c.fold.name(),
                line.mode(c),
                c.instances,
                c.stops,
                c.metric.name(),
                v.len()
            );
        }
        md.push('\n');
    }
    if dash {
        md.push_str(MISSING);
    }
    any.then_some((md, csv))
}

/// Below a table with a dash in it: what the dash means.
const MISSING: &str = "\n-: none of the method's records holds this evaluation. A record tested before an \
                       evaluation mode existed has none of it; `study` tests a model once and does not add it.\n";

const CELL: &str = "Each cell: ours, mean ± std over seeds (the dissertation's figure in brackets).";

/// T4.3 and T4.4's lines: the three methods per scene type, as the dissertation prints them.
fn per_type_lines(figures: &'static [[&'static [f64]; 3]; 4]) -> Vec<Line> {
    let mut lines = Vec::new();
    for (t, per_method) in SceneType::ALL.into_iter().zip(figures) {
        for (stem, d) in ["vis_sem", "referencing", "intervention"].into_iter().zip(per_method) {
            lines.push(Line { scene_type: Some(t), stem, label: label(stem), dissertation: d });
        }
    }
    lines
}

fn label(stem: &str) -> &'static str {
    method(stem).map_or("?", |m| m.label)
}

fn lines(rows: &[(&'static str, &'static [f64])]) -> Vec<Line> {
    rows.iter().map(|&(stem, d)| Line { scene_type: None, stem, label: label(stem), dissertation: d }).collect()
}

// The dissertation's tables, in the order of the columns below.
const T43: [[&[f64]; 3]; 4] = [
    [&[12.3, 10.2, 11.5, 7.6, 7.1, 7.9], &[21.1, 18.7, 19.2, 13.3, 11.6, 11.2], &[44.9, 31.5, 40.3, 27.0, 20.0, 24.0]],
    [&[6.3, 3.6, 3.5, 4.1, 2.3, 2.1], &[4.9, 3.2, 2.7, 3.2, 1.7, 1.6], &[13.0, 9.0, 9.5, 7.8, 5.3, 5.4]],
    [&[15.2, 9.1, 8.7, 9.1, 5.3, 5.4], &[43.5, 10.7, 15.4, 28.3, 6.6, 10.5], &[42.4, 22.4, 20.4, 27.5, 13.8, 11.9]],
    [&[16.3, 15.5, 11.9, 11.4, 9.1, 8.8], &[33.0, 19.4, 19.9, 20.5, 11.1, 11.7], &[40.5, 32.2, 35.0, 29.1, 21.0, 23.0]],
];
const T44: [[&[f64]; 3]; 4] = [
    [
        &[11.5, 18.0, 23.1, 49.3, 7.9, 12.1, 14.6, 25.1],
        &[19.2, 26.3, 29.7, 47.9, 11.2, 15.0, 16.6, 24.1],
        &[40.3, 55.1, 62.8, 89.0, 24.0, 32.7, 37.2, 52.8],
    ],
    [
        &[3.5, 6.4, 9.5, 23.3, 2.1, 3.7, 5.1, 9.8],
        &[2.7, 3.9, 4.7, 7.8, 1.6, 2.4, 2.9, 4.7],
        &[9.5, 16.9, 21.7, 58.0, 5.4, 9.8, 12.6, 30.8],
    ],
    [
        &[8.7, 15.3, 18.4, 31.0, 5.4, 9.5, 11.2, 17.0],
        &[15.4, 18.7, 20.2, 31.9, 10.5, 12.4, 13.3, 19.2],
        &[20.4, 27.9, 33.5, 51.2, 11.9, 16.3, 19.5, 29.7],
    ],
    [
        &[11.9, 18.9, 23.7, 57.8, 8.8, 13.8, 16.9, 33.1],
        &[19.9, 30.5, 35.9, 64.3, 11.7, 18.1, 21.3, 32.4],
        &[35.0, 44.6, 51.7, 76.5, 23.0, 29.6, 33.9, 48.3],
    ],
];

/// Writes `T4.3.md/.csv` … `T4.7.md/.csv` into `out` for the tables the results can fill.
pub fn write(out: &Path, results: &[RunResult]) -> anyhow::Result<()> {
    let data = Loaded::new(results)?;
    let tables = [t43(), t44(), t45(), t46(), pointing(), t47()];
    for (name, caption, lines, columns) in tables {
        if let Some((md, csv)) = table(name, &caption, &lines, &columns, &data) {
            farm::files::write_atomic(&out.join(format!("{name}.md")), md.as_bytes())?;
            farm::files::write_atomic(&out.join(format!("{name}.csv")), csv.as_bytes())?;
        }
    }
    Ok(())
}

/// One table: its name, caption, rows (with the dissertation's figures) and columns.
type Spec = (&'static str, String, Vec<Line>, Vec<Column>);

const PER_TYPE_NOTE: &str = "The dissertation trains one model per scene type for this table; \"one per type\" rows are \
                             such models (`--per-scene-type`), \"all types, broken down\" rows are the models trained in \
                             every room evaluated on that type's rooms only.";

/// SR and SPL per scene type on train, val and test.
fn t43() -> Spec {
    let mut c43 = Vec::new();
    for m in [Metric::Sr, Metric::Spl] {
        for f in [Fold::Train, Fold::Val, Fold::Test] {
            c43.push(col(format!("{} {} (%)", m.name(), f.name()), f, "normal", "all", "1", m));
        }
    }
    (
        "T4.3",
        format!(
            "SR and SPL at the first stop per scene type on train, val and test: the selected checkpoint on a \
             spread of each split's programs (val: the evaluation that selected it, so biased upward). \
             {PER_TYPE_NOTE} {CELL}"
        ),
        per_type_lines(&T43),
        c43,
    )
}

/// SR and SPL per scene type at 1, 2, 3 and unlimited stops.
fn t44() -> Spec {
    let mut c44 = Vec::new();
    for m in [Metric::Sr, Metric::Spl] {
        for (k, head) in [("1", "1"), ("2", "2"), ("3", "3"), ("inf", "∞")] {
            c44.push(col(format!("{} {head}", m.name()), Fold::Test, "normal", "all", k, m));
        }
    }
    (
        "T4.4",
        format!("SR and SPL (%) on test per scene type at 1, 2, 3 and unlimited (∞) stops. {PER_TYPE_NOTE} {CELL}"),
        per_type_lines(&T44),
        c44,
    )
}

/// SR and SPL by the number of instances of the target category.
fn t45() -> Spec {
    let mut c45 = Vec::new();
    for m in [Metric::Sr, Metric::Spl] {
        for b in ["1", "2", "3+"] {
            c45.push(col(format!("{} {b}", m.name()), Fold::Test, "normal", b, "1", m));
        }
    }
    (
        "T4.5",
        format!(
            "SR and SPL (%) on test at the first stop by the number of instances of the target category in the room \
             (a breakdown of each model's test episodes). {CELL}"
        ),
        lines(&[
            ("vis_sem", &[20.2, 18.9, 8.0, 6.1, 7.0, 4.3]),
            ("referencing", &[21.1, 19.8, 13.5, 7.9, 8.3, 6.4]),
            ("intervention", &[49.2, 41.1, 32.2, 17.7, 16.7, 11.1]),
            ("both", &[55.2, 47.5, 36.5, 19.4, 20.3, 11.4]),
        ]),
        c45,
    )
}

/// T4.6's and T4.7's columns: SR, SPL and DTS on test at the first stop, in `mode`.
fn first(mode: &'static str) -> Vec<Column> {
    vec![
        col("SR (%)", Fold::Test, mode, "all", "1", Metric::Sr),
        col("SPL (%)", Fold::Test, mode, "all", "1", Metric::Spl),
        col("DTS (m)", Fold::Test, mode, "all", "1", Metric::Dts),
    ]
}

/// Blind mode.
fn t46() -> Spec {
    (
        "T4.6",
        format!(
            "Blind mode: the models of T4.2 on test at the first stop with their visual inputs zeroed at evaluation \
             (they were trained seeing). Random sees nothing, so its row is its normal evaluation. {CELL}"
        ),
        lines(&[
            ("random", &[8.7, 7.1, 2.908]),
            ("vis_sem", &[6.5, 5.8, 2.772]),
            ("referencing", &[11.2, 9.4, 2.769]),
            ("intervention", &[21.26, 16.1, 2.614]),
            ("both", &[22.64, 16.3, 2.578]),
        ]),
        first("blind"),
    )
}

/// Own gesture against another room's.
fn pointing() -> Spec {
    let sr =
        |head: &str, mode: &'static str, stops: &'static str| col(head, Fold::Test, mode, "all", stops, Metric::Sr);
    (
        "pointing",
        "Is where the arm points read? (beyond the dissertation) The models shown the referencing gesture, on test: \
         SR (%) with each program's own gesture and with another room's (the program half the split on; the person \
         stands and faces where the program puts them). What a policy gained from where the arm points, it loses \
         with another room's gesture; what it gained from where the person stands, it keeps. Each cell: mean ± std \
         over seeds; each model's test/tables.md pairs the two program by program (McNemar)."
            .to_string(),
        lines(&[("referencing", &[]), ("both", &[])]),
        vec![
            sr("SR 1, own gesture", "normal", "1"),
            sr("SR 1, another room's", "other_gesture", "1"),
            sr("SR ∞, own gesture", "normal", "inf"),
            sr("SR ∞, another room's", "other_gesture", "inf"),
        ],
    )
}

/// RGB only, depth only, RGB-D.
fn t47() -> Spec {
    let mut t47 = lines(&[("rgb_sem_both", &[41.4, 23.2, 1.988]), ("depth_sem_both", &[41.0, 24.8, 2.012])]);
    t47.push(Line { scene_type: None, stem: "both", label: "RGBD+Semantic+Both", dissertation: &[49.2, 28.7, 1.976] });
    (
        "T4.7",
        format!(
            "Visual inputs: +Both trained separately with RGB only, depth only, and RGB-D (the frozen encoder's other \
             input zeroed in training and evaluation); test, first stop. {CELL}"
        ),
        t47,
        first("normal"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::commands::study::summary::tests::result;

    #[test]
    fn ablation_tables_hold_ours_beside_the_dissertation_and_name_their_models() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut results = vec![
            result(d, "vis_sem", 1, 4.0),
            result(d, "vis_sem", 2, 6.0),
            result(d, "both", 1, 10.0),
            result(d, "random", 1, 1.0),
        ];
        let mut kitchen = result(d, "intervention", 1, 30.0);
        kitchen.scene_type = Some(SceneType::Kitchen);
        results.push(kitchen);
        write(d, &results).unwrap();
        let t43 = std::fs::read_to_string(d.join("T4.3.md")).unwrap();
        assert!(t43.contains("| Kitchen | VisSem | all types, broken down | 5.0 ± 1.4 (12.3) |"), "{t43}");
        assert!(t43.contains("| Kitchen | +Intervention | one per type | 30.0 ± 0.0 (44.9) |"), "{t43}");
        assert!(!t43.contains("| Bedroom | +Intervention"), "no model, no line: {t43}");
        let t44 = std::fs::read_to_string(d.join("T4.4.md")).unwrap();
        assert!(t44.contains("| Kitchen | VisSem | all types, broken down | 5.0 ± 1.4 (11.5) | 5.0 ± 1.4 (18.0) | 5.0 ± 1.4 (23.1) | 50.0 ± 0.0 (49.3) |"), "{t44}");
        let t46 = std::fs::read_to_string(d.join("T4.6.md")).unwrap();
        assert!(
            t46.contains("| Random | 1.0 ± 0.0 (8.7) |") && t46.contains("| +Both | 10.0 ± 0.0 (22.64) |"),
            "{t46}"
        );
        let t47 = std::fs::read_to_string(d.join("T4.7.md")).unwrap();
        assert!(t47.contains("| RGBD+Semantic+Both | 10.0 ± 0.0 (49.2) |") && !t47.contains("| RGB+Semantic"), "{t47}");
        let pointing = std::fs::read_to_string(d.join("pointing.md")).unwrap();
        assert!(pointing.contains("| +Both | 10.0 ± 0.0 | 9.0 ± 0.0 | 50.0 ± 0.0 | 40.0 ± 0.0 |"), "{pointing}");
        assert!(!pointing.contains("VisSem") && !pointing.contains("(49.2)"), "{pointing}");
        let csv = std::fs::read_to_string(d.join("pointing.csv")).unwrap();
        assert!(
            csv.lines().any(|l| l == "pointing,all,+Both,all types,test,other_gesture,all,1,SR,1,9.0000,0.0000,"),
            "{csv}"
        );
        let csv = std::fs::read_to_string(d.join("T4.5.csv")).unwrap();
        assert!(csv.lines().any(|l| l == "T4.5,all,VisSem,all types,test,normal,3+,1,SR,2,5.0000,1.4142,8.0"), "{csv}");
    }

    #[test]
    fn a_dash_is_explained_below_its_table() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // a record tested before the other-gesture evaluation existed
        let old = result(d, "referencing", 1, 20.0);
        let path = old.test_tables.clone().unwrap();
        let tables = std::fs::read_to_string(&path).unwrap();
        let tables: String =
            tables.lines().filter(|l| !l.contains(",other_gesture,")).map(|l| format!("{l}\n")).collect();
        std::fs::write(&path, tables).unwrap();
        write(d, &[old, result(d, "both", 1, 10.0)]).unwrap();
        let pointing = std::fs::read_to_string(d.join("pointing.md")).unwrap();
        assert!(pointing.contains("| +Referencing | 20.0 ± 0.0 | - | 50.0 ± 0.0 | - |"), "{pointing}");
        assert!(pointing.ends_with(MISSING), "{pointing}");
        let t46 = std::fs::read_to_string(d.join("T4.6.md")).unwrap();
        assert!(!t46.contains(" - ") && !t46.contains(MISSING), "no dash, no note: {t46}");
    }
}
