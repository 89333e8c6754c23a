//! Training metrics: one JSON line per PPO update (`metrics.jsonl`), the same scalars and the
//! farm's counters in TensorBoard (`tb/`), and a PNG of the curves (`curves.png`), all in the
//! run directory.

use std::io::Write;
use std::path::{Path, PathBuf};

use farm::tensorboard::EventWriter;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

/// What one PPO update reports.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateMetrics {
    /// Updates done, this one included.
    pub update: u64,
    /// Environment frames in the rollouts learned from so far (drives the lr schedule).
    pub frames: u64,
    /// Frames per second since the previous update (acting and learning).
    pub fps: f64,
    /// Learning rate of this update.
    pub lr: f64,
    pub policy_loss: f64,
    pub value_loss: f64,
    pub entropy: f64,
    pub approx_kl: f64,
    pub clip_fraction: f64,
    pub explained_variance: f64,
    /// Mean global gradient norm before clipping.
    pub grad_norm: f64,
    /// Episodes that ended during this rollout, and their means.
    pub episodes: u64,
    pub episode_return: Option<f64>,
    pub episode_length: Option<f64>,
    pub success_rate: Option<f64>,
    pub spl: Option<f64>,
    /// Fraction of the rollout's steps learned from (the rest: final observations, lost messages).
    pub valid_fraction: f64,
    /// Truncations bootstrapped from the final observation, and those that could not be.
    pub bootstrapped: u64,
    pub truncated_without_final: u64,
    pub lost_messages: u64,
    /// Optimizer steps skipped because the gradient was not finite.
    #[serde(default)]
    pub skipped_steps: u64,
    /// Seconds spent in the PPO epochs.
    pub update_seconds: f64,
    /// A stop (Ctrl-C) arrived during the update and ended its epochs early.
    #[serde(default)]
    pub cut_short: bool,
    /// Updates between the weights that collected the rollout and those it was learned from
    /// (`ppo.overlap_update`: 1 after the first; 0 otherwise).
    #[serde(default)]
    pub policy_lag: u64,
}

/// The episodes finished between two updates (a window of the run), summed until the update
/// drains their means into its [`UpdateMetrics`].
#[derive(Clone, Debug, Default)]
pub struct EpisodeWindow {
    pub count: u64,
    sum_return: f64,
    sum_length: f64,
    successes: u64,
    sum_spl: f64,
}

impl EpisodeWindow {
    pub fn add(&mut self, ret: f64, length: u32, success: bool, spl: f32) {
        self.count += 1;
        self.sum_return += ret;
        self.sum_length += length as f64;
        self.successes += success as u64;
        self.sum_spl += if success { spl as f64 } else { 0.0 };
    }

    fn mean(&self, sum: f64) -> Option<f64> {
        (self.count > 0).then(|| sum / self.count as f64)
    }

    pub fn success_rate(&self) -> Option<f64> {
        self.mean(self.successes as f64)
    }

    /// Writes the means into `m` and starts over.
    pub fn drain_into(&mut self, m: &mut UpdateMetrics) {
        m.episodes = self.count;
        m.episode_return = self.mean(self.sum_return);
        m.episode_length = self.mean(self.sum_length);
        m.success_rate = self.success_rate();
        m.spl = self.mean(self.sum_spl);
        *self = EpisodeWindow::default();
    }
}

/// `metrics.jsonl` of a run directory, appended one line per update, and this process's
/// TensorBoard event file in `tb/`.
#[derive(Debug)]
pub struct MetricsLog {
    pub jsonl: PathBuf,
    pub png: PathBuf,
    pub rows: Vec<UpdateMetrics>,
    tb: EventWriter,
    /// Frames of this process's last update, and of its last farm counters in TensorBoard.
    updated_at: Option<u64>,
    farm_at: Option<u64>,
}

#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    #[error("{file}: {message}")]
    File { file: String, message: String },
    #[error("plotting {file}: {message}")]
    Plot { file: String, message: String },
}

