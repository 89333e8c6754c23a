//! Bad input on the command line: one clear line naming what is wrong, and nothing created or
//! started before it is refused.

use std::process::Command;

use gesthor_tests::bin;

fn orchestrator(args: &[&str]) -> (bool, String) {
    let out = Command::new(bin("orchestrator")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn bad_worker_counts_and_durations_are_refused_before_the_run_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let dir = run.to_str().unwrap();
    for (args, says) in [
        (vec!["up", "--workers", "0", "--run-dir", dir], "--workers"),
        (vec!["up", "--seconds=-1", "--run-dir", dir], "--seconds"),
        (vec!["up", "--seconds", "nan", "--run-dir", dir], "--seconds"),
    ] {
        let (ok, err) = orchestrator(&args);
        assert!(!ok && err.contains(says), "{args:?}: {err}");
        assert!(!run.exists(), "{args:?} created {}", run.display());
    }
}

#[test]
fn a_bad_config_value_names_the_file_and_field() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("bad.toml");
    std::fs::write(&cfg, "[run]\nmethod = \"both\"\n[ppo]\nclip = -5\n").unwrap();
    let run = tmp.path().join("run");
    let (ok, err) = orchestrator(&["up", "--config", cfg.to_str().unwrap(), "--run-dir", run.to_str().unwrap()]);
    assert!(!ok && err.contains("bad.toml") && err.contains("ppo.clip"), "{err}");
    assert!(!run.exists());
}

#[test]
fn replay_of_an_unknown_program_is_one_line() {
    let (ok, err) = orchestrator(&["replay", "nope:1", "--out", "/tmp/never"]);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert!(!ok && lines.len() == 1 && lines[0].contains("nope:1"), "{err}");
}

/// On a headless machine (no XDG_RUNTIME_DIR) the drivers' Wayland probe stays quiet.
#[test]
fn render_on_a_headless_machine_prints_no_error_line() {
    let tmp = tempfile::tempdir().unwrap();
    let out = Command::new(bin("orchestrator"))
        .args(["render", "--scene", "FloorPlan201", "--out"])
        .arg(tmp.path())
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.lines().any(|l| l.starts_with("error:")), "{err}");
}

/// `--set` overrides a config value; a wrong key is one line naming it, before anything is made.
#[test]
fn a_wrong_override_key_is_one_line_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (ok, err) = orchestrator(&["up", "--set", "ppo.lrr=1", "--run-dir", run.to_str().unwrap()]);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert!(!ok && lines.len() == 1 && lines[0].contains("ppo.lrr"), "{err}");
    assert!(!run.exists());
}
