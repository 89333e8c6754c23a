//! Two hosts on one machine: the learner's (`up --listen`, one local worker) and a worker host
//! (`orchestrator workers --connect`, its own shared-memory domain), Zenoh over 127.0.0.1 with
//! multicast scouting off. Traffic stays on loopback.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gesthor_tests::*;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

/// A port nobody listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn host(endpoint: &str, run_id: &str, secret: &str, dir: &std::path::Path, log: &std::path::Path) -> Child {
    let out = std::fs::File::create(log).unwrap();
    Command::new(bin("orchestrator"))
        .args(["workers", "--connect", endpoint, "--run-id", run_id, "--secret", secret, "--workers", "1", "--dir"])
        .arg(dir)
        .stdin(Stdio::null())
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap()
}

fn wait_exit(c: &mut Child, limit: Duration) -> std::process::ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(s) = c.try_wait().unwrap() {
            return s;
        }
        assert!(t.elapsed() < limit, "still running after {limit:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A PPO training with a local and a remote worker: a host with the wrong secret is refused
/// (a line on each side); the remote worker's frames reach the learner; kill -9 of the worker
/// host leaves the learner training on its local worker; the host started again gets its slot
/// back under a new generation; at the end nothing corrupt or duplicated reached PPO and the
/// host's processes are gone.
#[test]
fn a_worker_host_joins_over_zenoh_dies_and_comes_back() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = small_ppo_config(tmp.path(), "");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let args = [
        "--workers",
        "1",
        "--remote-workers",
        "1",
        "--listen",
        endpoint.as_str(),
        "--secret",
        "right",
        "--config",
        cfg.to_str().unwrap(),
        "--seconds",
        "600",
        "--report-every",
        "0.3",
    ];
    let mut run = Run::start(&tmp.path().join("run"), &args);
    run.wait_progress(Duration::from_secs(120), "the local worker", |p| p["workers_seen"].as_u64() >= Some(1));
    let run_id = run.run_id();
    let host_dir = tmp.path().join("host");

    let bad = Command::new(bin("orchestrator"))
        .args(["workers", "--connect", &endpoint, "--run-id", &run_id, "--secret", "wrong", "--dir"])
        .arg(tmp.path().join("bad"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.lines().count() == 1 && err.contains("secret"), "{err}");
    assert!(run.output().contains("refused a worker host: host"), "{}", run.diagnostics());

    let mut h = host(&endpoint, &run_id, "right", &host_dir, &tmp.path().join("host1.log"));
    let p = run.wait_progress(Duration::from_secs(120), "frames from the remote worker", |p| {
        p["workers_seen"] == 2 && p["workers_live"] == 2
    });
    let frames = p["frames"].as_u64().unwrap();
    kill(Pid::from_raw(h.id() as i32), Signal::SIGKILL).unwrap();
    h.wait().unwrap();
    // its worker follows its parent (parent-death signal)
    let gone = Instant::now();
    while !processes_mentioning(host_dir.to_str().unwrap()).is_empty() {
        assert!(gone.elapsed() < Duration::from_secs(10), "the host's worker outlived it");
        std::thread::sleep(Duration::from_millis(100));
    }
    run.wait_progress(Duration::from_secs(120), "training on without the host", |p| {
        p["frames"].as_u64() > Some(frames + 300) && p["workers_live"] == 1
    });

    let mut h = host(&endpoint, &run_id, "right", &host_dir, &tmp.path().join("host2.log"));
    run.wait_progress(Duration::from_secs(120), "the host back in its slot", |p| {
        p["workers_live"] == 2 && p["restarts"].as_u64() >= Some(1)
    });
    run.signal(Signal::SIGINT);
    let status = run.wait(Duration::from_secs(120));
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    // the learner's SHUTDOWN reached the remote worker: the host ends by itself
    let hs = wait_exit(&mut h, Duration::from_secs(60));
    let host_log = std::fs::read_to_string(tmp.path().join("host2.log")).unwrap();
    assert!(hs.success(), "{hs}: {host_log}");

    let s = run.summary();
    let t = &s["totals"];
    assert_eq!((t["corrupt"].as_u64(), t["duplicates"].as_u64()), (Some(0), Some(0)), "{s}");
    let remote = &s["workers"][1];
    assert!(remote["generation"].as_u64() > Some(0) && remote["messages"].as_u64() > Some(0), "{s}");
    assert!(run.output().contains("a worker host left"), "{}", run.diagnostics());
    assert!(processes_mentioning(host_dir.to_str().unwrap()).is_empty());
}
