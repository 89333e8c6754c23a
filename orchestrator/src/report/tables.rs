//! Evaluation tables in the layouts of chapter 4 (T4.2–T4.7), as Markdown and CSV.

use std::collections::BTreeMap;
use std::fmt::Write;

use serde::{Deserialize, Serialize};

use farm::metrics::{EpisodeResult, FirstStops, Paired, Scores, scores};
use worker::program::Program;
use worker::scene::SceneType;

/// Random's SR and SPL at the first stop on test in the dissertation (T4.2, %).
pub const RANDOM_DISSERTATION: (f64, f64) = (8.7, 7.1);

/// What the policy may see during an evaluation pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EvalMode {
    /// Everything the checkpoint was trained with.
    Normal,
    /// Visual inputs zeroed (T4.6).
    Blind,
    /// Depth zeroed: RGB only (T4.7).
    RgbOnly,
    /// RGB zeroed: depth only (T4.7).
    DepthOnly,
    /// Every program shows the referencing gesture of the program half its split on (another
    /// room; the person stands and faces where the program puts them): what the policy gained
    /// from where the arm points, it loses (`task.gesture_shift`).
    OtherGesture,
}

impl EvalMode {
    pub const ALL: [EvalMode; 5] =
        [EvalMode::Normal, EvalMode::Blind, EvalMode::RgbOnly, EvalMode::DepthOnly, EvalMode::OtherGesture];

    pub fn name(self) -> &'static str {
        match self {
            EvalMode::Normal => "normal",
            EvalMode::Blind => "blind",
            EvalMode::RgbOnly => "rgb_only",
            EvalMode::DepthOnly => "depth_only",
            EvalMode::OtherGesture => "other_gesture",
        }
    }

    pub fn from_name(s: &str) -> Option<EvalMode> {
        EvalMode::ALL.into_iter().find(|m| m.name() == s)
    }

    /// (zero RGB, zero depth) for the policy's inputs.
    pub fn zeroed(self) -> (bool, bool) {
        match self {
            EvalMode::Normal | EvalMode::OtherGesture => (false, false),
            EvalMode::Blind => (true, true),
            EvalMode::RgbOnly => (false, true),
            EvalMode::DepthOnly => (true, false),
        }
    }
}

pub const STOPS: [(Option<usize>, &str); 4] = [(Some(1), "1"), (Some(2), "2"), (Some(3), "3"), (None, "∞")];

/// Everything one checkpoint's evaluation produced.
pub struct Evaluation<'a> {
    pub label: String,
    pub split: &'a str,
    pub programs: &'a [Program],
    pub passes: BTreeMap<EvalMode, Vec<EpisodeResult>>,
    pub dts_threshold: f64,
}

fn bucket(instances: u32) -> &'static str {
    match instances {
        0 | 1 => "1",
        2 => "2",
        _ => "3+",
    }
}

