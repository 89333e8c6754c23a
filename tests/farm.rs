//! The rollout farm end to end: real `orchestrator up` runs with real workers (simulator
//! environments, 64×64 frames) and the learner serving the random or expert policy.
//!
//! They need the binaries (`cargo build --release --workspace`) and build a small dataset once
//! (`orchestrator dataset build`, cached under target/release/gesthor-test-data).

use std::path::Path;
use std::time::{Duration, Instant};

use gesthor_tests::*;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

/// How long a test waits for an event the orchestrator brings about at once (a restart, a stop,
/// children following a killed parent). Generous on purpose: on a busy 2-core machine a
/// process may start slowly; the tests assert that the event happens, not how fast.
const EVENT_DEADLINE: Duration = Duration::from_secs(60);

fn u(v: &Value, k: &str) -> u64 {
    v[k].as_u64().unwrap_or_else(|| panic!("no `{k}` in {v}"))
}

fn assert_clean_totals(s: &Value) {
    let t = &s["totals"];
    assert_eq!((u(t, "lost"), u(t, "duplicates"), u(t, "corrupt")), (0, 0, 0), "integrity: {t}");
}

fn assert_gone(run: &Run) {
    let left = run.processes();
    assert!(left.is_empty(), "processes of the run still alive: {left:?}");
    let files = shm_leftovers(&run.run_id());
    assert!(files.is_empty(), "shared-memory leftovers of run {}: {files:?}", run.run_id());
}

/// Four workers step 2000 frames: every message and every env step reaches the learner exactly
/// once (the learner's check mode fails the run otherwise), episodes are recorded, and nothing
/// of the run is left behind.
#[test]
fn four_workers_step_without_loss_or_duplicates() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 2);
    let mut run = Run::start(
        &tmp.path().join("run"),
        &["--workers", "4", "--config", cfg.to_str().unwrap(), "--policy", "random", "--frames", "2000", "--check"],
    );
    let status = run.wait(Duration::from_secs(240));
    assert!(status.success(), "{status}\n{}", run.diagnostics());
    let s = run.summary();
    assert_clean_totals(&s);
    assert!(u(&s["totals"], "frames") >= 2000, "{s}");
    let workers = s["workers"].as_array().unwrap();
    assert_eq!(workers.len(), 4);
    for w in workers {
        assert_eq!(w["generation"].as_u64(), Some(0), "{w}");
        assert!(u(w, "messages") > 10, "{w}");
    }
    let episodes = run.episodes();
    assert_eq!(episodes.len() as u64, u(&s["totals"], "episodes"));
    assert!(!episodes.is_empty(), "2000 random frames of 100-step episodes end some episodes");
    assert!(episodes.iter().all(|e| e["steps"].as_u64().unwrap() <= 100));
    assert_gone(&run);
}

/// `kill -9` of a worker mid-run: the run goes on, the slot comes back as generation 1, no
/// malformed or out-of-order observation reaches the learner (check mode), and after the run
/// no process and no shared-memory file of it remains.
#[test]
fn a_killed_worker_is_restarted_and_nothing_half_written_arrives() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 2);
    let mut run = Run::start(
        &tmp.path().join("run"),
        &[
            "--workers",
            "3",
            "--config",
            cfg.to_str().unwrap(),
            "--policy",
            "random",
            "--seconds",
            "120",
            "--check",
            "--report-every",
            "0.5",
        ],
    );
    let p = run.wait_progress(Duration::from_secs(120), "frames from all 3 workers", |p| {
        p["workers_seen"] == 3 && p["frames"].as_u64() > Some(200)
    });
    let victim = run.worker_pid(1).expect("worker 1 is running");
    kill(Pid::from_raw(victim), Signal::SIGKILL).unwrap();
    let killed_at = Instant::now();
    let frames_then = u(&p, "frames");
    let new_pid = loop {
        if let Some(pid) = run.worker_pid(1).filter(|&p| p != victim) {
            break pid;
        }
        assert!(killed_at.elapsed() < EVENT_DEADLINE, "worker 1 not restarted\n{}", run.diagnostics());
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_ne!(new_pid, victim);
    run.wait_progress(Duration::from_secs(120), "the restarted worker back in the batches", |p| {
        p["restarts"].as_u64() >= Some(1) && p["workers_live"] == 3 && p["frames"].as_u64() > Some(frames_then + 300)
    });
    run.signal(Signal::SIGINT);
    let status = run.wait(EVENT_DEADLINE);
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    let s = run.summary();
    assert_clean_totals(&s);
    assert!(u(&s["totals"], "restarts") >= 1, "{s}");
    assert_eq!(s["workers"][1]["generation"].as_u64(), Some(1), "{s}");
    assert_eq!(s["workers"][0]["generation"].as_u64(), Some(0), "{s}");
    assert!(run.output().contains("restarting it as generation 1"), "{}", run.output());
    assert_gone(&run);
}

