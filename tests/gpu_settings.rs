//! The GPU settings, run on the CPU as CI has them: the frames kept on the device
//! (lavapipe's memory, imported through Vulkan) and the update overlapped with collection. Each
//! trains a small model with `orchestrator up` and checks what the setting must not change.

use gesthor_tests::*;
use serde_json::Value;

/// `ppo.overlap_update`: a run whose updates learn on a thread while the next rollout
/// is collected says so in its log (a policy lag of 1 after the first update) and, stopped at its
/// frame budget, learns the rollouts still queued or in flight: its final checkpoint holds as
/// many frames as the same run's in place.
#[test]
fn an_overlapped_run_learns_every_rollout_it_collected() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    // three rollouts of 16 steps × 2 workers × 2 envs: the third is not complete at the stop
    let budget = (3 * 16 * 2 * 2).to_string();
    let run = |name: &str, set: &str| {
        let dir = tmp.path().join(name);
        let o = std::process::Command::new(bin("orchestrator"))
            .args(["up", "--workers", "2", "--frames", &budget, "--set", set, "--config"])
            .arg(&cfg)
            .arg("--run-dir")
            .arg(&dir)
            .output()
            .unwrap();
        let log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap_or_default();
        assert!(o.status.success(), "{}\n{log}", String::from_utf8_lossy(&o.stderr));
        let lags: Vec<u64> = std::fs::read_to_string(dir.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str::<Value>(l).unwrap()["policy_lag"].as_u64().unwrap())
            .collect();
        let ckpt = farm::checkpoints::latest(&farm::checkpoints::dir_of(&dir)).expect("a checkpoint");
        (farm::checkpoints::frames(&ckpt).unwrap(), lags, log)
    };
    let (in_place, lags, _) = run("in-place", "ppo.overlap_update=false");
    assert_eq!(lags, vec![0, 0]);
    let (overlapped, lags, log) = run("overlapped", "ppo.overlap_update=true");
    assert_eq!(lags, vec![0, 1], "{log}");
    assert!(log.contains("policy lag 1") && log.contains("(learned at the stop)"), "{log}");
    assert_eq!(overlapped, in_place, "{log}");
}

/// `env.frames = "device"`: the workers draw into GPU memory they hand the learner
/// once over the run's frame socket (here lavapipe's, imported through Vulkan), and no frame
/// passes through shared memory. A run trains that way, and its checkpoint, evaluated greedily,
/// takes every step exactly as with the frames read back through shared memory.
#[test]
fn frames_kept_on_the_device_are_the_frames_read_back() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    let dir = tmp.path().join("run");
    let o = std::process::Command::new(bin("orchestrator"))
        .args(["up", "--workers", "2", "--frames", "128", "--set", "env.frames=device", "--config"])
        .arg(&cfg)
        .arg("--run-dir")
        .arg(&dir)
        .output()
        .unwrap();
    let learner_log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap_or_default();
    assert!(o.status.success(), "{}\n{learner_log}", String::from_utf8_lossy(&o.stderr));
    for w in 0..2 {
        assert!(
            learner_log.contains(&format!("worker {w} (generation 0): 2 frames of 32x32 imported")),
            "{learner_log}"
        );
    }
    assert!(!dir.join("frames.sock").exists(), "the learner removes its socket");
    let ckpt = farm::checkpoints::latest(&farm::checkpoints::dir_of(&dir)).expect("a checkpoint");
    // (normal, blind) episodes of the checkpoint's greedy policy
    let episodes = |frames: &str| {
        let out = tmp.path().join(frames);
        let o = std::process::Command::new(bin("orchestrator"))
            .args([
                "eval",
                "--split",
                "val",
                "--workers",
                "1",
                "--greedy",
                "--max-programs",
                "6",
                "--modes",
                "normal,blind",
            ])
            .args(["--set", &format!("env.frames={frames}"), "--config"])
            .arg(&cfg)
            .arg("--checkpoint")
            .arg(&ckpt)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "eval with {frames}: {}", String::from_utf8_lossy(&o.stderr));
        let log = std::fs::read_to_string(out.join("normal/logs/learner.log")).unwrap_or_default();
        assert_eq!(log.contains("imported from its GPU memory"), frames == "device", "{log}");
        let pass = |mode: &str| {
            let text = std::fs::read_to_string(out.join(mode).join("episodes.jsonl")).unwrap();
            let mut rows: Vec<Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
            rows.sort_by_key(|r| r["program"].as_u64());
            let keep = ["program", "steps", "success", "path_length", "final_distance", "collisions", "stops"];
            rows.iter().map(|r| keep.map(|k| r[k].clone())).collect::<Vec<_>>()
        };
        (pass("normal"), pass("blind"))
    };
    let (read_back, blind) = episodes("shared_memory");
    assert_eq!(read_back.len(), 6);
    // the policy's steps depend on what it sees: blind, it takes others
    assert_ne!(blind, read_back);
    assert_eq!(episodes("device"), (read_back, blind));
}
