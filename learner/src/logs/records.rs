//! What the serve loop writes in the run directory, and the records it writes there:
//! `farm.jsonl` (a [`Progress`] line every report interval, and a final one), `episodes.jsonl`
//! (an [`EpisodeLine`] per finished episode), in evaluation `trajectories.jsonl` (every episode
//! step by step), and `farm_summary.json` (the [`Summary`], at exit, written atomically).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use farm::metrics::{EpisodeResult, Trajectory};
use farm::progress::{Counters, Progress};
use serde::{Deserialize, Serialize};
use shm_schema::EnvRecord;

/// A run-directory file that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}")]
pub struct RecordError {
    pub path: String,
    #[source]
    pub source: std::io::Error,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RecordError + '_ {
    move |source| RecordError { path: path.display().to_string(), source }
}

/// Per-worker state at the end (`farm_summary.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WorkerSummary {
    pub worker: u32,
    pub generation: Option<u32>,
    /// Messages accepted from the current generation.
    pub messages: u64,
    pub frames: u64,
    pub finished: bool,
}

/// What `crate::serve::server::serve` returns and writes to `farm_summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub run_id: String,
    pub policy: String,
    pub seconds: f64,
    pub stop_reason: String,
    pub totals: Counters,
    pub workers: Vec<WorkerSummary>,
}

/// One line of `episodes.jsonl`: the episode as `farm::metrics` scores it, plus where it
/// came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeLine {
    #[serde(flatten)]
    pub result: EpisodeResult,
    /// The env's episode counter in its worker process.
    pub episode: u64,
    pub terminated: bool,
    pub truncated: bool,
    pub target_category: u32,
    pub target_instances: u32,
}

impl EpisodeLine {
    pub fn new(worker: u32, generation: u32, env: usize, r: &EnvRecord) -> EpisodeLine {
        EpisodeLine {
            result: EpisodeResult::from_record(r, worker, env as u32, generation),
            episode: r.episode,
            terminated: r.terminated != 0,
            truncated: r.truncated != 0,
            target_category: r.target_category,
            target_instances: r.target_instances,
        }
    }
}

/// The serve loop's files in the run directory, open for appending (a resumed run appends).
#[derive(Debug)]
pub struct RunRecords {
    run_dir: PathBuf,
    episodes: BufWriter<File>,
    episodes_path: PathBuf,
    /// Evaluation: every episode step by step (`trajectories.jsonl`), per worker and env.
    trajectories: Option<(BufWriter<File>, PathBuf, Vec<Vec<Trajectory>>)>,
    progress: File,
    progress_path: PathBuf,
}

impl RunRecords {
    /// Creates `run_dir` if need be and opens its files; `eval` adds the trajectories of
    /// `workers` × `envs_per_worker` envs.
    pub fn open(run_dir: &Path, eval: bool, workers: usize, envs_per_worker: usize) -> Result<RunRecords, RecordError> {
        std::fs::create_dir_all(run_dir).map_err(io_err(run_dir))?;
        let episodes_path = run_dir.join("episodes.jsonl");
        let progress_path = run_dir.join("farm.jsonl");
        let open_append = |p: &Path| std::fs::OpenOptions::new().create(true).append(true).open(p);
        let episodes = BufWriter::new(open_append(&episodes_path).map_err(io_err(&episodes_path))?);
        let progress = open_append(&progress_path).map_err(io_err(&progress_path))?;
        let trajectories = if eval {
            let path = run_dir.join("trajectories.jsonl");
            let f = BufWriter::new(open_append(&path).map_err(io_err(&path))?);
            Some((f, path, vec![vec![Trajectory::default(); envs_per_worker]; workers]))
        } else {
            None
        };
        Ok(RunRecords { run_dir: run_dir.into(), episodes, episodes_path, trajectories, progress, progress_path })
    }

    /// Evaluation: adds env `env` of worker `worker`'s step to its trajectory, and writes the
    /// trajectory when the step ends an episode.
    pub fn trajectory_step(&mut self, worker: usize, env: usize, r: &EnvRecord) -> Result<(), RecordError> {
        if let Some((file, path, trajs)) = &mut self.trajectories
            && let Some(t) = trajs[worker][env].record(r, worker as u32, env as u32)
        {
            let line = serde_json::to_string(&t).expect("serialisable");
            writeln!(file, "{line}").map_err(io_err(path))?;
        }
        Ok(())
    }

