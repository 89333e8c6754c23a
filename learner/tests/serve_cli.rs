//! `learner serve`'s command line. (Also makes `cargo test --workspace` build the executable
//! that the workspace tests in tests/ start through the orchestrator.)

use std::process::Command;

#[test]
fn serve_reports_a_bad_config_in_one_line() {
    let d = tempfile::tempdir().unwrap();
    let cfg = d.path().join("l.toml");
    std::fs::write(&cfg, "[run]\nmethod = \"both\"\n[ppo]\nclip = \"wide\"\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_learner"))
        .args(["serve", "--config", cfg.to_str().unwrap(), "--run-id", "x", "--workers", "1", "--run-dir"])
        .arg(d.path().join("run"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("l.toml") && err.contains("ppo.clip"), "{err}");
}
