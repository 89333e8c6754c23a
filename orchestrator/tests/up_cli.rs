//! `orchestrator up` refuses bad input with one clear line, before starting anything.
//! (Also makes `cargo test --workspace` build the `orchestrator` executable the workspace tests
//! in tests/ run.)

use std::process::Command;

fn up(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_orchestrator")).arg("up").args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn a_typo_in_the_config_names_the_file_and_the_field() {
    let d = tempfile::tempdir().unwrap();
    let cfg = d.path().join("typo.toml");
    std::fs::write(&cfg, "[run]\nmethod = \"both\"\n[env]\nenvs_per_wroker = 2\n").unwrap();
    let (ok, err) = up(&["--config", cfg.to_str().unwrap(), "--run-dir", d.path().join("run").to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("typo.toml") && err.contains("envs_per_wroker"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(!d.path().join("run").exists(), "nothing is created for a bad config");
}

#[test]
fn a_missing_dataset_names_the_path_and_how_to_build_it() {
    let d = tempfile::tempdir().unwrap();
    let cfg = d.path().join("c.toml");
    std::fs::write(&cfg, "[run]\nmethod = \"both\"\ndataset = \"/nonexistent/gond\"\n").unwrap();
    let (ok, err) = up(&["--config", cfg.to_str().unwrap(), "--run-dir", d.path().join("run").to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("/nonexistent/gond") && err.contains("orchestrator dataset build"), "{err}");
}

#[test]
fn frames_and_seconds_exclude_each_other() {
    let (ok, err) = up(&["--frames", "10", "--seconds", "3"]);
    assert!(!ok && err.contains("cannot be used with"), "{err}");
}