/// Ctrl-C (SIGINT) to the orchestrator stops the learner and every worker; the learner stops
/// cleanly (it is not killed by the orchestrator's escalation) and says why.
#[test]
fn sigint_stops_every_process_cleanly() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 2);
    let mut run = Run::start(
        &tmp.path().join("run"),
        &[
            "--workers",
            "4",
            "--config",
            cfg.to_str().unwrap(),
            "--policy",
            "expert",
            "--seconds",
            "300",
            "--report-every",
            "0.5",
        ],
    );
    run.wait_progress(Duration::from_secs(120), "frames from all 4 workers", |p| {
        p["workers_seen"] == 4 && p["frames"].as_u64() > Some(0)
    });
    assert_eq!(run.processes().len(), 5, "learner + 4 workers: {:?}", run.processes());
    run.signal(Signal::SIGINT);
    let status = run.wait(EVENT_DEADLINE);
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    assert_gone(&run);
    // the learner stopped cleanly (it was not killed) and said why
    let s = run.summary();
    assert_eq!(s["stop_reason"], "stopped by SIGINT", "{s}");
}

/// Ctrl-C while PPO trains: the learner ends (or cuts short) its update, writes a final
/// checkpoint the orchestrator waits for, and `up --resume` continues from it.
#[test]
fn ctrl_c_while_training_keeps_a_checkpoint_that_resumes() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    // no periodic checkpoint: the final one is all there is
    let cfg = small_ppo_config(tmp.path(), "epochs = 8\n\n[checkpoint]\nevery_updates = 100000\n");
    let dir = tmp.path().join("run");
    let args = ["--workers", "1", "--config", cfg.to_str().unwrap(), "--seconds", "900", "--report-every", "0.5"];
    let mut run = Run::start(&dir, &args);
    run.wait_progress(Duration::from_secs(240), "two PPO updates", |p| p["frames"].as_u64() > Some(64));
    run.signal(Signal::SIGINT);
    let status = run.wait(EVENT_DEADLINE);
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    assert_gone(&run);
    let ckpts = farm::checkpoints::dir_of(&dir);
    let (found, skipped) = farm::checkpoints::latest_verified(&ckpts);
    let found = found.unwrap_or_else(|| panic!("no checkpoint after Ctrl-C ({skipped:?}): {}", run.diagnostics()));
    assert!(skipped.is_empty() && !farm::checkpoints::final_write_in_progress(&ckpts));
    let learner_log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap();
    assert!(learner_log.contains("writing the final checkpoint"), "{learner_log}");
    let stopped_at = farm::checkpoints::update_of(&found).unwrap();
    assert!(stopped_at >= 2, "{}", found.display());

    let out = std::process::Command::new(bin("orchestrator"))
        .args(["up", "--resume"])
        .arg(&dir)
        .args(["--workers", "1", "--frames", "96"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let learner_log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap();
    assert!(learner_log.contains(&format!("resumed from {}", found.display())), "{learner_log}");
    let newest = farm::checkpoints::latest(&ckpts).unwrap();
    assert!(farm::checkpoints::update_of(&newest).unwrap() > stopped_at, "{}", newest.display());
}

/// `up` killed with SIGKILL mid-run, then `up --resume` without --frames: training goes on to
/// the run's own budget (the frames its checkpoint holds count), the progress line counts the
/// run's frames, and the curves go on from the checkpoint without a jump back.
#[test]
fn a_killed_run_resumes_to_its_own_budget() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    // 1 worker × 2 envs × rollout 16 = 32 frames an update; a budget of 24 updates
    let (per_update, budget) = (32u64, 768u64);
    let cfg = small_ppo_config(tmp.path(), "\n[checkpoint]\nevery_updates = 2\nkeep = 3\n");
    let dir = tmp.path().join("run");
    let budget_set = format!("run.total_frames={budget}");
    let args = ["--workers", "1", "--config", cfg.to_str().unwrap(), "--set", &budget_set, "--report-every", "0.5"];
    let mut run = Run::start(&dir, &args);
    let ckpts = farm::checkpoints::dir_of(&dir);
    let t0 = Instant::now();
    while farm::checkpoints::list(&ckpts).iter().all(|(u, _)| *u < 6) {
        assert!(t0.elapsed() < Duration::from_secs(240), "no checkpoint at update 6\n{}", run.diagnostics());
        assert!(run.try_wait().is_none(), "the run ended before its kill\n{}", run.diagnostics());
        std::thread::sleep(Duration::from_millis(20));
    }
    run.signal(Signal::SIGKILL);
    run.wait(EVENT_DEADLINE);
    while !run.processes().is_empty() {
        assert!(t0.elapsed() < Duration::from_secs(300), "children outlived the orchestrator: {:?}", run.processes());
        std::thread::sleep(Duration::from_millis(20));
    }
    let (kept, _) = farm::checkpoints::latest_verified(&ckpts);
    let kept_frames = farm::checkpoints::frames(&kept.expect("a checkpoint")).unwrap();
    assert!(kept_frames < budget, "killed before the end: {kept_frames}");

    let out = std::process::Command::new(bin("orchestrator"))
        .args(["up", "--resume"])
        .arg(&dir)
        .args(["--workers", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let last = farm::checkpoints::latest(&ckpts).unwrap();
    let frames = farm::checkpoints::frames(&last).unwrap();
    assert!(
        frames + per_update >= budget && frames <= budget + per_update,
        "the resumed run ended at {frames} frames; its budget is {budget} (one update either side)\n{stderr}"
    );
    let rows: Vec<u64> = std::fs::read_to_string(dir.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap()["frames"].as_u64().unwrap())
        .collect();
    assert!(rows.windows(2).all(|w| w[1] == w[0] + per_update), "one row an update, no jump back: {rows:?}");
    assert_eq!(rows.last(), Some(&frames), "{rows:?}");

    // resuming again does not train the budget over again
    let again = std::process::Command::new(bin("orchestrator"))
        .args(["up", "--resume"])
        .arg(&dir)
        .args(["--workers", "1"])
        .output()
        .unwrap();
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    let frames = farm::checkpoints::frames(&farm::checkpoints::latest(&ckpts).unwrap()).unwrap();
    assert!(frames <= budget + per_update, "a second resume trained on to {frames}");
}

/// A dataset with one flipped bit is refused before any process starts, with one line naming
/// the damaged file; `eval` on it writes no tables.
#[test]
fn a_bit_flipped_dataset_is_refused_before_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("gond");
    std::fs::create_dir_all(copy.join("scenes")).unwrap();
    for e in std::fs::read_dir(dataset()).unwrap().chain(std::fs::read_dir(dataset().join("scenes")).unwrap()) {
        let e = e.unwrap();
        if e.file_type().unwrap().is_file() {
            let rel = e.path().strip_prefix(dataset()).unwrap().to_path_buf();
            std::fs::copy(e.path(), copy.join(rel)).unwrap();
        }
    }
    orchestrator::supervise::launch::verify_dataset(&copy).unwrap();
    let val = copy.join("val.gond");
    let mut bytes = std::fs::read(&val).unwrap();
    let k = bytes.len() * 2 / 3;
    bytes[k] ^= 0x10;
    std::fs::write(&val, &bytes).unwrap();
    let err =
        format!("{:#}", orchestrator::supervise::launch::verify_dataset(&copy).err().expect("a flipped bit is found"));
    assert!(err.contains("val.gond") && err.contains("corrupted"), "{err}");
    let out_dir = tmp.path().join("eval");
    let out = std::process::Command::new(bin("orchestrator"))
        .args(["eval", "--split", "val", "--max-programs", "4", "--workers", "1", "--dataset"])
        .arg(&copy)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("val.gond"), "{stderr}");
    assert!(!out_dir.join("tables.md").exists());
}

