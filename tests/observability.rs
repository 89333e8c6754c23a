//! Watching a run: TensorBoard reads what training and evaluation log, and the terminal output
//! of a run written to a file holds no line twice.

use std::collections::BTreeMap;
use std::process::Command;

use gesthor_tests::*;
use serde_json::Value;

fn orchestrator(args: &[&str]) -> String {
    let out = Command::new(bin("orchestrator")).args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "orchestrator {args:?} failed:\n{err}");
    err
}

/// (step, value) pairs per tag, as TensorBoard's own reader gives them.
fn series(v: &Value) -> BTreeMap<String, Vec<(i64, f64)>> {
    v.as_object()
        .unwrap()
        .iter()
        .map(|(tag, points)| {
            let pts = points.as_array().unwrap().iter().map(|p| (p[0].as_i64().unwrap(), p[1].as_f64().unwrap()));
            (tag.clone(), pts.collect())
        })
        .collect()
}

/// A training, resumed from an earlier checkpoint than its last, then evaluated: TensorBoard's
/// reader lists the training scalars once per update with increasing frame counts (what the
/// first process logged after the resumed checkpoint is hidden), the farm's counters, the
/// evaluation under `eval/` at the checkpoint's frames, the curves and a trajectory map as
/// images, and the configuration and tables as text.
#[test]
fn tensorboard_reads_a_resumed_training_and_its_evaluation() {
    let mut python = match python_with(&["tensorboard"]) {
        Ok(p) => p,
        Err(why) => {
            eprintln!("skipping tensorboard_reads_a_resumed_training_and_its_evaluation: {why}");
            return;
        }
    };
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    // 32 frames per update (1 worker × 2 envs × 16 steps), a checkpoint every 2 updates and at the end
    let cfg = small_ppo_config(tmp.path(), "\n[checkpoint]\nevery_updates = 2\nkeep = 10\n");
    let run = tmp.path().join("run");
    let (run_s, cfg_s) = (run.to_str().unwrap(), cfg.to_str().unwrap());
    let common = ["--workers", "1", "--report-every", "0.2"];
    orchestrator(&[&["up", "--run-dir", run_s, "--config", cfg_s, "--frames", "160"][..], &common].concat());
    let ckpts = farm::checkpoints::dir_of(&run);
    let last = farm::checkpoints::latest(&ckpts).unwrap();
    let first_updates = farm::checkpoints::update_of(&last).unwrap();
    assert!(first_updates >= 3, "{}", last.display());
    // Resume from the checkpoint before: the updates after it are learned again, at the same
    // frame counts as the first process logged them.
    std::fs::remove_file(&last).unwrap();
    orchestrator(&[&["up", "--resume", run_s, "--frames", "100"][..], &common].concat());
    let newest = farm::checkpoints::latest(&ckpts).unwrap();
    let updates = farm::checkpoints::update_of(&newest).unwrap() as i64;
    assert!(updates > first_updates as i64, "{}", newest.display());
    let frames = farm::checkpoints::frames(&newest).unwrap();
    assert_eq!(frames as i64, updates * 32);
    orchestrator(&[
        "eval",
        "--checkpoint",
        run_s,
        "--split",
        "val",
        "--max-programs",
        "4",
        "--modes",
        "normal",
        "--workers",
        "1",
        "--trajectories",
        "1",
    ]);

    let out = python.arg(repo_root().join("tests/python/read_tensorboard.py")).arg(run.join("tb")).output().unwrap();
    assert!(out.status.success(), "read_tensorboard.py failed: {}", String::from_utf8_lossy(&out.stderr));
    let tb: Value = serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).expect("one JSON object");
    let scalars = series(&tb["scalars"]);

    let training: Vec<&String> = scalars.keys().filter(|t| !t.starts_with("eval/")).collect();
    assert!(training.len() >= 10, "{training:?}");
    let per_update: Vec<i64> = (1..=updates).map(|u| u * 32).collect();
    for tag in ["losses/value_loss", "losses/entropy", "charts/learning_rate", "perf/fps"] {
        let steps: Vec<i64> = scalars[tag].iter().map(|p| p.0).collect();
        assert_eq!(steps, per_update, "{tag}: one point per update, the redone one once");
    }
    for tag in &training {
        let steps: Vec<i64> = scalars[*tag].iter().map(|p| p.0).collect();
        assert!(steps.windows(2).all(|w| w[0] < w[1]), "{tag}: steps {steps:?}");
    }
    for tag in ["farm/restarts", "farm/lost", "farm/corrupt", "farm/stale", "farm/duplicates"] {
        let pts = scalars.get(tag).unwrap_or_else(|| panic!("no {tag} in {training:?}"));
        assert!(pts.iter().all(|p| p.1 == 0.0), "{tag}: {pts:?}");
    }

    let sr = &scalars["eval/val/SR@1"];
    assert_eq!(sr.len(), 1);
    assert_eq!(sr[0].0, frames as i64, "evaluation at the checkpoint's frames");
    assert!((0.0..=1.0).contains(&sr[0].1));
    for stops in ["1", "2", "3", "inf"] {
        for m in ["SR", "SPL", "DTS"] {
            assert!(scalars.contains_key(&format!("eval/val/{m}@{stops}")), "eval/val/{m}@{stops}");
        }
    }

    let images = tb["images"].as_object().unwrap();
    assert!(images.contains_key("charts/curves"), "{images:?}");
    assert_eq!(images.keys().filter(|t| t.starts_with("eval/val/trajectories/")).count(), 1, "{images:?}");
    let texts = tb["texts"].as_object().unwrap();
    let config = texts["config"][0][1].as_str().unwrap();
    assert!(config.contains("rollout = 16"), "{config}");
    assert!(texts["eval/val/tables"][0][1].as_str().unwrap().contains("SR"), "{texts:?}");
}

/// `up` with its output in a file (not a terminal): plain progress lines, none repeated, and no
/// library or driver noise.
#[test]
fn a_run_logged_to_a_file_repeats_no_line() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    let run = tmp.path().join("run");
    let err = orchestrator(&[
        "up",
        "--run-dir",
        run.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--workers",
        "2",
        "--seconds",
        "12",
        "--report-every",
        "0.2",
    ]);
    let lines: Vec<&str> = err.lines().collect();
    let mut seen = std::collections::BTreeSet::new();
    for l in &lines {
        assert!(seen.insert(*l), "printed twice: {l}\n{err}");
        assert!(!l.starts_with("error") && !l.contains("XDG_RUNTIME_DIR"), "noise: {l}\n{err}");
    }
    assert!(lines.iter().any(|l| l.starts_with("[up] ") && l.contains("/12 s (")), "no progress line:\n{err}");
}
