//! The study's progress: a bar on a terminal (one line per step otherwise), with an ETA summed
//! per kind of step from each kind's rate in this invocation, and what each lane (a model in
//! flight, `--parallel`) runs now.

use std::io::IsTerminal;
use std::sync::Mutex;

/// Kinds of step, which go at different rates.
#[derive(Clone, Copy)]
pub enum Kind {
    /// Work: frames.
    Train = 0,
    /// Work: programs × passes.
    Eval = 1,
}

/// Seconds per unit of work of a kind not yet run in this invocation (training at 1,000
/// frames/s, evaluation at 15 episodes/s: this machine's order of magnitude).
const PRIOR_SECONDS: [f64; 2] = [1.0 / 1000.0, 1.0 / 15.0];

/// Where the study is, with an ETA summed per kind of step from each kind's rate in this
/// invocation: a bar on a terminal, one line per step otherwise (studies run for hours, mostly
/// unattended, into logs). The lanes report through it at once.
pub struct StepBar {
    state: Mutex<State>,
    /// Models in flight at once.
    lanes: usize,
    bar: Option<indicatif::ProgressBar>,
}

struct State {
    done: usize,
    steps: usize,
    left: [f64; 2],
    spent: [(f64, f64); 2],
    /// What each lane runs now (empty: between steps).
    now: Vec<String>,
}

/// One lane's view of the progress.
pub struct Lane<'a> {
    progress: &'a StepBar,
    id: usize,
}

impl StepBar {
    /// For `plan`'s steps, run `lanes` at a time.
    pub fn new(plan: &[(Kind, f64)], lanes: usize) -> StepBar {
        let mut left = [0.0; 2];
        for (k, w) in plan {
            left[*k as usize] += w;
        }
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::new(plan.len() as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template("study [{bar:30}] {pos}/{len} steps  {msg}")
                    .expect("a valid template")
                    .progress_chars("=> "),
            );
            b.enable_steady_tick(std::time::Duration::from_secs(1));
            b
        });
        let lanes = lanes.max(1);
        let state = State { done: 0, steps: plan.len(), left, spent: [(0.0, 0.0); 2], now: vec![String::new(); lanes] };
        StepBar { state: Mutex::new(state), lanes, bar }
    }

    pub fn lane(&self, id: usize) -> Lane<'_> {
        Lane { progress: self, id }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Seconds left: a lane's steps were timed beside the other lanes', so the study goes
    /// `lanes` times as fast as one lane's rate (the prior is the machine's rate: lanes share it).
    fn eta(&self, s: &State) -> f64 {
        (0..2)
            .map(|k| {
                let (secs, w) = s.spent[k];
                s.left[k] * if w > 0.0 { secs / w / self.lanes as f64 } else { PRIOR_SECONDS[k] }
            })
            .sum()
    }

    fn show(&self, s: &State) {
        if let Some(b) = &self.bar {
            let now: Vec<&str> = s.now.iter().filter(|w| !w.is_empty()).map(String::as_str).collect();
            let sep = if now.is_empty() { "" } else { "; " };
            b.set_message(format!("{}{sep}about {} left", now.join("; "), humantime(self.eta(s))));
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

impl Lane<'_> {
    /// Shows what this lane runs now (beside what the others run).
    pub fn doing(&self, what: &str) {
        let p = self.progress;
        let mut s = p.state();
        s.now[self.id] = what.to_string();
        p.show(&s);
    }

    /// A step of `work` units is over: run here in `seconds`, or found done (None).
    pub fn step(&self, kind: Kind, work: f64, seconds: Option<f64>, what: &str) {
        let p = self.progress;
        let mut s = p.state();
        s.done += 1;
        s.left[kind as usize] = (s.left[kind as usize] - work).max(0.0);
        s.now[self.id].clear();
        let Some(secs) = seconds else {
            if let Some(b) = &p.bar {
                b.inc(1);
            }
            return;
        };
        let spent = &mut s.spent[kind as usize];
        (spent.0, spent.1) = (spent.0 + secs, spent.1 + work);
        let line = format!("{}/{} done: {what}; about {} left", s.done, s.steps, humantime(p.eta(&s)));
        match &p.bar {
            Some(b) => {
                b.inc(1);
                b.println(format!("[study] {line}"));
                p.show(&s);
            }
            None => eprintln!("[study] {line}"),
        }
    }
}

fn humantime(s: f64) -> String {
    let m = (s / 60.0).round() as u64;
    if m >= 60 { format!("{} h {:02} min", m / 60, m % 60) } else { format!("{m} min") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_finish_the_work_that_many_times_as_fast() {
        let plan = [(Kind::Train, 1000.0), (Kind::Train, 1000.0), (Kind::Eval, 100.0)];
        let (one, two) = (StepBar::new(&plan, 1), StepBar::new(&plan, 2));
        for p in [&one, &two] {
            // 1,000 frames in 10 s a lane
            p.lane(0).step(Kind::Train, 1000.0, Some(10.0), "trained");
        }
        let eta = |p: &StepBar| p.eta(&p.state());
        // the frames left at the measured rate, Random's programs at the prior rate
        assert_eq!(eta(&one), 10.0 + 100.0 / 15.0);
        assert_eq!(eta(&two), 5.0 + 100.0 / 15.0);
    }
}
