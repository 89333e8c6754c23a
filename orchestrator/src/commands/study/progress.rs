//! The study's progress: a bar on a terminal (one line per step otherwise), with an ETA summed
//! per kind of step from each kind's rate in this invocation.

use std::io::IsTerminal;

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
/// unattended, into logs).
pub struct Progress {
    done: usize,
    steps: usize,
    left: [f64; 2],
    spent: [(f64, f64); 2],
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    pub fn new(plan: &[(Kind, f64)]) -> Progress {
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
        Progress { done: 0, steps: plan.len(), left, spent: [(0.0, 0.0); 2], bar }
    }

    fn eta(&self) -> f64 {
        (0..2)
            .map(|k| {
                let (s, w) = self.spent[k];
                self.left[k] * if w > 0.0 { s / w } else { PRIOR_SECONDS[k] }
            })
            .sum()
    }

    /// Shows what runs now.
    pub fn doing(&self, what: &str) {
        if let Some(b) = &self.bar {
            b.set_message(format!("{what}; about {} left", humantime(self.eta())));
        }
    }

    /// A step of `work` units is over: run here in `seconds`, or found done (None).
    pub fn step(&mut self, kind: Kind, work: f64, seconds: Option<f64>, what: &str) {
        self.done += 1;
        self.left[kind as usize] = (self.left[kind as usize] - work).max(0.0);
        let Some(s) = seconds else {
            if let Some(b) = &self.bar {
                b.inc(1);
            }
            return;
        };
        let spent = &mut self.spent[kind as usize];
        (spent.0, spent.1) = (spent.0 + s, spent.1 + work);
        let line = format!("{}/{} done: {what}; about {} left", self.done, self.steps, humantime(self.eta()));
        match &self.bar {
            Some(b) => {
                b.inc(1);
                b.println(format!("[study] {line}"));
            }
            None => eprintln!("[study] {line}"),
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

fn humantime(s: f64) -> String {
    let m = (s / 60.0).round() as u64;
    if m >= 60 { format!("{} h {:02} min", m / 60, m % 60) } else { format!("{m} min") }
}
