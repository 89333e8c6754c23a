//! Models in flight at once (`--parallel N`): N lanes, each a thread that takes the plan's next
//! model and drives its steps as the study alone would. Two crews on one machine never meet: each
//! step runs in its model's own folders, a crew names its shared-memory services after a run id
//! made of its run folder, process and start time (`supervise::run_dir::make_run_id`), and the
//! sweep of dead runs that each `up` and `eval` does first ends only domains without a live
//! process. A finished model goes to `done` under one lock, so the tables have one writer at a
//! time.
//!
//! A failure starts no new model: the models in flight go on to their end (their results are
//! kept), then the study stops with the error. A termination signal reaches every step in flight
//! (`steps::orchestrator`), each stops as `up` or `eval` does, and the same command continues.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use super::steps;

/// Runs `model(lane, job)` for every job, in order, `lanes` at a time, and `done(index, result)`
/// as each ends, one at a time; the first error, once every lane has stopped.
pub fn run<J: Sync, R>(
    jobs: &[J],
    lanes: usize,
    model: impl Fn(usize, &J) -> anyhow::Result<R> + Sync,
    done: impl FnMut(usize, R) -> anyhow::Result<()> + Send,
) -> anyhow::Result<()> {
    let (next, busy, failed) = (AtomicUsize::new(0), AtomicUsize::new(0), AtomicBool::new(false));
    let (done, errors) = (Mutex::new(done), Mutex::new(Vec::new()));
    let lane = |id: usize| {
        while !failed.load(Ordering::SeqCst) && farm::process::termination_count() == 0 {
            let i = next.fetch_add(1, Ordering::SeqCst);
            let Some(job) = jobs.get(i) else { break };
            busy.fetch_add(1, Ordering::SeqCst);
            let ended = model(id, job).and_then(|r| done.lock().unwrap_or_else(|p| p.into_inner())(i, r));
            let others = busy.fetch_sub(1, Ordering::SeqCst) - 1;
            if let Err(e) = ended {
                if !failed.swap(true, Ordering::SeqCst) && others > 0 && steps::stopped().is_ok() {
                    eprintln!(
                        "[study] {e:#}\n[study] no other model starts; the {others} in flight go on to their end"
                    );
                }
                errors.lock().unwrap_or_else(|p| p.into_inner()).push(e);
                return;
            }
        }
    };
    std::thread::scope(|s| {
        for id in 0..lanes.clamp(1, jobs.len().max(1)) {
            let lane = &lane;
            s.spawn(move || lane(id));
        }
    });
    let mut errors = errors.into_inner().unwrap_or_else(|p| p.into_inner()).into_iter();
    // no error: every model done, or a signal came between two of them
    let Some(first) = errors.next() else { return steps::stopped() };
    for e in errors.filter(|e| e.to_string() != first.to_string()) {
        eprintln!("[study] also: {e:#}");
    }
    Err(first)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_job_is_done_once_and_a_failure_starts_no_new_one() {
        let jobs: Vec<usize> = (0..7).collect();
        let mut seen = Vec::new();
        run(
            &jobs,
            3,
            |_, &j| Ok(j * 10),
            |i, r| {
                seen.push((i, r));
                Ok(())
            },
        )
        .unwrap();
        seen.sort();
        assert_eq!(seen, jobs.iter().map(|&j| (j, j * 10)).collect::<Vec<_>>());

        // one lane: job 2 fails, jobs 3.. never start
        let started = AtomicUsize::new(0);
        let e = run(
            &jobs,
            1,
            |_, &j| {
                started.fetch_add(1, Ordering::SeqCst);
                if j == 2 { anyhow::bail!("job 2 failed") } else { Ok(()) }
            },
            |_, ()| Ok(()),
        )
        .unwrap_err();
        assert_eq!((e.to_string().as_str(), started.load(Ordering::SeqCst)), ("job 2 failed", 3));
    }
}