impl MetricsLog {
    /// Opens `dir/metrics.jsonl`, reading the rows already there (a resumed run appends).
    pub fn open(dir: &Path) -> Result<MetricsLog, MetricsError> {
        let jsonl = dir.join("metrics.jsonl");
        let png = dir.join("curves.png");
        let mut rows = Vec::new();
        if let Ok(text) = std::fs::read_to_string(&jsonl) {
            for (i, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
                let row = serde_json::from_str(line).map_err(|e| MetricsError::File {
                    file: jsonl.display().to_string(),
                    message: format!("line {}: {e}", i + 1),
                })?;
                rows.push(row);
            }
        }
        let tb_dir = dir.join("tb");
        let tb = EventWriter::create(&tb_dir, "train")
            .map_err(|e| MetricsError::File { file: tb_dir.display().to_string(), message: e.to_string() })?;
        Ok(MetricsLog { jsonl, png, rows, tb, updated_at: None, farm_at: None })
    }

    fn tb_err(&self) -> impl FnOnce(std::io::Error) -> MetricsError + '_ {
        |e| MetricsError::File { file: self.tb.path().display().to_string(), message: e.to_string() }
    }

    /// Marks that training goes on from a checkpoint taken at `frames`: what an earlier process
    /// recorded after it is hidden in TensorBoard and moved from `metrics.jsonl` to
    /// `metrics.redone.jsonl` (those updates are done again: the curves go on without a jump
    /// back), and the effective configuration is shown as text.
    pub fn started_at(&mut self, frames: u64, config_toml: &str) -> Result<(), MetricsError> {
        if frames > 0 {
            self.tb.restart_at(frames as i64 + 1).map_err(self.tb_err())?;
        }
        if self.rows.iter().any(|r| r.frames > frames) {
            self.set_aside_after(frames)?;
        }
        let text = format!("```toml\n{config_toml}\n```");
        self.tb.text("config", frames as i64, &text).map_err(self.tb_err())
    }

    /// The farm's counters since this learner process started, at an update's frame count.
    pub fn farm(&mut self, frames: u64, p: &farm::progress::Progress) -> Result<(), MetricsError> {
        if self.farm_at.is_some_and(|f| f >= frames) {
            return Ok(());
        }
        self.farm_at = Some(frames);
        let t = &p.totals;
        let mut v = vec![
            ("farm/fps", p.fps),
            ("farm/workers_live", p.workers_live as f64),
            ("farm/restarts", t.restarts as f64),
            ("farm/lost", t.lost as f64),
            ("farm/duplicates", t.duplicates as f64),
            ("farm/corrupt", t.corrupt as f64),
            ("farm/stale", t.stale as f64),
        ];
        if let Some(l) = p.latency_ms {
            v.push(("farm/step_latency_ms", l));
        }
        self.tb.scalars(frames as i64, &v).map_err(self.tb_err())
    }

    /// The farm's counters at the end, at this process's last update (the last report comes
    /// after it: waiting for a next update would lose them).
    pub fn farm_final(&mut self, p: &farm::progress::Progress) -> Result<(), MetricsError> {
        match self.updated_at {
            Some(frames) => self.farm(frames, p),
            None => Ok(()),
        }
    }

    /// Moves the rows past `frames` to `metrics.redone.jsonl` (appended: nothing is lost) and
    /// rewrites `metrics.jsonl` without them, atomically.
    fn set_aside_after(&mut self, frames: u64) -> Result<(), MetricsError> {
        let err = |p: &Path| {
            let file = p.display().to_string();
            move |e: std::io::Error| MetricsError::File { file, message: e.to_string() }
        };
        let lines = |rows: &[UpdateMetrics]| -> String {
            rows.iter().map(|r| serde_json::to_string(r).expect("metrics serialise") + "\n").collect()
        };
        let (kept, redone): (Vec<UpdateMetrics>, Vec<UpdateMetrics>) =
            std::mem::take(&mut self.rows).into_iter().partition(|r| r.frames <= frames);
        let aside = self.jsonl.with_file_name("metrics.redone.jsonl");
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&aside).map_err(err(&aside))?;
        f.write_all(lines(&redone).as_bytes()).map_err(err(&aside))?;
        farm::files::write_atomic(&self.jsonl, lines(&kept).as_bytes()).map_err(err(&self.jsonl))?;
        self.rows = kept;
        Ok(())
    }

    pub fn append(&mut self, m: &UpdateMetrics) -> Result<(), MetricsError> {
        self.updated_at = Some(m.frames);
        let err =
            |e: std::io::Error| MetricsError::File { file: self.jsonl.display().to_string(), message: e.to_string() };
        if let Some(dir) = self.jsonl.parent() {
            std::fs::create_dir_all(dir).map_err(err)?;
        }
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&self.jsonl).map_err(err)?;
        let line = serde_json::to_string(m).expect("metrics serialise");
        writeln!(f, "{line}").map_err(err)?;
        self.tb.scalars(m.frames as i64, &tensorboard_scalars(m)).map_err(self.tb_err())?;
        self.rows.push(m.clone());
        Ok(())
    }

    /// Redraws `curves.png`.
    pub fn plot(&self) -> Result<(), MetricsError> {
        plot_curves(&self.rows, &self.png)
    }

    /// Redraws `curves.png` and puts it in TensorBoard (at the end of a run: TensorBoard draws
    /// the scalars itself while it runs).
    pub fn plot_final(&mut self) -> Result<(), MetricsError> {
        self.plot()?;
        let png = std::fs::read(&self.png)
            .map_err(|e| MetricsError::File { file: self.png.display().to_string(), message: e.to_string() })?;
        let frames = self.rows.last().map_or(0, |r| r.frames) as i64;
        let (w, h) = CURVES_SIZE;
        self.tb.image_png("charts/curves", frames, &png, w, h).map_err(self.tb_err())
    }
}