/// A short chaos soak: a seeded schedule of worker, learner and orchestrator kills and Ctrl-Cs
/// during training, resumed after each stop, loses no checkpoint, sample or file — with the two
/// workers taking their rounds in turn (`ppo.env_groups`), so a kill lands between groups too.
#[test]
fn a_short_soak_survives_every_fault() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "env_groups = 2\n\n[checkpoint]\nevery_updates = 2\nkeep = 3\n");
    let out = tmp.path().join("soak");
    // seed 3's first eight faults include every kind (a unit test of the schedule says so)
    let status = std::process::Command::new(bin("orchestrator"))
        .args(["soak", "--faults", "8", "--seed", "3", "--workers", "2", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    let report: Value = serde_json::from_str(&std::fs::read_to_string(out.join("soak.json")).unwrap()).unwrap();
    assert!(status.success(), "{report:#}");
    let injected: Vec<u64> = report["injected"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert_eq!(injected.iter().sum::<u64>(), 8);
    assert!(injected.iter().all(|&n| n > 0), "every kind of fault: {injected:?}");
    assert_eq!(report["survived"], report["injected"]);
    for k in ["bad_resumes", "unusable_checkpoints", "integrity_errors"] {
        assert_eq!(report[k], 0, "{k}: {report:#}");
    }
    assert!(report["leftovers"].as_array().unwrap().is_empty(), "{report:#}");
}

/// Two runs with different run ids on one host at the same time: each sees only its own
/// workers and messages.
#[test]
fn two_runs_on_one_host_do_not_interfere() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 2);
    let args =
        ["--workers", "2", "--config", cfg.to_str().unwrap(), "--policy", "random", "--frames", "800", "--check"];
    let mut a = Run::start(&tmp.path().join("a"), &args);
    let mut b = Run::start(&tmp.path().join("b"), &args);
    let (sa, sb) = (a.wait(Duration::from_secs(240)), b.wait(Duration::from_secs(240)));
    assert!(sa.success(), "{}", a.diagnostics());
    assert!(sb.success(), "{}", b.diagnostics());
    assert_ne!(a.run_id(), b.run_id());
    for run in [&a, &b] {
        let s = run.summary();
        assert_clean_totals(&s);
        assert_eq!(s["run_id"].as_str(), Some(run.run_id().as_str()));
        assert_eq!(u(&s["totals"], "restarts"), 0);
        let w = s["workers"].as_array().unwrap();
        assert_eq!(w.len(), 2);
        // frames of each run add up from its own two workers only
        assert_eq!(w.iter().map(|w| u(w, "frames")).sum::<u64>(), u(&s["totals"], "frames"));
        assert_gone(run);
    }
}

