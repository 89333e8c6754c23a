//! The shipped models (`models/`): each loads, acts and reproduces the episodes its check
//! recorded (`orchestrator model check`), checking one leaves its folder as shipped, and a
//! damaged one is refused in one line naming its file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use gesthor_tests::{bin, default_dataset, repo_root, serial};

/// Every file of `dir` with its size, by name.
fn files(dir: &Path) -> Vec<(String, u64)> {
    let mut found: Vec<(String, u64)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| (e.file_name().to_string_lossy().into_owned(), e.metadata().unwrap().len()))
        .collect();
    found.sort();
    found
}

fn check(model: &Path, out: &Path) -> Output {
    Command::new(bin("orchestrator"))
        .current_dir(repo_root())
        .args(["model", "check"])
        .arg(model)
        .arg("--dataset")
        .arg(default_dataset())
        .arg("--out")
        .arg(out)
        .output()
        .expect("running orchestrator model check")
}

fn shipped() -> Vec<PathBuf> {
    let models = farm::models::list(&repo_root().join(farm::models::DIR));
    assert!(!models.is_empty(), "models/ ships no model");
    models
}

#[test]
fn every_shipped_model_reproduces_the_episodes_its_card_records() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    for model in shipped() {
        let name = model.file_name().unwrap().to_string_lossy().into_owned();
        let before = files(&model);
        for file in [farm::models::CARD, farm::models::CHECK] {
            assert!(model.join(file).is_file(), "{name} has no {file}");
        }
        let weights = before.iter().find(|(f, _)| f == farm::models::WEIGHTS).unwrap().1;
        assert!(weights <= 16_000_000, "{name}'s weights are {weights} bytes, over 16 MB");
        let out = check(&model, &tmp.path().join(&name));
        let said = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "{name} does not reproduce its check:\n{said}");
        assert!(said.contains("episodes as recorded"), "{said}");
        assert_eq!(files(&model), before, "checking {name} changed its folder");
    }
}

#[test]
fn a_damaged_model_is_refused_naming_its_file() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("damaged");
    std::fs::create_dir(&model).unwrap();
    let from = &shipped()[0];
    for (file, _) in files(from) {
        std::fs::copy(from.join(&file), model.join(&file)).unwrap();
    }
    let weights = model.join(farm::models::WEIGHTS);
    let mut bytes = std::fs::read(&weights).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&weights, bytes).unwrap();
    let out = check(&model, &tmp.path().join("out"));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a damaged model passed its check");
    assert!(said.contains(&weights.display().to_string()) && said.contains("checksum"), "{said}");
}