impl Evaluation<'_> {
    fn scene_type(&self, e: &EpisodeResult) -> SceneType {
        self.programs[e.program as usize].scene_type
    }

    fn instances(&self, e: &EpisodeResult) -> u32 {
        self.programs[e.program as usize].instances
    }

    pub fn scores(&self, mode: EvalMode, k: Option<usize>, filter: impl Fn(&EpisodeResult) -> bool) -> Option<Scores> {
        let eps = self.passes.get(&mode)?;
        Some(scores(eps.iter().filter(|e| filter(e)), k, self.dts_threshold))
    }

    /// (successful episodes of every pass whose path is shorter than their l_i, successful
    /// episodes): the first should be 0, as l_i is a lower bound.
    pub fn shorter_than_l(&self) -> (usize, usize) {
        let wins: Vec<&EpisodeResult> = self.passes.values().flatten().filter(|e| e.success).collect();
        // 1 mm of slack for f32 sums of 0.25 m steps
        (wins.iter().filter(|e| e.path_length < e.shortest_path - 1e-3).count(), wins.len())
    }

    /// Markdown with every table this evaluation supports.
    pub fn markdown(&self) -> String {
        let mut md = String::new();
        self.md_header(&mut md);
        self.md_stops(&mut md);
        self.md_first_stop(&mut md);
        self.md_per_scene_type(&mut md);
        self.md_by_instances(&mut md);
        self.md_blind(&mut md);
        self.md_other_gesture(&mut md);
        self.md_vision(&mut md);
        md
    }

    /// The title, the success rule and how SPL's shortest paths held.
    fn md_header(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        let n = self.passes.get(&normal).map_or(0, |v| v.len());
        writeln!(md, "# Evaluation: {} on {} ({} episodes)\n", self.label, self.split, n).unwrap();
        writeln!(
            md,
            "DTS threshold {:.2} m; success needs Stop within 1 m of the target with the target in view.\n",
            self.dts_threshold
        )
        .unwrap();
        let (short, successes) = self.shorter_than_l();
        writeln!(
            md,
            "SPL's l_i is a lower bound of any successful path (`worker::shortest_path`): {short} of {successes} \
             successful episodes were shorter than their l_i.\n"
        )
        .unwrap();
    }

    /// SR, SPL and DTS at 1, 2, 3 and unlimited stops.
    fn md_stops(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        writeln!(md, "## Navigation performance at 1, 2, 3 and unlimited stops (T4.2 at the first stop)\n").unwrap();
        writeln!(md, "| stops | SR (%) | SPL (%) | DTS (m) |\n|---|---:|---:|---:|").unwrap();
        for (k, name) in STOPS {
            if let Some(s) = self.scores(normal, k, |_| true) {
                writeln!(md, "| {name} | {:.1} | {:.1} | {:.3} |", s.sr, s.spl, s.dts).unwrap();
            }
        }
    }

    /// Where the policy stops the first time.
    fn md_first_stop(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        if let Some(eps) = self.passes.get(&normal) {
            let f = FirstStops::of(eps, 1.0);
            let (sr, (lo, hi)) = f.sr();
            writeln!(md, "\n## The first stop: where the policy stops\n").unwrap();
            writeln!(
                md,
                "| SR 1 (%) | 95% interval | episodes with a stop | first stops within 1 m of the target | mean step of the first stop | SR 1 / SR ∞ |\n|---:|---:|---:|---:|---:|---:|"
            )
            .unwrap();
            writeln!(
                md,
                "| {sr:.1} | {lo:.1}–{hi:.1} | {:.1}% | {:.1}% | {:.1} | {:.2} |",
                f.stopped_share(),
                f.near_share(),
                f.mean_step,
                f.ratio()
            )
            .unwrap();
        }
    }

    /// T4.3 / T4.4's breakdown by scene type.
    fn md_per_scene_type(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        writeln!(md, "\n## Per scene type (T4.3 / T4.4)\n").unwrap();
        writeln!(md, "| scene type | episodes | SR 1 | SR 2 | SR 3 | SR ∞ | SPL 1 | SPL 2 | SPL 3 | SPL ∞ |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|").unwrap();
        for t in SceneType::ALL {
            let row: Vec<Scores> =
                STOPS.iter().filter_map(|(k, _)| self.scores(normal, *k, |e| self.scene_type(e) == t)).collect();
            if row.is_empty() || row[0].episodes == 0 {
                continue;
            }
            write!(md, "| {} | {} ", t.name(), row[0].episodes).unwrap();
            for s in &row {
                write!(md, "| {:.1} ", s.sr).unwrap();
            }
            for s in &row {
                write!(md, "| {:.1} ", s.spl).unwrap();
            }
            writeln!(md, "|").unwrap();
        }
    }

    /// T4.5: by instances of the target category.
    fn md_by_instances(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        writeln!(md, "\n## By instances of the target category in the room, first stop (T4.5)\n").unwrap();
        writeln!(md, "| instances | episodes | SR (%) | SPL (%) | DTS (m) |\n|---|---:|---:|---:|---:|").unwrap();
        for b in ["1", "2", "3+"] {
            if let Some(s) = self.scores(normal, Some(1), |e| bucket(self.instances(e)) == b) {
                if s.episodes > 0 {
                    writeln!(md, "| {b} | {} | {:.1} | {:.1} | {:.3} |", s.episodes, s.sr, s.spl, s.dts).unwrap();
                }
            }
        }
    }

    /// T4.6: blind mode beside normal.
    fn md_blind(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        if let Some(s) = self.scores(EvalMode::Blind, Some(1), |_| true) {
            writeln!(md, "\n## Blind mode: visual inputs zeroed, first stop (T4.6)\n").unwrap();
            writeln!(md, "| mode | SR (%) | SPL (%) | DTS (m) |\n|---|---:|---:|---:|").unwrap();
            if let Some(n) = self.scores(normal, Some(1), |_| true) {
                writeln!(md, "| with vision | {:.1} | {:.1} | {:.3} |", n.sr, n.spl, n.dts).unwrap();
            }
            writeln!(md, "| blind | {:.1} | {:.1} | {:.3} |", s.sr, s.spl, s.dts).unwrap();
        }
    }

    /// Own gesture against another program's.
    fn md_other_gesture(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        if let (Some(own), Some(other)) = (self.passes.get(&normal), self.passes.get(&EvalMode::OtherGesture)) {
            writeln!(md, "\n## Another program's gesture: is where the arm points read?\n").unwrap();
            writeln!(
                md,
                "Each program showed the referencing gesture of the program half the split on (another room); \
                 the person stood and faced where the program puts them. A policy that reads where the arm \
                 points loses what it gained from it.\n"
            )
            .unwrap();
            writeln!(md, "| gesture | SR 1 (%) | SPL 1 (%) | SR ∞ (%) | SPL ∞ (%) |\n|---|---:|---:|---:|---:|")
                .unwrap();
            for (name, eps) in [("its own", own), ("another program's", other)] {
                let (first, any) = (scores(eps, Some(1), self.dts_threshold), scores(eps, None, self.dts_threshold));
                writeln!(md, "| {name} | {:.1} | {:.1} | {:.1} | {:.1} |", first.sr, first.spl, any.sr, any.spl)
                    .unwrap();
            }
            md.push('\n');
            md.push_str(&paired(&[("its own gesture".into(), own), ("another program's".into(), other)]));
        }
    }

    /// T4.7: RGB or depth alone.
    fn md_vision(&self, md: &mut String) {
        let normal = EvalMode::Normal;
        let rgb = self.scores(EvalMode::RgbOnly, Some(1), |_| true);
        let depth = self.scores(EvalMode::DepthOnly, Some(1), |_| true);
        if rgb.is_some() || depth.is_some() {
            writeln!(md, "\n## Visual perception ablation, first stop (T4.7)\n").unwrap();
            writeln!(md, "| vision | SR (%) | SPL (%) | DTS (m) |\n|---|---:|---:|---:|").unwrap();
            for (name, s) in [("RGB", rgb), ("Depth", depth), ("RGB-D", self.scores(normal, Some(1), |_| true))] {
                if let Some(s) = s {
                    writeln!(md, "| {name} | {:.1} | {:.1} | {:.3} |", s.sr, s.spl, s.dts).unwrap();
                }
            }
        }
    }

    /// Random at the first stop beside the dissertation's (T4.2: SR 8.7%, SPL 7.1%): the task's
    /// calibration, as Random knows nothing but the distances of the starts.
    pub fn calibration(&self) -> Option<String> {
        let eps = self.passes.get(&EvalMode::Normal)?;
        let f = FirstStops::of(eps, 1.0);
        let (sr, (lo, hi)) = f.sr();
        let spl = self.scores(EvalMode::Normal, Some(1), |_| true)?.spl;
        let (d_sr, d_spl) = RANDOM_DISSERTATION;
        let verdict = if (lo..=hi).contains(&d_sr) { "inside" } else { "outside" };
        Some(format!(
            "## Calibration: Random at the first stop against the dissertation's\n\n\
             | | SR 1 (%) | 95% interval (Wilson) | SPL 1 (%) | episodes |\n|---|---:|---:|---:|---:|\n\
             | this evaluation | {sr:.1} | {lo:.1}–{hi:.1} | {spl:.1} | {} |\n\
             | the dissertation (T4.2) | {d_sr:.1} | | {d_spl:.1} | |\n\n\
             The dissertation's SR is {verdict} this evaluation's 95% interval.\n",
            f.episodes
        ))
    }

    /// One CSV row per (mode, scene type or "all", instance bucket or "all", stops).
    pub fn csv(&self) -> String {
        let mut out = String::from("label,split,mode,scene_type,instances,stops,episodes,sr,spl,dts\n");
        let types: Vec<Option<SceneType>> = std::iter::once(None).chain(SceneType::ALL.into_iter().map(Some)).collect();
        let buckets = [None, Some("1"), Some("2"), Some("3+")];
        for (&mode, _) in &self.passes {
            for t in &types {
                for b in buckets {
                    for (k, kname) in STOPS {
                        let s = self
                            .scores(mode, k, |e| {
                                t.is_none_or(|t| self.scene_type(e) == t)
                                    && b.is_none_or(|b| bucket(self.instances(e)) == b)
                            })
                            .unwrap_or_default();
                        if s.episodes == 0 {
                            continue;
                        }
                        let kname = if kname == "∞" { "inf" } else { kname };
                        writeln!(
                            out,
                            "{},{},{},{},{},{},{},{:.3},{:.3},{:.4}",
                            csv_field(&self.label),
                            self.split,
                            mode.name(),
                            t.map_or("all", |t| t.name()),
                            b.unwrap_or("all"),
                            kname,
                            s.episodes,
                            s.sr,
                            s.spl,
                            s.dts
                        )
                        .unwrap();
                    }
                }
            }
        }
        out
    }
}