/// A second live run cannot use the same run directory.
#[test]
fn a_live_run_directory_is_locked() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 1);
    let dir = tmp.path().join("run");
    let mut first = Run::start(
        &dir,
        &[
            "--workers",
            "1",
            "--config",
            cfg.to_str().unwrap(),
            "--policy",
            "random",
            "--seconds",
            "120",
            "--report-every",
            "0.5",
        ],
    );
    first.wait_progress(Duration::from_secs(120), "the first run going", |p| p["frames"].as_u64() > Some(0));
    let out = std::process::Command::new(bin("orchestrator"))
        .args([
            "up",
            "--workers",
            "1",
            "--policy",
            "random",
            "--seconds",
            "5",
            "--config",
            cfg.to_str().unwrap(),
            "--run-dir",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("in use by a live run"), "{err}");
    first.signal(Signal::SIGINT);
    first.wait(EVENT_DEADLINE);
    assert_gone(&first);
}

/// The Python reader (iceoryx2's own binding, numpy views, no copy) attaches to a live run,
/// reads one observation and writes its RGB frame as a PNG.
#[test]
fn python_reads_one_frame_of_a_live_run() {
    let mut python = match python_with(&["iceoryx2", "numpy"]) {
        Ok(p) => p,
        Err(why) => {
            eprintln!("skipping python_reads_one_frame_of_a_live_run: {why}");
            return;
        }
    };
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 2);
    let mut run = Run::start(
        &tmp.path().join("run"),
        &[
            "--workers",
            "2",
            "--config",
            cfg.to_str().unwrap(),
            "--policy",
            "random",
            "--seconds",
            "120",
            "--report-every",
            "0.5",
        ],
    );
    run.wait_progress(Duration::from_secs(120), "frames from both workers", |p| {
        p["workers_seen"] == 2 && p["frames"].as_u64() > Some(0)
    });
    let png = tmp.path().join("frame.png");
    let out = python
        .arg(repo_root().join("tests/python/read_frame.py"))
        .arg("--run-dir")
        .arg(&run.dir)
        .args(["--worker", "1", "--env", "1", "--out"])
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "read_frame.py failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        run.diagnostics()
    );
    let info: Value = serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).expect("one JSON line");
    assert_eq!(info["worker_id"], 1);
    assert_eq!(
        (info["width"].as_u64(), info["height"].as_u64(), info["num_envs"].as_u64()),
        (Some(64), Some(64), Some(2))
    );
    assert_eq!(png_size(&png), (64, 64));
    run.signal(Signal::SIGINT);
    run.wait(EVENT_DEADLINE);
    assert_gone(&run);
}

