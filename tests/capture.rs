//! `orchestrator gesture capture` end to end, through the real landmark model (MediaPipe, which
//! scripts/setup.sh installs): the avatar's gestures filmed and captured back point where the
//! originals did, so does the real GOND recording, the captured files replay, and bad videos get
//! one line each.

use std::path::Path;
use std::process::Command;

use gesthor_tests::{bin, capture_ready, dataset, repo_root};
use serde_json::Value;

/// Median error bound (degrees) of the recovered shoulder→wrist line during the hold. Measured
/// (docs/bench/log.md, "Gesture capture"): a median of 16.5° over 12 filmed dataset gestures (4.5–34°
/// each; 13.8° from the landmarks alone: most of it is the landmark model's depth) and 16.2° on
/// the GOND recording; the test dataset's first 4 gestures: 11.9, 16.0, 22.1, 22.9° (median
/// 19.1°). 25° leaves room for that spread without admitting a lost or wrong arm (≥ 40°).
pub(crate) const BOUND_DEG: f64 = 25.0;

/// The real GOND recording (the repository's copy of reference/gond-sample).
fn gond_sample() -> std::path::PathBuf {
    repo_root().join("worker/tests/fixtures/gond-sample/2021-05-04_13-22-28_mocap.json")
}

fn orchestrator(args: &[&str]) -> std::process::Output {
    Command::new(bin("orchestrator")).args(args).output().unwrap()
}

