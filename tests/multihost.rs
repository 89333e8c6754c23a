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

fn host(endpoint: &str, bundle: &std::path::Path, dir: &std::path::Path, log: &std::path::Path) -> Child {
    let out = std::fs::File::create(log).unwrap();
    Command::new(bin("orchestrator"))
        .args(["workers", "--connect", endpoint, "--workers", "1", "--certs"])
        .arg(bundle)
        .arg("--dir")
        .arg(dir)
        .stdin(Stdio::null())
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap()
}

fn hosts(args: &[&str]) -> std::process::Output {
    Command::new(bin("orchestrator")).arg("hosts").args(args).output().unwrap()
}

/// A host that must be refused: it fails with one line and never joins.
fn refused(endpoint: &str, bundle: &std::path::Path, dir: &std::path::Path) -> String {
    let out = Command::new(bin("orchestrator"))
        .args(["workers", "--connect", endpoint, "--workers", "1", "--wait", "5", "--certs"])
        .arg(bundle)
        .arg("--dir")
        .arg(dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success() && err.lines().count() == 1, "{err}");
    err
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

/// A PPO training with a local worker and two worker hosts over TLS. Refused at the transport,
/// with a line on each side and no join: a revoked host, a host of another run, and a raw Zenoh
/// peer without a certificate (which receives no frame while the hosts stream); a peer with a
/// host's certificate may not subscribe to frames. The hosts'
/// frames reach the learner; kill -9 of one leaves the learner training on; started again it
/// gets its slot back under a new generation. A third host issued mid-run makes the learner
/// reopen its listener: the two hosts wait for it and train on. Revoking the first host mid-run
/// ends it and frees its slot, the second trains on. At the end nothing corrupt or duplicated reached PPO and the
/// hosts' processes are gone.
#[test]
fn worker_hosts_join_over_tls_die_come_back_and_are_revoked() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let cfg = small_ppo_config(t, "");
    let endpoint = format!("tls/127.0.0.1:{}", free_port());
    let args = [
        "--workers",
        "1",
        "--remote-workers",
        "2",
        "--listen",
        endpoint.as_str(),
        "--config",
        cfg.to_str().unwrap(),
        "--seconds",
        "900",
        "--report-every",
        "0.3",
    ];
    let run_dir = t.join("run");
    let mut run = Run::start(&run_dir, &args);
    run.wait_progress(Duration::from_secs(120), "the local worker", |p| p["workers_seen"].as_u64() >= Some(1));
    let run_s = run_dir.to_str().unwrap();
    for name in ["one", "two", "gone"] {
        let out = hosts(&["issue", "--run", run_s, name, "--out", t.join(name).to_str().unwrap()]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains("--certs gesthor-"));
    }
    assert!(hosts(&["revoke", "--run", run_s, "gone"]).status.success());
    // another run's bundle: its own learner, its own host
    let other = t.join("other-run");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(run_dir.join("run.json"), other.join("run.json")).unwrap();
    std::fs::write(other.join("secret"), std::fs::read_to_string(run_dir.join("secret")).unwrap()).unwrap();
    orchestrator::remote::certs::learner_files(&other, &run.run_id()).unwrap();
    orchestrator::remote::certs::issue(&other, "one", &t.join("other")).unwrap();
    // let the learner reopen with its new trust
    run.wait_output(Duration::from_secs(30), "trusted hosts now: one, two (revoked: gone)");

    for (bundle, why) in [("gone", "revoked"), ("other", "another run's")] {
        let err = refused(&endpoint, &t.join(bundle), &t.join(format!("{bundle}-host")));
        assert!(err.contains("certificate"), "{why}: {err}");
    }
    let out = run.output();
    assert!(out.matches("refused a TLS connection").count() >= 2, "{}", run.diagnostics());
    assert!(!out.contains("joined"), "{}", run.diagnostics());

    let host_dir = t.join("one-host");
    let mut h = host(&endpoint, &t.join("one"), &host_dir, &t.join("host1.log"));
    let two_dir = t.join("host-two");
    let mut h2 = host(&endpoint, &t.join("two"), &two_dir, &t.join("two.log"));
    let p = run.wait_progress(Duration::from_secs(120), "frames from the remote workers", |p| {
        p["workers_seen"] == 3 && p["workers_live"] == 3 && p["frames"].as_u64() > Some(0)
    });
    // A Zenoh peer without a certificate, pointed at the port while frames flow, gets none.
    let raw =
        orchestrator::remote::session(&[], std::slice::from_ref(&endpoint), &orchestrator::remote::Security::Insecure);
    if let Ok(raw) = raw {
        let sub = zenoh::Wait::wait(raw.declare_subscriber("gesthor/**")).unwrap();
        std::thread::sleep(Duration::from_secs(3));
        assert!(sub.try_recv().unwrap().is_none(), "a peer without a certificate received a sample");
    }
    // A peer with a host's own certificate may not subscribe to observations (Zenoh's access
    // control): it sees no frame of any slot, while the answers a host may read reach it.
    let (files, _) = orchestrator::remote::certs::host_files(&t.join("two")).unwrap();
    let as_host = orchestrator::remote::Security::Tls { files, access: None };
    let spy = orchestrator::remote::session(&[], std::slice::from_ref(&endpoint), &as_host).unwrap();
    let sub = zenoh::Wait::wait(spy.declare_subscriber(format!("gesthor/{}/obs/*", run.run_id()))).unwrap();
    // what a host may read (the learner's answers) does arrive: the spy is connected
    let answers = zenoh::Wait::wait(spy.declare_subscriber(format!("gesthor/{}/act/*", run.run_id()))).unwrap();
    // (its TLS handshake and Zenoh's routing can take longer than a moment on a loaded machine:
    // wait for the first answer, then give the frames the same 3 s as before to arrive or not)
    assert!(answers.recv_timeout(Duration::from_secs(60)).unwrap().is_some(), "the spy never connected");
    std::thread::sleep(Duration::from_secs(3));
    assert!(sub.try_recv().unwrap().is_none(), "a host's certificate read another slot's frames");
    drop((sub, answers));
    zenoh::Wait::wait(spy.close()).unwrap();
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
        p["frames"].as_u64() > Some(frames + 300) && p["workers_live"] == 2
    });
    let mut h = host(&endpoint, &t.join("one"), &host_dir, &t.join("host2.log"));
    run.wait_progress(Duration::from_secs(120), "the host back in its slot", |p| {
        p["workers_live"] == 3 && p["restarts"].as_u64() >= Some(1)
    });

    // A host issued mid-run: the learner reopens its listener, the hosts stay and train on.
    assert!(hosts(&["issue", "--run", run_s, "three", "--out", t.join("three").to_str().unwrap()]).status.success());
    run.wait_output(Duration::from_secs(30), "trusted hosts now: one, three, two");
    let p = run.wait_progress(Duration::from_secs(60), "frames", |p| p["frames"].as_u64() > Some(0));
    run.wait_progress(Duration::from_secs(120), "both hosts after the reopen", |q| {
        q["workers_live"] == 3 && q["frames"].as_u64() > Some(p["frames"].as_u64().unwrap() + 300)
    });

    // Revoked mid-run: the first host is refused and ends, its slot is freed, the second stays.
    assert!(hosts(&["revoke", "--run", run_s, "one"]).status.success());
    let hs = wait_exit(&mut h, Duration::from_secs(90));
    let log1 = std::fs::read_to_string(t.join("host2.log")).unwrap();
    assert!(!hs.success() && log1.contains("revoked"), "{hs}: {log1}");
    run.wait_output(Duration::from_secs(60), "did not come back after the reopen");
    let p = run.wait_progress(Duration::from_secs(60), "the second host alone", |p| p["workers_live"] == 2);
    run.wait_progress(Duration::from_secs(120), "frames after the revocation", |q| {
        q["frames"].as_u64() > Some(p["frames"].as_u64().unwrap() + 300)
    });

    run.signal(Signal::SIGINT);
    let status = run.wait(Duration::from_secs(120));
    assert_eq!(status.code(), Some(130), "{}", run.diagnostics());
    // the learner's SHUTDOWN reached the remote worker: the host ends by itself
    let hs = wait_exit(&mut h2, Duration::from_secs(60));
    let log2 = std::fs::read_to_string(t.join("two.log")).unwrap();
    assert!(hs.success(), "{hs}: {log2}");

    let s = run.summary();
    let tot = &s["totals"];
    assert_eq!((tot["corrupt"].as_u64(), tot["duplicates"].as_u64()), (Some(0), Some(0)), "{s}");
    let remote = &s["workers"][1];
    assert!(remote["generation"].as_u64() > Some(0) && remote["messages"].as_u64() > Some(0), "{s}");
    assert!(run.output().contains("a worker host left"), "{}", run.diagnostics());
    for d in [&host_dir, &two_dir] {
        assert!(processes_mentioning(d.to_str().unwrap()).is_empty());
    }
}

/// Plain TCP only when asked for, and then with a warning; TLS needs a bundle.
#[test]
fn plain_tcp_needs_insecure_and_tls_needs_a_bundle() {
    let o = Command::new(bin("orchestrator"))
        .args(["up", "--workers", "1", "--remote-workers", "1", "--listen", "tcp/127.0.0.1:7447"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.lines().count() == 1 && err.contains("--insecure"), "{err}");
    let o = Command::new(bin("orchestrator")).args(["workers", "--connect", "tls/127.0.0.1:7447"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.lines().count() == 1 && err.contains("--certs"), "{err}");
    let o = Command::new(bin("orchestrator")).args(["workers", "--connect", "tcp/127.0.0.1:7447"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--insecure"), "{err}");
}