/// One update's scalars under CleanRL's tag groups (charts/, losses/) and ours (rollout/, perf/).
fn tensorboard_scalars(m: &UpdateMetrics) -> Vec<(&'static str, f64)> {
    let mut v = vec![
        ("charts/learning_rate", m.lr),
        ("charts/episodes", m.episodes as f64),
        ("losses/policy_loss", m.policy_loss),
        ("losses/value_loss", m.value_loss),
        ("losses/entropy", m.entropy),
        ("losses/approx_kl", m.approx_kl),
        ("losses/clip_fraction", m.clip_fraction),
        ("losses/explained_variance", m.explained_variance),
        ("losses/grad_norm", m.grad_norm),
        ("losses/skipped_steps", m.skipped_steps as f64),
        ("rollout/valid_fraction", m.valid_fraction),
        ("rollout/bootstrapped", m.bootstrapped as f64),
        ("rollout/truncated_without_final", m.truncated_without_final as f64),
        ("rollout/lost_messages", m.lost_messages as f64),
        ("rollout/policy_lag", m.policy_lag as f64),
        ("perf/fps", m.fps),
        ("perf/update_seconds", m.update_seconds),
    ];
    // Means over the episodes that ended in the rollout; none ended, no point.
    for (tag, value) in [
        ("charts/success_rate", m.success_rate),
        ("charts/spl", m.spl),
        ("charts/episode_return", m.episode_return),
        ("charts/episode_length", m.episode_length),
    ] {
        if let Some(x) = value {
            v.push((tag, x));
        }
    }
    v
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, farm::font::FONT_TTF);
    });
}