/// One row of `tables.csv` as [`Evaluation::csv`] writes it (scene type, instances and stops
/// as written: "all", "3+", "inf").
#[derive(Clone, Debug, PartialEq)]
pub struct TableRow {
    pub mode: String,
    pub scene_type: String,
    pub instances: String,
    pub stops: String,
    pub episodes: u64,
    pub sr: f64,
    pub spl: f64,
    pub dts: f64,
}

/// The rows of an evaluation's `tables.csv`; a malformed file is one error naming it and the field.
pub fn read_rows(csv: &std::path::Path) -> anyhow::Result<Vec<TableRow>> {
    use anyhow::Context;
    let text = std::fs::read_to_string(csv).with_context(|| format!("reading {}", csv.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| {
        header.iter().position(|h| *h == name).with_context(|| format!("{}: no column `{name}`", csv.display()))
    };
    let cols = ["mode", "scene_type", "instances", "stops", "episodes", "sr", "spl", "dts"].map(col);
    let [mode, scene, inst, stops, episodes, sr, spl, dts] = cols;
    let (mode, scene, inst, stops, episodes, sr, spl, dts) = (mode?, scene?, inst?, stops?, episodes?, sr?, spl?, dts?);
    let mut rows = Vec::new();
    for (n, line) in lines.enumerate() {
        let f = fields(line);
        anyhow::ensure!(
            f.len() == header.len(),
            "{}: line {} has {} fields, not {}",
            csv.display(),
            n + 2,
            f.len(),
            header.len()
        );
        let num = |i: usize| {
            f[i].parse::<f64>()
                .with_context(|| format!("{}: line {}: {} `{}` is not a number", csv.display(), n + 2, header[i], f[i]))
        };
        rows.push(TableRow {
            mode: f[mode].into(),
            scene_type: f[scene].into(),
            instances: f[inst].into(),
            stops: f[stops].into(),
            episodes: num(episodes)? as u64,
            sr: num(sr)?,
            spl: num(spl)?,
            dts: num(dts)?,
        });
    }
    Ok(rows)
}

/// `text` as a CSV field: quoted, its quotes doubled, when it holds a comma or a quote (a
/// label such as "+Both, greedy").
fn csv_field(text: &str) -> std::borrow::Cow<'_, str> {
    match text.contains([',', '"']) {
        true => format!("\"{}\"", text.replace('"', "\"\"")).into(),
        false => text.into(),
    }
}

/// A `tables.csv` line's fields; the first (the label) may be quoted as [`csv_field`] writes it,
/// and is returned as written between its quotes.
fn fields(line: &str) -> Vec<&str> {
    let Some(quoted) = line.strip_prefix('"') else { return line.split(',').collect() };
    let bytes = quoted.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        match (bytes[i], bytes.get(i + 1)) {
            (b'"', Some(b'"')) => i += 2,
            (b'"', _) => break,
            _ => i += 1,
        }
    }
    let mut f = vec![&quoted[..i.min(quoted.len())]];
    if let Some(rest) = quoted.get(i + 1..).and_then(|r| r.strip_prefix(',')) {
        f.extend(rest.split(','));
    }
    f
}

