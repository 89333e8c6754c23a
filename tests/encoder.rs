//! The frozen visual encoder end to end, on a small build: `orchestrator encoder pretrain` gives
//! the same frames and the same weights (sha256) for the same seed, other weights for another;
//! a short `orchestrator up` trains on it; the probes of the encoders and of the gesture input report.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use gesthor_tests::{Run, bin, dataset, serial};
use serde_json::Value;

/// `orchestrator encoder pretrain` of 64 frames and one epoch, with `threads` renderers.
fn pretrain(out: &Path, seed: u64, threads: usize) -> Value {
    let o = Command::new(bin("orchestrator"))
        .args(["encoder", "pretrain", "--frames", "64", "--epochs", "1", "--keep-frames", "--seed"])
        .arg(seed.to_string())
        .args(["--threads", &threads.to_string()])
        .arg("--dataset")
        .arg(dataset())
        .arg("--out")
        .arg(out)
        .output()
        .expect("running orchestrator encoder pretrain");
    assert!(
        o.status.success(),
        "encoder pretrain failed ({}):\n{}\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let json = out.with_extension("json");
    serde_json::from_str(&std::fs::read_to_string(&json).unwrap_or_else(|e| panic!("{}: {e}", json.display()))).unwrap()
}

/// Same seed (rendered with one thread, then two) → the same frame set and weights.
#[test]
fn the_same_seed_gives_the_same_encoder() {
    let _one_at_a_time = serial();
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (dir.path().join("a"), dir.path().join("b"), dir.path().join("c"));
    let (ja, jb, jc) = (pretrain(&a, 5, 1), pretrain(&b, 5, 2), pretrain(&c, 6, 2));
    let frames = |p: &Path| std::fs::read(p.with_extension("frames")).unwrap();
    assert!(frames(&a) == frames(&b), "the frame sets differ (1 and 2 render threads)");
    assert_eq!(ja["sha256"], jb["sha256"]);
    assert_ne!(ja["sha256"], jc["sha256"]);
    let weights = std::fs::read(a.with_extension("safetensors")).unwrap();
    assert!(weights.len() > 1000);
    assert_eq!(ja["frames"], 64);
    assert_eq!(ja["held_out_frames"], 7);
    assert_eq!(ja["width"], 64);
    assert_eq!(ja["held_out_rooms"].as_array().unwrap().len(), 8);
    assert!(ja["rooms"].as_array().unwrap().iter().all(|r| r.as_str().unwrap().starts_with("FloorPlan")));
    assert!(ja["held_out"]["cells_matched"].as_f64().is_some_and(|x| (0.0..=1.0).contains(&x)), "{ja}");
}

/// The label-free objectives read the pixels only: a copy of a frame set with every cell label,
/// cell depth and facing changed gives the same weights (the RGB-D encoder's and configs/faithful's
/// ResNet-18's); the semantic sensor's do change.
#[test]
fn the_default_encoder_reads_no_label() {
    let _one_at_a_time = serial();
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a");
    let ja = pretrain(&a, 5, 2);
    assert_eq!(ja["objective"], "contrast", "{ja}");
    let mut set = farm::frame_set::FrameSet::read(&a.with_extension("frames")).unwrap();
    let classes = set.header.classes as u8;
    set.cell_class.iter_mut().for_each(|c| *c = (*c + 1) % classes);
    set.cell_depth.iter_mut().for_each(|d| *d = d.wrapping_add(999));
    set.person_facing.iter_mut().for_each(|f| *f = 45.0);
    let relabelled = dir.path().join("relabelled.frames");
    set.write(&relabelled).unwrap();
    let train = |frames: &Path, out: &str, objective: &str| -> Value {
        let (objective, trunk) = objective.split_once('/').unwrap_or((objective, "rgbd"));
        let out = dir.path().join(out);
        let o = Command::new(bin("learner"))
            .args(["--device", "cpu", "pretrain-encoder", "--seed", "5", "--epochs", "1", "--objective", objective])
            .args(["--trunk", trunk])
            .arg("--frames")
            .arg(frames)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap()).unwrap()
    };
    let frames = a.with_extension("frames");
    assert_eq!(train(&frames, "c1", "contrast")["sha256"], ja["sha256"], "the orchestrator's run is the same");
    assert_eq!(train(&relabelled, "c2", "contrast")["sha256"], ja["sha256"]);
    assert_eq!(train(&frames, "r1", "reconstruct")["sha256"], train(&relabelled, "r2", "reconstruct")["sha256"]);
    // configs/faithful's ResNet-18 trunk, by the same contrast
    let resnet = train(&frames, "n1", "contrast/resnet18");
    assert_eq!((&resnet["trunk"], &resnet["feature_channels"]), (&Value::from("resnet18"), &Value::from(512)));
    assert_eq!(train(&relabelled, "n2", "contrast/resnet18")["sha256"], resnet["sha256"]);
    assert_ne!(train(&frames, "s1", "semantic")["sha256"], train(&relabelled, "s2", "semantic")["sha256"]);
}