/// Evaluation through the orchestrator's library (as `orchestrator eval` uses it): each worker
/// runs exactly its list of programs, the learner stops once every worker reports `finished`,
/// and `episodes.jsonl` holds each program exactly once.
#[test]
fn evaluation_runs_each_assigned_program_once_and_ends_by_itself() {
    use farm::serve_args::Policy;
    use orchestrator::supervise::crew::{Crew, CrewSpec};
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg_path = tiny_config(tmp.path(), 2);
    let mut cfg = farm::config::RunConfig::load(&cfg_path).unwrap();
    orchestrator::supervise::launch::resolve_dataset(&mut cfg, false).unwrap();
    let (dir, config_path) =
        orchestrator::supervise::launch::prepare_run(&tmp.path().join("eval"), &cfg, false, 2, Policy::Expert).unwrap();
    let mut spec = CrewSpec::new(&dir.path, &dir.run_id, &config_path, cfg, 2, Policy::Expert);
    spec.bin_dir = Some(bin_dir());
    spec.programs = Some(vec![vec![0, 1, 2], vec![3, 4]]);
    spec.check = true;
    spec.max_seconds = Some(180.0);
    let farm = Crew::start(spec).unwrap();
    let out = farm.finish().unwrap();
    assert!(out.learner.is_some_and(|e| e.success()), "{out:?}");
    let p = out.progress.unwrap();
    assert_eq!(p.stop_reason.as_deref(), Some("every worker finished its programs"));
    let lines = std::fs::read_to_string(dir.path.join("episodes.jsonl")).unwrap();
    let mut seen: Vec<(u64, u64)> = lines
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .map(|v| (v["worker"].as_u64().unwrap(), v["program"].as_u64().unwrap()))
        .collect();
    seen.sort();
    assert_eq!(seen, vec![(0, 0), (0, 1), (0, 2), (1, 3), (1, 4)]);
    assert!(out.leftovers.is_empty(), "{:?}", out.leftovers);
}

/// `kill -9` of the orchestrator itself: the parent-death signal takes every worker and the
/// learner down with it.
#[test]
fn no_child_outlives_a_killed_orchestrator() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 1);
    let mut run = Run::start(
        &tmp.path().join("run"),
        &[
            "--workers",
            "3",
            "--config",
            cfg.to_str().unwrap(),
            "--policy",
            "random",
            "--seconds",
            "300",
            "--report-every",
            "0.5",
        ],
    );
    run.wait_progress(Duration::from_secs(120), "frames from all 3 workers", |p| {
        p["workers_seen"] == 3 && p["frames"].as_u64() > Some(0)
    });
    assert_eq!(run.processes().len(), 4);
    run.signal(Signal::SIGKILL);
    run.wait(EVENT_DEADLINE);
    let t0 = Instant::now();
    while !run.processes().is_empty() {
        assert!(t0.elapsed() < EVENT_DEADLINE, "children outlived the orchestrator: {:?}", run.processes());
        std::thread::sleep(Duration::from_millis(20));
    }
    // Nobody was left to end the run's shared-memory domain: the next `orchestrator up`
    // sweeps it; here the test does.
    farm::transport::end_run_domain(&run.run_id()).unwrap();
    assert!(shm_leftovers(&run.run_id()).is_empty());
}