#[test]
fn filmed_gestures_and_the_gond_recording_come_back_pointing_the_same_way() {
    if !capture_ready() {
        return;
    }
    // the landmark model on many films: alone, not beside the browser's webcam tests
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bench");
    let (data, sample) = (dataset(), gond_sample());
    let o = orchestrator(&[
        "bench",
        "capture",
        "--programs",
        "4",
        "--dataset",
        &data.display().to_string(),
        "--recording",
        &sample.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows: Vec<Value> = serde_json::from_str(&std::fs::read_to_string(out.join("capture.json")).unwrap()).unwrap();
    assert_eq!(rows.len(), 5);
    assert!(rows.iter().all(|r| r["arm_found"] == true), "{rows:#?}");
    let mut errs: Vec<f64> = rows[..4].iter().map(|r| r["captured_deg"].as_f64().unwrap()).collect();
    errs.sort_by(f64::total_cmp);
    let median = (errs[1] + errs[2]) / 2.0;
    assert!(median < BOUND_DEG, "median of the filmed gestures {median:.1}° ({errs:?})");
    let gond = rows[4]["captured_deg"].as_f64().unwrap();
    assert!(gond < BOUND_DEG, "the GOND recording: {gond:.1}°");

    // a capture writes the recorder's files, which replay
    let cap = tmp.path().join("cap");
    let o = orchestrator(&[
        "gesture",
        "capture",
        &out.join("00/frames").display().to_string(),
        "--fps",
        "30",
        "--program",
        "val:1",
        "--dataset",
        &data.display().to_string(),
        "--name",
        "mine",
        "--out",
        &cap.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["mine.json", "motions/mine.csv", "mine.bvh", "landmarks.jsonl"] {
        assert!(cap.join(f).is_file(), "no {f}");
    }
    let o = orchestrator(&[
        "replay",
        &cap.join("mine.json").display().to_string(),
        "--dataset",
        &data.display().to_string(),
        "--every",
        "25",
        "--out",
        &tmp.path().join("replay").display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// One line on stderr, naming the source, and a failure.
fn one_line_error(source: &Path, data: &Path) -> String {
    let out = source.with_extension("out");
    let o = orchestrator(&[
        "gesture",
        "capture",
        &source.display().to_string(),
        "--dataset",
        &data.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.starts_with("[capture]")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains(&*source.display().to_string()), "{err}");
    lines[0].to_string()
}

#[test]
fn bad_videos_get_one_line_each() {
    if !capture_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset();
    // an empty floor: no person
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let grey = image::RgbImage::from_pixel(320, 240, image::Rgb([120, 120, 110]));
    for i in 0..40 {
        grey.save(empty.join(format!("{i:03}.png"))).unwrap();
    }
    let e = one_line_error(&empty, &data);
    assert!(e.contains("no person found in 40 of 40 frames"), "{e}");
    // a person, but for a third of a second
    let film = tmp.path().join("film");
    let o = orchestrator(&[
        "gesture",
        "film",
        "val:0",
        "--dataset",
        &data.display().to_string(),
        "--out",
        &film.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let short = tmp.path().join("short");
    std::fs::create_dir_all(&short).unwrap();
    for i in 0..10 {
        std::fs::copy(film.join(format!("{:03}.png", 40 + i)), short.join(format!("{i:03}.png"))).unwrap();
    }
    let e = one_line_error(&short, &data);
    assert!(e.contains("10 frames") && e.contains("too short"), "{e}");
    // no such video
    let e = one_line_error(&tmp.path().join("nothing.mp4"), &data);
    assert!(e.contains("no such file"), "{e}");
}

#[test]
fn a_trained_agent_follows_a_given_gesture_from_the_cli_and_from_python() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let data = dataset();
    // a small +Both checkpoint
    let cfg = gesthor_tests::small_ppo_config(tmp.path(), "");
    let run = tmp.path().join("run");
    let o = orchestrator(&[
        "up",
        "--config",
        &cfg.display().to_string(),
        "--run-dir",
        &run.display().to_string(),
        "--workers",
        "2",
        "--frames",
        "128",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // the gesture: another program's, from the recorder's files
    let exported = tmp.path().join("exported");
    let o = orchestrator(&[
        "program",
        "export",
        "val:2",
        "--dataset",
        &data.display().to_string(),
        "--out",
        &exported.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let motion = std::fs::read_dir(exported.join("motions")).unwrap().flatten().next().unwrap().path();

    let out = tmp.path().join("follow");
    let o = orchestrator(&[
        "follow",
        "--checkpoint",
        &run.display().to_string(),
        "--program",
        "val:1",
        "--motion",
        &motion.display().to_string(),
        "--dataset",
        &data.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(said.contains("val:1") && said.contains("SR at the first stop"), "{said}");
    let r: Value = serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    let steps = r["steps"].as_u64().unwrap();
    assert!(steps >= 1 && r["spl_first_stop"].as_f64().unwrap() <= 1.0, "{r}");
    assert_eq!(r["success_first_stop"].as_bool().unwrap(), r["spl_first_stop"].as_f64().unwrap() > 0.0, "{r}");
    assert!(out.join("follow.gif").is_file() && out.join("map.png").is_file());
    // the program ran with the given gesture in place of its own
    let csv = std::fs::read_to_string(&motion).unwrap();
    let first: Vec<f64> =
        csv.lines().nth(1).unwrap().trim().split(';').take(3).map(|v| v.replace(',', ".").parse().unwrap()).collect();
    let index: Value = serde_json::from_str(&std::fs::read_to_string(out.join("dataset/val.json")).unwrap()).unwrap();
    assert_eq!(index.as_array().unwrap().len(), 1);
    let gond = std::fs::read(out.join("dataset/val.gond")).unwrap();
    let m0 = f32::from(half_f16(&gond[64..66]));
    assert!((m0 as f64 - first[0]).abs() < 1e-3, "motion {m0} vs the CSV's {}", first[0]);

    // the robot moved (turned where it starts), and moved out of the room: one line
    let start = &index[0]["robot_pos"];
    let (x, z) = (start[0].as_f64().unwrap(), start[2].as_f64().unwrap());
    let turned = tmp.path().join("turned");
    let robot = |x: f64, z: f64, out: &Path| {
        orchestrator(&[
            "follow",
            "--checkpoint",
            &run.display().to_string(),
            "--program",
            "val:1",
            "--robot",
            &x.to_string(),
            &z.to_string(),
            "90",
            "--dataset",
            &data.display().to_string(),
            "--out",
            &out.display().to_string(),
        ])
    };
    let o = robot(x, z, &turned);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let moved: Value =
        serde_json::from_str(&std::fs::read_to_string(turned.join("dataset/val.json")).unwrap()).unwrap();
    assert_eq!(moved[0]["robot_yaw"].as_f64(), Some(90.0));
    assert_eq!(moved[0]["geodesic"], index[0]["geodesic"], "the same start, the same distance");
    let o = robot(100.0, 100.0, &tmp.path().join("away"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.trim().lines().count() == 1 && err.contains("outside the room"), "{err}");

    // from Python: the same, as a dict
    let py_out = tmp.path().join("follow-py");
    let o = Command::new("python3")
        .env("PYTHONPATH", repo_root().join("python"))
        .env("GESTHOR_ORCHESTRATOR", bin("orchestrator"))
        .args([
            "-c",
            &format!(
                "import gesthor, json; r = gesthor.follow({:?}, program='val:1', motion={:?}, out={:?}, dataset={:?}); \
                 print(json.dumps(r))",
                run.display().to_string(),
                motion.display().to_string(),
                py_out.display().to_string(),
                data.display().to_string()
            ),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let py: Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    assert_eq!((py["steps"].clone(), py["success"].clone()), (r["steps"].clone(), r["success"].clone()), "{py}");
    // and one clear error from Python for a motion that is not there
    let o = Command::new("python3")
        .env("PYTHONPATH", repo_root().join("python"))
        .env("GESTHOR_ORCHESTRATOR", bin("orchestrator"))
        .args([
            "-c",
            &format!(
                "import gesthor; gesthor.follow({:?}, program='val:1', motion='nowhere.csv', out={:?})",
                run.display().to_string(),
                py_out.display().to_string()
            ),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("GestureError") && err.contains("nowhere.csv"), "{err}");
}

/// An IEEE half-precision value from two little-endian bytes.
fn half_f16(b: &[u8]) -> f32 {
    let h = u16::from_le_bytes([b[0], b[1]]);
    let (sign, exp, frac) = ((h >> 15) as i32, ((h >> 10) & 0x1f) as i32, (h & 0x3ff) as f32);
    let v = match exp {
        0 => frac / 1024.0 * 2f32.powi(-14),
        _ => (1.0 + frac / 1024.0) * 2f32.powi(exp - 15),
    };
    if sign == 1 { -v } else { v }
}
