//! `orchestrator robot` on ROS 2: the node closed-loop with GesTHOR published as a ROS 2 robot
//! (`robot sim`) over DDS, and the node with an independent DDS implementation (Cyclone DDS,
//! from Python) as its robot, holding still on bad and stale input.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use farm::stepper::PayloadBuf;
use gesthor_tests::{bin, default_dataset, python_with, repo_root, serial};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;
use shm_schema::{ObsShape, ObsView};
use worker::env::{EnvPool, PoolSpec, ProgramSource};

/// A DDS domain of this test process's own (`offset` tells a test's apart), so that runs of
/// the suite beside each other never hear one another.
fn domain(offset: u32) -> String {
    (100 + (std::process::id() * 2 + offset) % 130).to_string()
}

/// `orchestrator robot` on `models/both`, stopped by SIGINT when dropped.
struct Node(Child, PathBuf);

impl Node {
    fn start(dir: &Path, args: &[&str]) -> Node {
        let log = dir.join("node.log");
        let child = Command::new(bin("orchestrator"))
            .arg("robot")
            .arg("--checkpoint")
            .arg(repo_root().join("models/both"))
            .args(args)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        Node(child, log)
    }

    /// Ctrl-C: the node stops the base and exits cleanly; its log.
    fn stop(mut self) -> String {
        kill(Pid::from_raw(self.0.id() as i32), Signal::SIGINT).unwrap();
        let status = self.0.wait().unwrap();
        let log = std::fs::read_to_string(&self.1).unwrap();
        assert!(status.success(), "the node exited with {status} on Ctrl-C:\n{log}");
        log
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn lines(path: &Path) -> Vec<Value> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// Every recorded step's pose follows from the action before it, as the grid would move it:
/// 0.25 m ahead (none when blocked), or 15° either way.
fn check_path(steps: &[Value], episode: &Path) {
    for pair in steps.windows(2) {
        let pose =
            |s: &Value| -> Vec<f64> { s["robot"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect() };
        let (a, b) = (pose(&pair[0]), pose(&pair[1]));
        let moved = (b[0] - a[0]).hypot(b[1] - a[1]);
        let turned = ((b[2] - a[2] + 540.0) % 360.0) - 180.0;
        let ok = match pair[0]["action"].as_u64().unwrap() {
            0 => ((moved - 0.25).abs() < 0.03 || moved < 0.03) && turned.abs() < 1.5,
            1 => moved < 0.01 && (turned + 15.0).abs() < 1.0,
            2 => moved < 0.01 && (turned - 15.0).abs() < 1.0,
            a => panic!("{}: action {a} before the episode's end", episode.display()),
        };
        assert!(
            ok,
            "{}: after action {} the robot moved {moved:.3} m and turned {turned:.2}°",
            episode.display(),
            pair[0]["action"]
        );
    }
}

#[test]
fn the_node_drives_gesthors_robot_closed_loop_each_episode_is_judged_and_a_stopped_run_goes_on() {
    let _s = serial();
    let out = tempfile::tempdir().unwrap();
    let d = domain(0);
    let node = Node::start(out.path(), &["--domain", &d, "--use-sim-time"]);
    let sim = Command::new(bin("orchestrator"))
        .args(["robot", "sim", "--checkpoint"])
        .arg(repo_root().join("models/both"))
        .arg("--dataset")
        .arg(default_dataset())
        .args(["--programs", "val:0-2", "--gifs", "1", "--domain", &d, "--out"])
        .arg(out.path().join("sim"))
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&sim.stderr);
    assert!(sim.status.success(), "robot sim failed:\n{said}");
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("sim/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["episodes"], 3, "{summary}");
    for n in 1..=3 {
        let dir = out.path().join(format!("sim/episode-{n:03}"));
        let steps = lines(&dir.join("steps.jsonl"));
        let episode: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("episode.json")).unwrap()).unwrap();
        assert_eq!(episode["program"], format!("val:{}", n - 1));
        assert_eq!(episode["steps"].as_u64().unwrap() as usize, steps.len(), "{}", dir.display());
        let last = steps.last().unwrap()["action"].as_u64().unwrap();
        assert!(last == 3 || steps.len() == 100, "{}: the episode ended on action {last}", dir.display());
        assert!(dir.join("dataset/manifest.json").is_file(), "{}: no GOND files", dir.display());
        check_path(&steps, &dir);
        // the person kept pointing (referencing) or called the robot back (intervention)
        assert!(steps.iter().all(|s| s["shown"] == 1 || s["shown"] == 2));
        // the first episode drawn (`--gifs 1`), the others not
        let gif = std::fs::read(dir.join("episode.gif")).ok();
        assert_eq!(gif.as_ref().map(|g| g.starts_with(b"GIF89a")), (n == 1).then_some(true), "{}", dir.display());
    }
    // a run stopped in its third episode goes on from there with the same command
    let first = std::fs::read(out.path().join("sim/episode-001/steps.jsonl")).unwrap();
    std::fs::remove_file(out.path().join("sim/episode-003/episode.json")).unwrap();
    std::fs::remove_file(out.path().join("sim/summary.json")).unwrap();
    let again = |programs: &str| {
        Command::new(bin("orchestrator"))
            .args(["robot", "sim", "--checkpoint"])
            .arg(repo_root().join("models/both"))
            .arg("--dataset")
            .arg(default_dataset())
            .args(["--programs", programs, "--domain", &d, "--out"])
            .arg(out.path().join("sim"))
            .output()
            .unwrap()
    };
    let sim = again("val:0-2");
    let said = String::from_utf8_lossy(&sim.stderr);
    assert!(sim.status.success(), "robot sim failed on going on:\n{said}");
    assert!(said.contains("2 of 3 episodes already recorded"), "{said}");
    assert!(said.contains("val:2: ") && !said.contains("val:0: "), "{said}");
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("sim/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["episodes"], 3, "{summary}");
    assert_eq!(std::fs::read(out.path().join("sim/episode-001/steps.jsonl")).unwrap(), first);
    // other programs into the same folder: one clear error, nothing overwritten
    let sim = again("val:1-2");
    let said = String::from_utf8_lossy(&sim.stderr);
    assert!(!sim.status.success() && said.contains("give another --out"), "{said}");
    assert_eq!(std::fs::read(out.path().join("sim/episode-001/steps.jsonl")).unwrap(), first);
    let log = node.stop();
    assert!(log.contains("episode 4 ended"), "{log}");
}

/// val:2 with the node reading the person by `gesture` (`camera`, `skeleton`): the node's log
/// and what it read beside the truth (`camera.json`). The person stands 2 m away, turned 40°
/// from the robot, and points with their left arm.
fn read_val2(gesture: &str, offset: u32) -> (String, Value) {
    let _s = serial();
    let out = tempfile::tempdir().unwrap();
    let d = domain(offset);
    let node = Node::start(out.path(), &["--domain", &d, "--use-sim-time", "--gesture", gesture, "--greedy"]);
    let sim = Command::new(bin("orchestrator"))
        .args(["robot", "sim", "--checkpoint"])
        .arg(repo_root().join("models/both"))
        .arg("--dataset")
        .arg(default_dataset())
        .args(["--programs", "val:2", "--camera-rate", "15", "--animate", "time", "--domain", &d, "--out"])
        .arg(out.path().join("sim"))
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&sim.stderr);
    assert!(sim.status.success(), "robot sim failed:\n{said}");
    let log = node.stop();
    let read = std::fs::read_to_string(out.path().join("sim/episode-001/camera.json")).unwrap();
    (log, serde_json::from_str(&read).unwrap())
}

fn num(read: &Value, k: &str) -> f64 {
    read[k].as_f64().unwrap_or_else(|| panic!("{k}: {read}"))
}

#[test]
fn the_node_reads_the_persons_pointing_through_its_own_camera() {
    let (log, read) = read_val2("camera", 2);
    assert!(log.contains("the person's gesture read (left arm"), "{log}");
    assert_eq!((&read["arm"], &read["arm_read"]), (&Value::from("Left"), &Value::from("Left")), "{read}");
    // where they stand and face, as the depth under their hips puts them
    assert!(num(&read, "place_error") < 0.3 && num(&read, "facing_error") < 20.0, "{read}");
    // the arm read points near where GOND's does: the clip starts at rest, whole
    assert!(num(&read, "arm_error_read") < 25.0, "{read}");
}

#[test]
fn the_node_reads_the_persons_pointing_from_a_body_trackers_skeletons() {
    // the simulator publishes its person's joints as a REP-155 tracker would
    let (log, read) = read_val2("skeleton", 4);
    assert!(log.contains("the person's gesture read (left arm"), "{log}");
    assert_eq!(read["arm_read"], Value::from("Left"), "{read}");
    // the depth under a keypoint is the body's surface, not its joint: 25° off in facing and
    // in the arm's line here (measured at d681747)
    assert!(num(&read, "place_error") < 0.3 && num(&read, "facing_error") < 35.0, "{read}");
    assert!(num(&read, "arm_error_read") < 35.0, "{read}");
}

/// The first camera frame of val:0 as GesTHOR renders it at 640×480, its person's gesture and
/// pose: what the Cyclone DDS robot publishes.
fn write_frames(dir: &Path) {
    let mut cfg = farm::config::RunConfig::load(&repo_root().join("models/both/config.toml")).unwrap();
    cfg.run.dataset = default_dataset();
    cfg.run.split = worker::scene::Split::Val;
    cfg.run.scenes.clear();
    cfg.run.max_programs = None;
    (cfg.env.width, cfg.env.height, cfg.env.envs_per_worker) = (640, 480, 1);
    let spec =
        PoolSpec { worker_id: 0, generation: 0, programs: ProgramSource::Sequence(vec![0]), expert_hints: false };
    let mut pool = EnvPool::new(&cfg, spec).unwrap();
    let shape = ObsShape::new(1, 640, 480);
    let mut buf = PayloadBuf::new(&pool.layout());
    pool.reset(buf.bytes_mut()).unwrap();
    let view = ObsView::new(shape, &buf.bytes()[..shape.layout.total_len as usize]).unwrap();
    std::fs::write(dir.join("rgb.bin"), view.rgb(0)).unwrap();
    let mm: Vec<u8> = view.depth(0).iter().flat_map(|&v| worker::camera::depth_mm(v).to_le_bytes()).collect();
    std::fs::write(dir.join("depth.bin"), mm).unwrap();
    let env = pool.env(0).unwrap();
    let muscles: Vec<u8> = env.perceived().unwrap().as_flat().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("gesture.bin"), muscles).unwrap();
    let p = &env.program;
    let (x, y, yaw) =
        orchestrator::commands::robot::sim::floor_pose(p.human_pos[0], p.human_pos[2], p.human_yaw).to_planar();
    let meta = serde_json::json!({"width": 640, "height": 480, "fov_deg": cfg.env.fov_deg, "target": p.target.name(), "person": [x, y, yaw]});
    std::fs::write(dir.join("meta.json"), meta.to_string()).unwrap();
}

