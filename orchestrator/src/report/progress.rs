//! Progress of long commands (`up`, `eval`, `dataset build`, `encoder pretrain`): a bar with
//! ETA when stderr is a terminal; otherwise (logs, CI) a plain line now and then, never the same
//! line twice.

use std::collections::VecDeque;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

/// One counted piece of work: `pos` of `total` `unit`s.
pub struct Bar {
    name: String,
    unit: &'static str,
    total: u64,
    shown: Option<ProgressBar>,
    started: Instant,
    /// Where this process began counting (a resumed run's frames trained before it): the ETA
    /// comes from the rate since then.
    from: u64,
    /// Plain lines: at most one per `every`; the last one printed, to never repeat it.
    every: Duration,
    last: Mutex<(Option<Instant>, String)>,
    /// The rate of the last few minutes, for plain lines' ETA: on a shared machine the rate
    /// changes when another job starts or ends, and the average since the start lags by hours.
    recent: Mutex<Rate>,
}

/// How far back a plain line's ETA looks.
const ETA_WINDOW: Duration = Duration::from_secs(300);

impl Bar {
    /// A bar on stderr; plain lines every `every` when stderr is not a terminal.
    pub fn new(name: &str, total: u64, unit: &'static str, every: Duration) -> Bar {
        Bar::build(name, total, unit, every, |b| b)
    }

    /// A bar among others drawn together (one per split of `dataset build`).
    pub fn in_group(group: &MultiProgress, name: &str, total: u64, unit: &'static str, every: Duration) -> Bar {
        Bar::build(name, total, unit, every, |b| group.add(b))
    }

    fn build(
        name: &str,
        total: u64,
        unit: &'static str,
        every: Duration,
        place: impl FnOnce(ProgressBar) -> ProgressBar,
    ) -> Bar {
        let shown = std::io::stderr().is_terminal().then(|| {
            let template =
                format!("{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {unit} ({{percent}}%) eta {{eta}}  {{msg}}");
            let b = place(ProgressBar::new(total))
                .with_style(ProgressStyle::with_template(&template).expect("a valid template").progress_chars("=> "))
                .with_prefix(name.to_string());
            b.enable_steady_tick(Duration::from_millis(500));
            b
        });
        Bar {
            name: name.into(),
            unit,
            total,
            shown,
            started: Instant::now(),
            from: 0,
            every,
            last: Mutex::new((None, String::new())),
            recent: Mutex::new(Rate::new(ETA_WINDOW)),
        }
    }

    /// The same bar, starting at `from` of its total (work done before this process).
    pub fn starting_at(mut self, from: u64) -> Bar {
        self.from = from.min(self.total);
        if let Some(b) = &self.shown {
            b.set_position(self.from);
            b.reset_eta();
        }
        self
    }

    /// Moves the bar to `pos` with `msg` beside it.
    pub fn set(&self, pos: u64, msg: &str) {
        if let Some(b) = &self.shown {
            b.set_position(pos);
            b.set_message(msg.to_string());
            return;
        }
        let mut last = self.last.lock().expect("no panic while printing");
        if last.0.is_some_and(|t| t.elapsed() < self.every) {
            return;
        }
        let line = self.plain_line(pos, msg);
        if line != last.1 {
            eprintln!("{line}");
            *last = (Some(Instant::now()), line);
        }
    }

    /// `[name] pos/total unit (p%), eta …  msg`, the ETA from the rate of the last
    /// [`ETA_WINDOW`] (from this process's average until a rate is seen).
    fn plain_line(&self, pos: u64, msg: &str) -> String {
        self.plain_line_at(Instant::now(), pos, msg)
    }

    fn plain_line_at(&self, now: Instant, pos: u64, msg: &str) -> String {
        let pos = pos.min(self.total);
        let pct = if self.total == 0 { 100.0 } else { 100.0 * pos as f64 / self.total as f64 };
        let recent = self.recent.lock().expect("no panic while printing").add(now, pos);
        let done = pos.saturating_sub(self.from);
        let rate = recent.filter(|&r| r > 0.0).or_else(|| {
            let elapsed = now.duration_since(self.started).as_secs_f64();
            (done > 0 && elapsed > 0.0).then(|| done as f64 / elapsed)
        });
        let eta = match rate {
            Some(r) if done > 0 => duration_words((self.total - pos) as f64 / r),
            _ => "-".to_string(),
        };
        let msg = if msg.is_empty() { String::new() } else { format!("  {msg}") };
        format!("[{}] {pos}/{} {} ({pct:.0}%), eta {eta}{msg}", self.name, self.total, self.unit)
    }

    /// A line that stays (above the bar on a terminal).
    pub fn println(&self, line: &str) {
        match &self.shown {
            Some(b) => b.println(line),
            None => eprintln!("{line}"),
        }
    }

    /// Removes the bar (a summary line follows from the command).
    pub fn finish(&self) {
        if let Some(b) = &self.shown {
            b.finish_and_clear();
        }
    }
}

/// A rate over the last `window` of a growing count: what a progress line shows, steady where
/// the count comes in bursts (a PPO update stops the frames, then they rush). The window
/// stretches to twice the longest pause seen, so that it always holds a whole round of collecting
/// and learning: an update longer than the window reads as the run's rate, not as 0.
pub struct Rate {
    window: Duration,
    seen: VecDeque<(Instant, u64)>,
    /// When the count last grew, and the longest time it stood still.
    grew: Option<Instant>,
    longest_pause: Duration,
}