/// `orchestrator encoder probe` of an encoder and of the raw pixels: a table row and a JSON
/// record each, figures in their ranges, and the frames it rendered removed.
#[test]
fn probes_report_each_encoder() {
    let _one_at_a_time = serial();
    let dir = tempfile::tempdir().unwrap();
    let enc = dir.path().join("enc");
    pretrain(&enc, 5, 2);
    let out = dir.path().join("probes");
    let o = Command::new(bin("orchestrator"))
        .args(["encoder", "probe", "--frames", "400", "--encoder", "pixels=pixels", "--encoder"])
        .arg(format!("enc={}", enc.with_extension("safetensors").display()))
        .arg("--dataset")
        .arg(dataset())
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    let table = std::fs::read_to_string(out.with_extension("md")).unwrap();
    assert!(table.lines().any(|l| l.starts_with("| pixels |")) && table.lines().any(|l| l.starts_with("| enc |")));
    let report: Value = serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap()).unwrap();
    for p in report["probes"].as_array().unwrap() {
        for k in ["category_targets_and_person", "category_person", "facing_side_accuracy"] {
            assert!(p[k].as_f64().is_some_and(|x| (0.0..=1.0).contains(&x)), "{k}: {p}");
        }
        assert!(p["facing_error_deg"].as_f64().is_some_and(|x| (0.0..=180.0).contains(&x)), "{p}");
    }
    assert!(!out.with_extension("frames").exists(), "the probe frames are removed");
    fails_naming(
        &["encoder", "probe", "--encoder", "x=/nonexistent/e.safetensors"],
        &out,
        "/nonexistent/e.safetensors",
    );
}

/// `orchestrator ARGS --out OUT` fails with one error naming `what`.
fn fails_naming(args: &[&str], out: &Path, what: &str) {
    let bad = Command::new(bin("orchestrator")).args(args).arg("--out").arg(out).output().unwrap();
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && stderr.contains(what), "{stderr}");
}

/// A short `orchestrator up` on the frozen encoder: the learner loads the weights, stores
/// features when acting, runs PPO updates on them, and the run ends cleanly.
#[test]
fn a_short_run_trains_on_the_frozen_encoder() {
    let _one_at_a_time = serial();
    let dir = tempfile::tempdir().unwrap();
    let enc = dir.path().join("enc");
    pretrain(&enc, 5, 2);
    let cfg = dir.path().join("frozen.toml");
    let text = format!(
        "[run]\nmethod = \"both\"\nseed = 7\ndataset = \"{}\"\n\n[env]\nenvs_per_worker = 2\nwidth = 64\nheight = 64\n\n\
         [model]\nencoder = \"pretrained\"\nencoder_weights = \"{}\"\nhidden = 32\ngru_layers = 1\n\n[ppo]\nrollout = 16\n",
        dataset().display(),
        enc.with_extension("safetensors").display()
    );
    std::fs::write(&cfg, text).unwrap();
    let mut run = Run::start(
        &dir.path().join("run"),
        &["--workers", "2", "--config", cfg.to_str().unwrap(), "--frames", "300", "--check"],
    );
    let status = run.wait(Duration::from_secs(300));
    assert!(status.success(), "{status}\n{}", run.diagnostics());
    let log = std::fs::read_to_string(run.dir.join("logs/learner.log")).unwrap();
    assert!(log.contains("pretrained RGB-D encoder"), "{}", run.diagnostics());
    let updates = std::fs::read_to_string(run.dir.join("metrics.jsonl")).unwrap_or_default();
    assert!(updates.lines().count() >= 2, "PPO updates on stored features\n{}", run.diagnostics());
}
