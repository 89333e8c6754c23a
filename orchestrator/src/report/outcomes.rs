//! Each test episode's outcome, small enough to commit beside a study record: what pairing two
//! methods program by program (and seed by seed) needs once the run folders are gone.
//!
//! ```text
//! pass,program,success_1,success,first_stop,steps,start_gesture,corrected
//! normal,60,1,1,1,1,1,0
//! ```
//! `success_1`: success at the first stop; `success`: with unlimited stops; `first_stop`: the
//! step of the first stop (empty: none); `start_gesture`: the gesture perceived at the first
//! step (0 none, 1 referencing, 2 intervention); `corrected`: an intervention gesture was shown
//! after the first step and before the first stop. The last two are empty where the pass kept
//! no trajectories.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

use anyhow::Context;
use farm::metrics::{EpisodeResult, Trajectory};

const HEADER: &str = "pass,program,success_1,success,first_stop,steps,start_gesture,corrected";

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Outcome {
    pub pass: String,
    pub program: u64,
    pub success_first: bool,
    pub success: bool,
    pub first_stop: Option<u32>,
    pub steps: u32,
    pub start_gesture: Option<u8>,
    pub corrected: Option<bool>,
}

impl Outcome {
    fn of(pass: &str, e: &EpisodeResult, t: Option<&Trajectory>) -> Outcome {
        let first_stop = e.stops.first().map(|s| s.step);
        let (start_gesture, corrected) = match t {
            Some(t) => {
                // steps[i] is the observation before action i: the first stop is the step whose
                // action was Stop, and the gestures shown before it are those of steps 1..=it
                let until = t.steps.iter().position(|s| s.action == shm_schema::action::STOP).unwrap_or(t.steps.len());
                let shown = t.steps.get(1..=until.min(t.steps.len().saturating_sub(1))).unwrap_or(&[]);
                (t.steps.first().map(|s| s.gesture), Some(shown.iter().any(|s| s.gesture == 2)))
            }
            None => (None, None),
        };
        Outcome {
            pass: pass.into(),
            program: e.program,
            success_first: e.at_stops(Some(1)).0,
            success: e.success,
            first_stop,
            steps: e.steps,
            start_gesture,
            corrected,
        }
    }
}

/// The outcomes of every pass of an evaluation folder (`<dir>/<pass>/episodes.jsonl`, with
/// `trajectories.jsonl` beside it where the pass kept them), passes in name order, programs in
/// order within each.
pub fn of_evaluation(dir: &Path) -> anyhow::Result<Vec<Outcome>> {
    let mut passes: Vec<_> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .flatten()
        .filter(|e| e.path().join("episodes.jsonl").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    passes.sort();
    let mut out = Vec::new();
    for pass in passes {
        let episodes = crate::commands::eval::read_episodes(&dir.join(&pass).join("episodes.jsonl"))?;
        let traj = dir.join(&pass).join("trajectories.jsonl");
        let trajectories: BTreeMap<(u32, u32, u64), Trajectory> = match traj.is_file() {
            true => farm::files::read_jsonl::<Trajectory>(&traj)?
                .into_iter()
                .map(|t| ((t.worker, t.env, t.program), t))
                .collect(),
            false => BTreeMap::new(),
        };
        let mut of_pass: Vec<Outcome> =
            episodes.iter().map(|e| Outcome::of(&pass, e, trajectories.get(&(e.worker, e.env, e.program)))).collect();
        // in program order: the episodes end in whatever order the workers finish them
        of_pass.sort_by_key(|o| o.program);
        out.extend(of_pass);
    }
    Ok(out)
}

pub fn to_csv(outcomes: &[Outcome]) -> String {
    let opt = |v: Option<u64>| v.map_or(String::new(), |v| v.to_string());
    let mut s = format!("{HEADER}\n");
    for o in outcomes {
        writeln!(
            s,
            "{},{},{},{},{},{},{},{}",
            o.pass,
            o.program,
            o.success_first as u8,
            o.success as u8,
            opt(o.first_stop.map(u64::from)),
            o.steps,
            opt(o.start_gesture.map(u64::from)),
            opt(o.corrected.map(u64::from)),
        )
        .unwrap();
    }
    s
}

pub fn read_csv(path: &Path) -> anyhow::Result<Vec<Outcome>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut lines = text.lines();
    anyhow::ensure!(lines.next() == Some(HEADER), "{}: the first line is not `{HEADER}`", path.display());
    let mut out = Vec::new();
    for (n, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let at =
            |col: usize| format!("{} line {}, column `{}`", path.display(), n + 2, HEADER.split(',').nth(col).unwrap());
        anyhow::ensure!(f.len() == 8, "{} line {}: {} fields, expected 8", path.display(), n + 2, f.len());
        let num = |col: usize| f[col].parse::<u64>().with_context(|| at(col));
        let flag = |col: usize| match f[col] {
            "0" => Ok(false),
            "1" => Ok(true),
            v => Err(anyhow::anyhow!("{}: `{v}` is not 0 or 1", at(col))),
        };
        let opt = |col: usize| if f[col].is_empty() { Ok(None) } else { num(col).map(Some) };
        out.push(Outcome {
            pass: f[0].to_string(),
            program: num(1)?,
            success_first: flag(2)?,
            success: flag(3)?,
            first_stop: opt(4)?.map(|v| v as u32),
            steps: num(5)? as u32,
            start_gesture: opt(6)?.map(|v| v as u8),
            corrected: if f[7].is_empty() { None } else { Some(flag(7)?) },
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use farm::metrics::TrajectoryStep;

    use super::*;

    fn step(action: u8, gesture: u8) -> TrajectoryStep {
        TrajectoryStep { x: 0.0, z: 0.0, yaw: 0.0, action, gesture, intervention: 0 }
    }

    #[test]
    fn outcomes_round_trip_and_read_the_gestures_before_the_first_stop() {
        let mut e = crate::report::tables::tests::result(7, false);
        e.steps = 4;
        // pointed at first; an intervention at step 2, after the first stop at step 1: not a correction
        let t = Trajectory {
            program: 7,
            worker: 0,
            env: 0,
            success: false,
            steps: vec![step(0, 1), step(3, 0), step(0, 2), step(255, 0)],
        };
        let o = Outcome::of("normal", &e, Some(&t));
        assert_eq!((o.start_gesture, o.corrected, o.success_first), (Some(1), Some(false), false));
        let t = Trajectory { steps: vec![step(1, 0), step(0, 2), step(3, 2), step(255, 0)], ..t };
        assert_eq!(Outcome::of("normal", &e, Some(&t)).corrected, Some(true), "shown before the stop");
        let bare = Outcome::of("blind", &e, None);
        assert_eq!((bare.start_gesture, bare.corrected), (None, None));

        let all = vec![o, bare];
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("test-episodes.csv");
        std::fs::write(&p, to_csv(&all)).unwrap();
        assert_eq!(read_csv(&p).unwrap(), all);
    }

    #[test]
    fn a_bad_field_is_one_error_naming_file_line_and_column() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("test-episodes.csv");
        std::fs::write(&p, format!("{HEADER}\nnormal,3,1,1,2,5,1,0\nnormal,4,yes,1,2,5,1,0\n")).unwrap();
        let e = format!("{:#}", read_csv(&p).unwrap_err());
        assert!(e.contains("test-episodes.csv line 3, column `success_1`") && e.contains("`yes`"), "{e}");
        std::fs::write(&p, "program,success\n").unwrap();
        assert!(read_csv(&p).unwrap_err().to_string().contains("first line"));
    }
}