impl Rate {
    pub fn new(window: Duration) -> Rate {
        Rate { window, seen: VecDeque::new(), grew: None, longest_pause: Duration::ZERO }
    }

    /// Records the count at `now`; returns the rate per second over the window (None until two
    /// points a second apart).
    pub fn add(&mut self, now: Instant, count: u64) -> Option<f64> {
        let grew = self.seen.back().is_none_or(|&(_, c)| count > c);
        let since = *self.grew.get_or_insert(now);
        if grew {
            self.grew = Some(now);
        }
        self.longest_pause = self.longest_pause.max(now.duration_since(since));
        self.seen.push_back((now, count));
        let window = self.window.max(2 * self.longest_pause);
        while self.seen.len() > 2 && now.duration_since(self.seen[1].0) >= window {
            self.seen.pop_front();
        }
        let (t0, c0) = *self.seen.front()?;
        let dt = now.duration_since(t0).as_secs_f64();
        (dt >= 1.0).then(|| count.saturating_sub(c0) as f64 / dt)
    }
}

/// `42 s`, `3 min 20 s`, `1 h 05 min`.
pub fn duration_words(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_lines_say_where_the_work_is_and_what_is_left() {
        let b = Bar { shown: None, ..Bar::new("up", 1000, "frames", Duration::ZERO) };
        let line = b.plain_line(0, "");
        assert_eq!(line, "[up] 0/1000 frames (0%), eta -");
        let line = b.plain_line(250, "success 3.0%");
        assert!(line.starts_with("[up] 250/1000 frames (25%), eta ") && line.ends_with("  success 3.0%"), "{line}");
        assert!(b.plain_line(2000, "").starts_with("[up] 1000/1000 frames (100%)"), "past the total reads as done");
        let resumed = Bar { shown: None, ..Bar::new("up", 1000, "frames", Duration::ZERO) }.starting_at(600);
        assert_eq!(resumed.plain_line(600, ""), "[up] 600/1000 frames (60%), eta -", "nothing done here yet");
    }

    /// A shared machine: slow while another job ran, then three times as fast once it ended. The
    /// ETA follows the new rate within the window instead of the whole run's average.
    #[test]
    fn the_eta_follows_the_rate_of_the_last_minutes() {
        let b = Bar { shown: None, ..Bar::new("up", 10_000_000, "frames", Duration::ZERO) };
        let t0 = b.started;
        let at = |s: u64| t0 + Duration::from_secs(s);
        // an hour at 400 frames/s, then 1200 frames/s
        let mut pos = 0;
        for s in (0..=3600).step_by(60) {
            pos = 400 * s;
            b.plain_line_at(at(s), pos, "");
        }
        let mut line = String::new();
        for s in (3660..=4200).step_by(60) {
            pos += 1200 * 60;
            line = b.plain_line_at(at(s), pos, "");
        }
        // 7.84M frames left at 1200/s: 1 h 48 min; the whole run's average (514/s) would say 4 h 14 min
        assert!(line.contains(&format!("eta {}", duration_words((10_000_000 - pos) as f64 / 1200.0))), "{line}");
    }

    /// Frames in bursts (500 a second, then nothing for a second while the learner updates):
    /// the rate over the window stays near the mean of 250 instead of swinging 0 ↔ 500.
    #[test]
    fn the_rate_is_steady_over_bursts() {
        let t0 = Instant::now();
        let mut r = Rate::new(Duration::from_secs(10));
        assert_eq!(r.add(t0, 0), None);
        let mut count = 0;
        let mut last = None;
        for s in 1..=40u64 {
            if s % 2 == 1 {
                count += 500;
            }
            last = r.add(t0 + Duration::from_secs(s), count);
            if s >= 12 {
                let v = last.unwrap();
                assert!((200.0..=300.0).contains(&v), "second {s}: {v}");
            }
        }
        assert!(last.is_some());
    }

    /// `up --workers 20`: a round collected in 40 s at 512 frames/s, then an update of 50 s
    /// without a frame: the rate never reads 0 while the round is learned, and settles on the
    /// run's rate (20,480 frames every 90 s).
    #[test]
    fn an_update_longer_than_the_window_does_not_read_as_zero() {
        let t0 = Instant::now();
        let mut r = Rate::new(Duration::from_secs(30));
        let mut count = 0;
        for tick in 1..=720u64 {
            let s = tick as f64 / 2.0;
            if s % 90.0 > 0.0 && s % 90.0 <= 40.0 {
                count += 256;
            }
            let v = r.add(t0 + Duration::from_millis(tick * 500), count);
            if tick >= 3 {
                assert!(v.unwrap() > 100.0, "second {s}: {v:?}");
            }
            if tick >= 400 {
                let v = v.unwrap();
                assert!((0.7..=1.4).contains(&(v / (20_480.0 / 90.0))), "second {s}: {v}");
            }
        }
    }

    #[test]
    fn the_first_update_reads_the_rollout_before_it() {
        // the learner's first report comes after a whole rollout; then it learns for a while
        let t0 = Instant::now();
        let mut r = Rate::new(Duration::from_secs(30));
        r.add(t0, 0);
        for tick in 8..=100u64 {
            let v = r.add(t0 + Duration::from_millis(tick * 500), 2336);
            assert!(v.unwrap() > 40.0, "second {}: {v:?}", tick / 2);
        }
    }

    #[test]
    fn durations_read_as_words() {
        assert_eq!(duration_words(42.4), "42 s");
        assert_eq!(duration_words(200.0), "3 min 20 s");
        assert_eq!(duration_words(3900.0), "1 h 05 min");
    }
}