#[test]
fn cyclone_dds_drives_the_node_which_holds_still_on_bad_and_stale_input() {
    let Ok(mut python) = python_with(&["cyclonedds", "numpy"]) else { return };
    let _s = serial();
    let dir = tempfile::tempdir().unwrap();
    write_frames(dir.path());
    let d = domain(1);
    let node = Node::start(dir.path(), &["--domain", &d]);
    let peer = python
        .arg(repo_root().join("tests/python/ros2_peer.py"))
        .args(["--domain", &d, "--seconds", "6", "--frames"])
        .arg(dir.path())
        .output()
        .unwrap();
    let log = node.stop();
    let said = String::from_utf8_lossy(&peer.stderr);
    assert!(peer.status.success(), "the Cyclone DDS robot failed:\n{said}\nthe node:\n{log}");
    let seen: Value = serde_json::from_slice(&peer.stdout).unwrap();
    let phase = |p: &str, k: &str| seen[p][k].as_u64().unwrap();
    let held =
        |p: &str, what: &str| seen[p]["holding"].as_array().unwrap().iter().any(|h| h.as_str().unwrap().contains(what));
    // good input: the node decides and drives
    assert!(phase("good", "decisions") >= 2 && phase("good", "moving_commands") > 0, "{seen}\n{log}");
    // an image of another encoding: one line why, and not one moving command after it
    assert!(held("mono8", "`mono8`"), "{seen}\n{log}");
    assert_eq!(phase("mono8", "moving_after_hold"), 0, "{seen}");
    assert!(phase("mono8", "zero_commands") > 0, "{seen}");
    // the camera gone: the same
    assert!(held("no_camera", "no colour image"), "{seen}\n{log}");
    assert_eq!(phase("no_camera", "moving_after_hold"), 0, "{seen}");
    // a gesture of another gesthor_msgs (its type's name, other fields): the same, naming the topic
    assert!(held("garbled", "/gesthor/gesture: a message that is not of its type"), "{seen}\n{log}");
    assert_eq!(phase("garbled", "moving_after_hold"), 0, "{seen}");
    // good again: it decides afresh and drives on
    assert!(phase("good_again", "decisions") >= 1 && phase("good_again", "moving_commands") > 0, "{seen}\n{log}");
    assert!(log.contains("holding still: colour image: encoding `mono8`"), "{log}");
    assert!(log.contains("input good again"), "{log}");
}