type Series = (&'static str, fn(&UpdateMetrics) -> Option<f64>);

const PANELS: [Series; 8] = [
    ("success rate", |m| m.success_rate),
    ("SPL", |m| m.spl),
    ("episode return", |m| m.episode_return),
    ("frames / s", |m| Some(m.fps)),
    ("policy loss", |m| Some(m.policy_loss)),
    ("value loss", |m| Some(m.value_loss)),
    ("entropy", |m| Some(m.entropy)),
    ("approx KL", |m| Some(m.approx_kl)),
];

const CURVES_SIZE: (u32, u32) = (1600, 800);

/// Eight panels against frames, written atomically as PNG.
pub fn plot_curves(rows: &[UpdateMetrics], path: &Path) -> Result<(), MetricsError> {
    register_font();
    let (w, h) = CURVES_SIZE;
    let mut buf = vec![0u8; (w * h * 3) as usize];
    let perr = |e: String| MetricsError::Plot { file: path.display().to_string(), message: e };
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
        let x_max = rows.iter().map(|r| r.frames).max().unwrap_or(1).max(1) as f64;
        for (area, (title, get)) in root.split_evenly((2, 4)).iter().zip(PANELS) {
            let pts: Vec<(f64, f64)> =
                rows.iter().filter_map(|r| get(r).filter(|v| v.is_finite()).map(|v| (r.frames as f64, v))).collect();
            let (lo, hi) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
            let (lo, hi) = if pts.is_empty() {
                (0.0, 1.0)
            } else if hi - lo < 1e-9 {
                (lo - 0.5, hi + 0.5)
            } else {
                (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
            };
            let mut chart = ChartBuilder::on(area)
                .caption(title, ("sans-serif", 20))
                .margin(8)
                .x_label_area_size(28)
                .y_label_area_size(56)
                .build_cartesian_2d(0.0..x_max, lo..hi)
                .map_err(|e| perr(e.to_string()))?;
            chart
                .configure_mesh()
                .x_labels(4)
                .y_labels(5)
                .x_label_formatter(&|x| format_frames(*x))
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(|e| perr(e.to_string()))?;
            chart.draw_series(LineSeries::new(pts, &BLUE)).map_err(|e| perr(e.to_string()))?;
        }
        root.present().map_err(|e| perr(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| perr("bad buffer".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).map_err(|e| perr(e.to_string()))?;
    farm::files::write_atomic(path, &png).map_err(|e| perr(e.to_string()))
}

fn format_frames(x: f64) -> String {
    if x >= 1e6 {
        format!("{:.1}M", x / 1e6)
    } else if x >= 1e3 {
        format!("{:.0}k", x / 1e3)
    } else {
        format!("{x:.0}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jsonl_round_trips_and_curves_are_drawn() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        for u in 1..=5u64 {
            let mut m = UpdateMetrics { update: u, frames: u * 1280, fps: 100.0, lr: 3e-4, ..Default::default() };
            let mut ep = EpisodeWindow::default();
            if u > 1 {
                ep.add(1.0, 20, true, 0.5);
                ep.add(-0.1, 100, false, 0.0);
            }
            ep.drain_into(&mut m);
            log.append(&m).unwrap();
        }
        let again = MetricsLog::open(dir.path()).unwrap();
        assert_eq!(again.rows, log.rows);
        assert_eq!(again.rows[0].success_rate, None);
        assert_eq!(again.rows[1].success_rate, Some(0.5));
        assert_eq!(again.rows[1].spl, Some(0.25));
        again.plot().unwrap();
        let png = image::open(&again.png).unwrap();
        assert_eq!((png.width(), png.height()), (1600, 800));
    }

    /// A run killed after update 5 resumes from its checkpoint at update 3: the rows of updates
    /// 4 and 5 (to be done again) move aside, and the curve goes on from update 3.
    #[test]
    fn a_resume_sets_aside_the_updates_done_again() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        for u in 1..=5u64 {
            log.append(&UpdateMetrics { update: u, frames: u * 1280, ..Default::default() }).unwrap();
        }
        let mut resumed = MetricsLog::open(dir.path()).unwrap();
        resumed.started_at(3 * 1280, "").unwrap();
        resumed.append(&UpdateMetrics { update: 4, frames: 4 * 1280, ..Default::default() }).unwrap();
        let frames = |name: &str| -> Vec<u64> {
            let text = std::fs::read_to_string(dir.path().join(name)).unwrap();
            text.lines().map(|l| serde_json::from_str::<UpdateMetrics>(l).unwrap().frames / 1280).collect()
        };
        assert_eq!(frames("metrics.jsonl"), vec![1, 2, 3, 4]);
        assert_eq!(frames("metrics.redone.jsonl"), vec![4, 5]);
        assert_eq!(MetricsLog::open(dir.path()).unwrap().rows.len(), 4);
    }
}