/// The row of `mode`, scene type, instance bucket and stops among `rows`.
pub fn find<'r>(
    rows: &'r [TableRow],
    mode: &str,
    scene_type: &str,
    instances: &str,
    stops: &str,
) -> Option<&'r TableRow> {
    rows.iter().find(|r| r.mode == mode && r.scene_type == scene_type && r.instances == instances && r.stops == stops)
}

/// Several evaluations side by side, as T4.2 (first stop) with ∞ columns added.
pub fn compare(rows: &[(String, Scores, Scores)]) -> String {
    let mut md = String::from(
        "| method | SR (%) | SPL (%) | DTS (m) | SR ∞ (%) | SPL ∞ (%) |\n|---|---:|---:|---:|---:|---:|\n",
    );
    for (label, first, inf) in rows {
        writeln!(
            md,
            "| {label} | {:.1} | {:.1} | {:.3} | {:.1} | {:.1} |",
            first.sr, first.spl, first.dts, inf.sr, inf.spl
        )
        .unwrap();
    }
    md
}

/// Each later evaluation against the first, episode by episode on the programs both ran: where
/// one succeeds and the other fails, at the first stop and with unlimited stops.
pub fn paired(evaluations: &[(String, &[EpisodeResult])]) -> String {
    let Some(((first, a), rest)) = evaluations.split_first() else { return String::new() };
    let mut md = format!(
        "Episode by episode against the first, **{first}** (the programs both ran; z = McNemar's \
         statistic, (only the first − only this one) / √(their sum), |z| > 1.96 at 5%):\n\n\
         | evaluation | stops | programs | both succeed | only the first | only this one | neither | z |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n"
    );
    for (label, b) in rest {
        for (k, stops) in [(Some(1), "1"), (None, "∞")] {
            let p = Paired::of(a, b, k);
            writeln!(
                md,
                "| {label} | {stops} | {} | {} | {} | {} | {} | {:.1} |",
                p.programs(),
                p.both,
                p.only_first,
                p.only_second,
                p.neither,
                p.mcnemar_z()
            )
            .unwrap();
        }
    }
    md
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use farm::metrics::Stop;
    use worker::program::Hand;
    use worker::scene::Category;

    /// A program in FloorPlan1 with everyone at the origin.
    pub(crate) fn program(id: u64, t: SceneType, instances: u32) -> Program {
        Program {
            id,
            scene: "FloorPlan1".into(),
            scene_type: t,
            target: Category::Cup,
            target_object: 0,
            target_pos: [0.0; 3],
            instances,
            human_pos: [0.0; 3],
            human_yaw: 0.0,
            robot_pos: [0.0; 3],
            robot_yaw: 0.0,
            geodesic: 2.0,
            target_geodesic: 2.9,
            starts_successful: false,
            robot_human_distance: 1.0,
            gesture_accuracy: 0.5,
            hand: Hand::Right,
            style: 0,
            seed: id,
        }
    }

    /// One episode of one stop at step 9 that succeeds or not.
    pub(crate) fn result(program: u64, success: bool) -> EpisodeResult {
        EpisodeResult {
            program,
            worker: 0,
            env: 0,
            generation: 0,
            steps: 9,
            success,
            collisions: 0,
            num_stops: 1,
            path_length: 2.0,
            shortest_path: 2.0,
            final_distance: if success { 0.5 } else { 3.0 },
            total_reward: 0.0,
            intervention_steps: 0,
            stops: vec![Stop { step: 9, success, distance: if success { 0.5 } else { 3.0 }, path_length: 2.0 }],
        }
    }

    #[test]
    fn paired_rows_count_each_program_once() {
        let a = vec![result(0, true), result(1, true), result(2, false)];
        let b = vec![result(2, true), result(1, false), result(0, true), result(7, true)];
        let md = paired(&[("own gesture".into(), &a), ("shifted".into(), &b)]);
        assert!(md.contains("**own gesture**"), "{md}");
        // program 7 ran in the second only; one success each way: z = 0
        assert!(md.contains("| shifted | 1 | 3 | 1 | 1 | 1 | 0 | 0.0 |"), "{md}");
        assert!(md.contains("| shifted | ∞ | 3 | 1 | 1 | 1 | 0 | 0.0 |"), "{md}");
        assert_eq!(paired(&[]), "");
    }

    #[test]
    fn another_programs_gesture_is_set_beside_its_own() {
        let programs: Vec<Program> = (0..4).map(|i| program(i, SceneType::Kitchen, 1)).collect();
        let mut passes = BTreeMap::new();
        passes.insert(EvalMode::Normal, (0..4).map(|i| result(i, i < 3)).collect());
        let e = Evaluation { label: "x".into(), split: "test", programs: &programs, passes, dts_threshold: 1.5 };
        assert!(!e.markdown().contains("Another program's gesture"), "only with the pass");
        let mut passes = e.passes;
        passes.insert(EvalMode::OtherGesture, (0..4).map(|i| result(i, i == 0)).collect());
        let e = Evaluation { passes, ..e };
        let md = e.markdown();
        assert!(md.contains("| its own | 75.0 |") && md.contains("| another program's | 25.0 |"), "{md}");
        // programs 1 and 2 succeed only with their own gesture: z = 2 / √2
        assert!(md.contains("| another program's | 1 | 4 | 1 | 2 | 0 | 1 | 1.4 |"), "{md}");
        assert!(e.csv().lines().any(|l| l.starts_with("x,test,other_gesture,all,all,1,4,25.000")));
    }

    #[test]
    fn tables_split_by_type_and_instances() {
        let programs = vec![
            program(0, SceneType::Kitchen, 1),
            program(1, SceneType::Bedroom, 3),
            program(2, SceneType::Bedroom, 2),
        ];
        let mut passes = BTreeMap::new();
        passes.insert(EvalMode::Normal, vec![result(0, true), result(1, false), result(2, true)]);
        passes.insert(EvalMode::Blind, vec![result(0, false), result(1, false), result(2, false)]);
        let e = Evaluation { label: "x".into(), split: "test", programs: &programs, passes, dts_threshold: 1.5 };
        let k = e.scores(EvalMode::Normal, Some(1), |r| e.scene_type(r) == SceneType::Kitchen).unwrap();
        assert_eq!((k.episodes, k.sr, k.spl), (1, 100.0, 100.0));
        let b = e.scores(EvalMode::Normal, Some(1), |r| bucket(e.instances(r)) == "3+").unwrap();
        assert_eq!((b.episodes, b.sr), (1, 0.0));
        let md = e.markdown();
        assert!(
            md.contains("| Kitchen | 1 | 100.0") && md.contains("## Blind mode") && md.contains("| 3+ | 1 | 0.0"),
            "{md}"
        );
        // 2 of 3 first stops succeed, at the target; every success is a first stop
        assert!(md.contains("| 66.7 | 20.8–93.9 | 100.0% | 66.7% | 9.0 | 1.00 |"), "{md}");
        let cal = e.calibration().unwrap();
        assert!(cal.contains("| 66.7 | 20.8–93.9 |") && cal.contains("SR is outside"), "{cal}");
        let csv = e.csv();
        assert!(csv.lines().any(|l| l.starts_with("x,test,blind,all,all,1,3,0.000")), "{csv}");
        // what the study reads back is what was written
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tables.csv");
        std::fs::write(&path, &csv).unwrap();
        let rows = read_rows(&path).unwrap();
        assert_eq!(rows.len(), csv.lines().count() - 1);
        let kitchen = find(&rows, "normal", "Kitchen", "all", "1").unwrap();
        assert_eq!((kitchen.episodes, kitchen.sr), (1, 100.0));
        assert!(find(&rows, "blind", "all", "3+", "inf").is_some());
        std::fs::write(&path, csv.replacen(",3,0.000", ",3,zero", 1)).unwrap();
        let e = read_rows(&path).unwrap_err().to_string();
        assert!(e.contains("tables.csv") && e.contains("sr `zero`"), "{e}");
    }

    #[test]
    fn a_label_with_a_comma_is_quoted_and_read_back() {
        assert_eq!(csv_field("+Both"), "+Both");
        assert_eq!(csv_field("+Both, greedy"), "\"+Both, greedy\"");
        let line = format!("{},val,normal,all,all,1,500,43.800,30.197,0.0386", csv_field("a \"b\", c"));
        let f = fields(&line);
        assert_eq!(f.len(), 10, "{f:?}");
        assert_eq!((f[0], f[2], f[7]), ("a \"\"b\"\", c", "normal", "43.800"));
        assert_eq!(fields("+Both,val,normal").len(), 3);
    }
}
