//! The `worker` executable's command line. (Also makes `cargo test --workspace` build the
//! executable that the workspace tests in tests/ start through the orchestrator.)

use std::process::Command;

#[test]
fn a_bad_config_is_one_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let cfg = d.path().join("w.toml");
    std::fs::write(&cfg, "[run]\nmethod = \"nope\"\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_worker"))
        .args(["--config", cfg.to_str().unwrap(), "--run-id", "x"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1));
    assert!(err.contains("w.toml") && err.contains("run.method"), "{err}");
}

#[test]
fn the_run_id_is_required() {
    let out = Command::new(env!("CARGO_BIN_EXE_worker")).args(["--config", "x.toml"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--run-id"));
}
