//! The `gesthor` Python package, assembled from this build (the workspace builds its native
//! extension; `pip install ./python` makes the same package with maturin): Gymnasium's checker
//! passes, the same seed gives the same observations, and a random rollout from Python succeeds
//! as often as the farm's Random policy on the same split.

use std::path::{Path, PathBuf};

use gesthor_tests::*;
use serde_json::Value;

/// `dir/gesthor/`: the package's Python files and the native extension of this build.
fn assemble_package(dir: &Path) -> PathBuf {
    let pkg = dir.join("gesthor");
    std::fs::create_dir_all(&pkg).unwrap();
    for e in std::fs::read_dir(repo_root().join("python/gesthor")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "py") {
            std::fs::copy(&p, pkg.join(p.file_name().unwrap())).unwrap();
        }
    }
    let native = bin_dir().join("lib_gesthor.so");
    assert!(native.is_file(), "{} missing: `cargo build --release --workspace` builds it", native.display());
    std::fs::copy(&native, pkg.join("_gesthor.abi3.so")).unwrap();
    dir.to_path_buf()
}

/// Success rate of `up --policy random` over `frames` frames of the test dataset's train split.
fn farm_random_success(dir: &Path, frames: u64) -> (u64, u64) {
    let cfg = tiny_config(dir, 8);
    let run = dir.join("random");
    let out = std::process::Command::new(bin("orchestrator"))
        .args(["up", "--policy", "random", "--workers", "1", "--frames", &frames.to_string(), "--config"])
        .arg(&cfg)
        .arg("--run-dir")
        .arg(&run)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let eps: Vec<Value> = farm::files::read_jsonl(&run.join("episodes.jsonl")).unwrap();
    let wins = eps.iter().filter(|e| e["success"] == true).count() as u64;
    (eps.len() as u64, wins)
}

#[test]
fn python_steps_gesthor_as_a_gymnasium_vector_env() {
    let mut python = match python_with(&["gymnasium", "numpy"]) {
        Ok(p) => p,
        Err(why) => {
            eprintln!("skipping python_steps_gesthor_as_a_gymnasium_vector_env: {why}");
            return;
        }
    };
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let pkg = assemble_package(tmp.path());
    let path: Vec<String> = python
        .get_envs()
        .filter(|(k, _)| *k == "PYTHONPATH")
        .filter_map(|(_, v)| v.map(|v| v.to_string_lossy().into_owned()))
        .collect();
    python.env("PYTHONPATH", std::iter::once(pkg.display().to_string()).chain(path).collect::<Vec<_>>().join(":"));
    let out = python
        .arg(repo_root().join("tests/python/test_gesthor.py"))
        .arg(dataset())
        .args(["--steps", "10000", "--envs", "8"])
        .output()
        .unwrap();
    assert!(out.status.success(), "test_gesthor.py failed:\n{}", String::from_utf8_lossy(&out.stderr));
    let r: Value = serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).expect("one JSON object");
    assert_eq!(r["check_env"], "passed");
    assert_eq!(r["same_seed_same_observations"], true, "{r}");

    let (n_py, wins_py) = (r["episodes"].as_u64().unwrap(), r["successes"].as_u64().unwrap());
    let (n_farm, wins_farm) = farm_random_success(tmp.path(), 10_000);
    assert!(n_py >= 30 && n_farm >= 30, "too few episodes: python {n_py}, farm {n_farm}");
    let (p_py, p_farm) = (wins_py as f64 / n_py as f64, wins_farm as f64 / n_farm as f64);
    // The same process seen from two sides: equal within 4 standard errors of the difference.
    let p = (wins_py + wins_farm) as f64 / (n_py + n_farm) as f64;
    let se = (p * (1.0 - p) * (1.0 / n_py as f64 + 1.0 / n_farm as f64)).sqrt().max(0.01);
    assert!(
        (p_py - p_farm).abs() <= 4.0 * se,
        "random success: python {wins_py}/{n_py} vs farm {wins_farm}/{n_farm} (4 se = {:.3})",
        4.0 * se
    );
}