/// `orchestrator eval` of the shortest-path expert over a whole split: every program once, SR
/// 100% and SPL above 70% with no path shorter than its l_i, trajectory pictures drawn; and the Random
/// baseline on the same programs far below it. `eval --compare` puts the two side by side, by the
/// target's nearness to the start too, every program in one class.
#[test]
fn eval_of_the_expert_scores_full_success_and_random_does_not() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tiny_config(tmp.path(), 4);
    let eval = |extra: &[&str], out: &Path| {
        let o = std::process::Command::new(bin("orchestrator"))
            .args(["eval", "--split", "val", "--workers", "2", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "eval failed:\n{}", String::from_utf8_lossy(&o.stderr));
        let csv = std::fs::read_to_string(out.join("tables.csv")).unwrap();
        let row = csv.lines().find(|l| l.contains(",normal,all,all,inf,")).expect("unlimited-stops row").to_string();
        let f: Vec<&str> = row.split(',').collect();
        (f[6].parse::<usize>().unwrap(), f[7].parse::<f64>().unwrap(), f[8].parse::<f64>().unwrap())
    };
    let programs = worker::dataset::Dataset::open(&dataset(), worker::dataset::Verify::Quick)
        .unwrap()
        .require(worker::scene::Split::Val)
        .unwrap()
        .len();
    let expert_dir = tmp.path().join("expert");
    let (n, sr, spl) = eval(&["--expert", "--trajectories", "2"], &expert_dir);
    assert_eq!(n, programs, "every program of the split once");
    assert_eq!(sr, 100.0, "expert SR");
    // l_i is a lower bound below any path of 0.25 m steps at 15° headings: the expert scores
    // less than 100, and none of its paths is shorter than its l_i
    assert!(spl > 70.0 && spl <= 100.0, "expert SPL {spl}");
    let md = std::fs::read_to_string(expert_dir.join("tables.md")).unwrap();
    assert!(md.contains(&format!(" 0 of {n} successful episodes were shorter than their l_i")), "{md}");
    let pictures: Vec<_> = std::fs::read_dir(expert_dir.join("trajectories"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        pictures.iter().filter(|p| p.ends_with(".png")).count() == 2
            && pictures.iter().filter(|p| p.ends_with(".gif")).count() == 2,
        "{pictures:?}"
    );
    let (n, sr, _) = eval(&[], &tmp.path().join("random"));
    assert_eq!(n, programs);
    assert!(sr < 50.0, "random SR {sr}");
    let compared = tmp.path().join("compared");
    let o = std::process::Command::new(bin("orchestrator"))
        .args(["eval", "--split", "val", "--out"])
        .arg(&compared)
        .arg("--compare")
        .args([&expert_dir, &tmp.path().join("random")])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(compared.join("compare.md")).unwrap();
    let near = md.split("## By the target's nearness at the start").nth(1).expect("the nearness table");
    let expert = near.lines().find(|l| l.starts_with("| Expert")).expect("the expert's row");
    let cells: Vec<&str> = expert.split('|').map(str::trim).filter(|c| !c.is_empty()).skip(1).collect();
    let count = |c: &str| c.rsplit('(').next().unwrap().trim_end_matches(')').parse::<usize>().unwrap();
    assert_eq!(cells.iter().map(|c| count(c)).sum::<usize>(), n, "{near}");
    assert!(cells.iter().all(|c| c.starts_with("100.0 / 100.0") || count(c) == 0), "{near}");
    assert!(near.lines().any(|l| l.starts_with("| Random")), "{near}");
    // where each heads at its first move ahead, over the same programs out of view at the start
    let heads = md.split("## The first move ahead: where the policy heads").nth(1).expect("the heading table");
    let rows: Vec<&str> = heads.lines().filter(|l| l.starts_with("| Expert") || l.starts_with("| Random")).collect();
    let out_of_view = |l: &str| l.split('|').nth(3).unwrap().trim().to_string();
    assert!(rows.len() == 2 && out_of_view(rows[0]) == out_of_view(rows[1]), "{heads}");
    let own = std::fs::read_to_string(expert_dir.join("tables.md")).unwrap();
    assert!(own.contains("## By the target's nearness at the start"), "{own}");
    assert!(own.contains("## The first move ahead: where the policy heads"), "{own}");
    // an evaluation of another dataset is named, not read against this split's programs
    let other = tmp.path().join("other");
    std::fs::create_dir_all(other.join("normal")).unwrap();
    let line =
        std::fs::read_to_string(expert_dir.join("normal/episodes.jsonl")).unwrap().lines().next().unwrap().to_string();
    let mut beyond: Value = serde_json::from_str(&line).unwrap();
    beyond["program"] = serde_json::json!(n + 7);
    std::fs::write(other.join("normal/episodes.jsonl"), format!("{line}\n{beyond}\n")).unwrap();
    let o = std::process::Command::new(bin("orchestrator"))
        .args(["eval", "--split", "val", "--compare"])
        .args([&expert_dir, &other])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains(&format!("program {} is not among the {n} val programs", n + 7)),
        "{err}"
    );
    // nor is one of another split (`--split` is test unless given)
    let o =
        std::process::Command::new(bin("orchestrator")).args(["eval", "--compare"]).arg(&expert_dir).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("an evaluation on val, compared on --split test"), "{err}");
}