    /// Appends the line of an episode that `r` ends.
    pub fn episode(&mut self, worker: u32, generation: u32, env: usize, r: &EnvRecord) -> Result<(), RecordError> {
        let line = serde_json::to_string(&EpisodeLine::new(worker, generation, env, r)).expect("serialisable");
        writeln!(self.episodes, "{line}").map_err(io_err(&self.episodes_path))
    }

    /// Appends a line to `farm.jsonl` (unbuffered: a reader sees progress as it is made).
    pub fn progress(&mut self, p: &Progress) -> Result<(), RecordError> {
        let line = serde_json::to_string(p).expect("serialisable");
        writeln!(self.progress, "{line}").map_err(io_err(&self.progress_path))
    }

    /// Pushes the buffered episode lines to the file.
    pub fn flush_episodes(&mut self) -> Result<(), RecordError> {
        self.episodes.flush().map_err(io_err(&self.episodes_path))
    }

    /// Pushes every buffered line to its file.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        if let Some((file, path, _)) = &mut self.trajectories {
            file.flush().map_err(io_err(path))?;
        }
        self.flush_episodes()
    }

    /// Writes `farm_summary.json`, atomically.
    pub fn summary(&self, summary: &Summary) -> Result<(), RecordError> {
        let path = self.run_dir.join("farm_summary.json");
        farm::files::write_atomic(&path, serde_json::to_string_pretty(summary).expect("serialisable").as_bytes())
            .map_err(io_err(&path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Env 1 of worker 0: an episode of program 7 that starts, takes a step and succeeds.
    fn episode() -> [EnvRecord; 3] {
        let start = EnvRecord { program: 7, episode: 2, episode_start: 1, last_action: 255, ..Default::default() };
        let mid = EnvRecord { program: 7, episode: 2, last_action: 0, robot: [0.0, 0.25, 0.0], ..Default::default() };
        let mut end = EnvRecord { program: 7, episode: 2, last_action: 3, terminated: 1, success: 1, ..mid };
        end.summary.success = 1;
        end.target_category = 5;
        [start, mid, end]
    }

    #[test]
    fn episodes_progress_and_summary_land_in_the_run_directory() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("run");
        let mut rec = RunRecords::open(&run, false, 1, 2).unwrap();
        for r in &episode() {
            rec.trajectory_step(0, 1, r).unwrap();
        }
        rec.episode(0, 3, 1, &episode()[2]).unwrap();
        rec.progress(&Progress {
            t: 1.0,
            fps: 2.0,
            latency_ms: None,
            success_rate: Some(1.0),
            workers_seen: 1,
            workers_live: 1,
            totals: Counters { frames: 3, episodes: 1, successes: 1, ..Default::default() },
            stop_reason: None,
            profile: Default::default(),
        })
        .unwrap();
        rec.flush().unwrap();
        let summary = Summary {
            run_id: "r".into(),
            policy: "expert".into(),
            seconds: 1.0,
            stop_reason: "frame budget reached".into(),
            totals: Counters::default(),
            workers: vec![WorkerSummary { worker: 0, generation: Some(3), messages: 3, frames: 3, finished: false }],
        };
        rec.summary(&summary).unwrap();

        let lines = std::fs::read_to_string(run.join("episodes.jsonl")).unwrap();
        let line: EpisodeLine = serde_json::from_str(lines.trim()).unwrap();
        assert_eq!(line, EpisodeLine::new(0, 3, 1, &episode()[2]));
        assert!(line.result.success && line.terminated && line.target_category == 5);
        let progress = std::fs::read_to_string(run.join("farm.jsonl")).unwrap();
        let p: Progress = serde_json::from_str(progress.trim()).unwrap();
        assert_eq!(p.totals.frames, 3);
        let back: Summary =
            serde_json::from_str(&std::fs::read_to_string(run.join("farm_summary.json")).unwrap()).unwrap();
        assert_eq!(back, summary);
        // trajectories are written in evaluation only
        assert!(!run.join("trajectories.jsonl").exists());
    }

    #[test]
    fn evaluation_writes_each_episode_step_by_step() {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = RunRecords::open(dir.path(), true, 1, 2).unwrap();
        for r in &episode() {
            rec.trajectory_step(0, 1, r).unwrap();
        }
        rec.flush().unwrap();
        let text = std::fs::read_to_string(dir.path().join("trajectories.jsonl")).unwrap();
        let t: Trajectory = serde_json::from_str(text.trim()).unwrap();
        assert_eq!((t.program, t.worker, t.env, t.success, t.steps.len()), (7, 0, 1, true, 3));
        assert_eq!(t.steps.iter().map(|s| s.action).collect::<Vec<_>>(), vec![0, 3, 255]);
    }
}