/// `orchestrator bench train` on a few hundred frames: the table, and a profile in the run's
/// last progress record with time in the learner's update and inference and in the workers'
/// rendering and waiting; a `--set` changes the config, and the table's command says so. Its
/// rounds are taken by two groups of workers in turn (`ppo.env_groups`), each rollout's last
/// step by both at once: the run learns (updates counted in the profile) and stops on budget.
#[test]
fn bench_train_reports_throughput_and_where_the_time_went() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    let out_dir = tmp.path().join("bench");
    let out = std::process::Command::new(bin("orchestrator"))
        .args(["bench", "train", "--workers", "2", "--frames", "300", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out_dir)
        .args(["--set", "env.envs_per_worker=3", "--set", "ppo.env_groups=2"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(out_dir.join("bench_train.md")).unwrap();
    assert!(md.contains("--set env.envs_per_worker=3") && md.contains("2 workers × 3 envs in 2 groups"), "{md}");
    assert!(md.contains("--set ppo.env_groups=2") && md.contains("in 2 groups taking rounds in turn"), "{md}");
    // the learner names where it ran (CPU here, CUDA on a GPU machine)
    for row in ["Learner: device ", "end-to-end frames/s", "PPO update", "inference", "render", "waiting for actions"] {
        assert!(md.contains(row), "no `{row}` in\n{md}");
    }
    let progress = std::fs::read_to_string(out_dir.join("run/farm.jsonl")).unwrap();
    let last: Value = serde_json::from_str(progress.lines().last().unwrap()).unwrap();
    assert!(u(&last, "frames") >= 300, "{last}");
    let p = &last["profile"];
    let secs = |v: &Value| v.as_f64().unwrap_or(0.0);
    for (part, v) in [
        ("learner update", &p["learner"]["update_s"]),
        ("learner inference", &p["learner"]["infer_s"]),
        ("worker render", &p["workers"]["render_s"]),
        ("worker wait", &p["workers"]["wait_s"]),
    ] {
        assert!(secs(v) > 0.0, "no time in {part}: {p}");
    }
}

/// `kill -9` of a worker whose frames stay on the device: its restart hands over new memory
/// as generation 1, the learner imports it and reads the new worker's frames from there, and
/// training goes on.
#[test]
fn a_killed_worker_hands_its_new_frame_memory_over() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    let dir = tmp.path().join("run");
    let args = ["--workers", "2", "--config", cfg.to_str().unwrap(), "--set", "env.frames=device", "--seconds", "600"];
    let mut run = Run::start(&dir, &[&args[..], &["--report-every", "0.5"]].concat());
    let p = run.wait_progress(Duration::from_secs(240), "frames from both workers", |p| {
        p["workers_seen"] == 2 && p["frames"].as_u64() > Some(100)
    });
    let victim = run.worker_pid(1).expect("worker 1 is running");
    kill(Pid::from_raw(victim), Signal::SIGKILL).unwrap();
    let frames_then = u(&p, "frames");
    run.wait_progress(Duration::from_secs(240), "the restarted worker back in the batches", |p| {
        p["restarts"].as_u64() >= Some(1) && p["workers_live"] == 2 && p["frames"].as_u64() > Some(frames_then + 200)
    });
    run.signal(Signal::SIGINT);
    let status = run.wait(EVENT_DEADLINE);
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    let log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap();
    for imported in ["worker 0 (generation 0)", "worker 1 (generation 0)", "worker 1 (generation 1)"] {
        assert!(log.contains(&format!("{imported}: 2 frames of 32x32 imported")), "{imported}:\n{log}");
    }
    assert_gone(&run);
}
