//! `orchestrator study` end to end on a tiny study (a few hundred frames per run): it writes
//! T4.2 with every method, and a study killed mid-run continues under the same command without
//! training again what was finished or starting a resumable run over; a published study continues
//! from its records on a machine without its folder.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use gesthor_tests::{bin, dataset, processes_mentioning, serial};
use serde_json::Value;

const DEADLINE: Duration = Duration::from_secs(300);

/// both, vis_sem, random and T4.7's rgb_sem_both configs: 32×32, small CNN, 2 envs, 16-step
/// rollouts (64 frames an update with 2 workers).
fn configs(dir: &Path) -> PathBuf {
    let d = dir.join("configs");
    std::fs::create_dir_all(&d).unwrap();
    for (stem, method, inputs) in [
        ("both", "both", ""),
        ("vis_sem", "vis_sem", ""),
        ("random", "random", ""),
        ("rgb_sem_both", "both", "depth = false\n"),
    ] {
        let text = format!(
            "[run]\nmethod = \"{method}\"\nseed = 7\ndataset = \"{}\"\n\n[env]\nenvs_per_worker = 2\nwidth = 32\nheight = 32\n\n\
             [model]\nencoder = \"small_cnn\"\nhidden = 32\ngru_layers = 1\n{inputs}\n[ppo]\nrollout = 16\n",
            dataset().display()
        );
        std::fs::write(d.join(format!("{stem}.toml")), text).unwrap();
    }
    d
}

fn study(configs: &Path, out: &Path, methods: &str) -> Command {
    study_of(configs, out, methods, 256)
}

fn study_of(configs: &Path, out: &Path, methods: &str, frames: u64) -> Command {
    let mut c = Command::new(bin("orchestrator"));
    c.args(["study", "--seeds", "1", "--frames", &frames.to_string(), "--workers", "2", "--checkpoints", "2"])
        .args(["--val-programs", "8", "--test-programs", "8", "--methods", methods, "--configs"])
        .arg(configs)
        .arg("--out")
        .arg(out);
    c
}

fn mtimes(dir: &Path) -> Vec<(PathBuf, SystemTime)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| (e.path(), e.metadata().unwrap().modified().unwrap()))
        .filter(|(p, _)| p.extension().is_some_and(|e| e == "safetensors"))
        .collect();
    v.sort();
    v
}

#[test]
fn a_killed_study_continues_without_retraining() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = configs(tmp.path());
    let out = tmp.path().join("study");

    // +Both alone, to the end
    let o = study(&cfg, &out, "both").output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let both = out.join("runs/both-seed1/checkpoints");
    let finished = mtimes(&both);
    assert_eq!(finished.len(), 2, "256 frames = 4 updates, a checkpoint every 2: {finished:?}");

    // the whole study, killed once VisSem has a checkpoint
    let mut child =
        study(&cfg, &out, "both,vis_sem,random").stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    let vis_sem = out.join("runs/vis_sem-seed1/checkpoints");
    let started = Instant::now();
    while mtimes_or_empty(&vis_sem).is_empty() {
        assert!(started.elapsed() < DEADLINE, "VisSem never wrote a checkpoint");
        assert!(child.try_wait().unwrap().is_none(), "the study ended before VisSem's first checkpoint");
        std::thread::sleep(Duration::from_millis(100));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    // its `up` stops with it (SIGTERM from the kernel when its parent dies)
    while !processes_mentioning(&out.display().to_string()).is_empty() {
        assert!(started.elapsed() < DEADLINE, "the killed study's steps did not stop");
        std::thread::sleep(Duration::from_millis(100));
    }
    let first_vis_sem = mtimes(&vis_sem)[0].clone();

    // the same command continues, with T4.7's variant added
    let o = study(&cfg, &out, "both,vis_sem,random,rgb_sem_both").output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert_eq!(mtimes(&both), finished, "the finished run was trained again:\n{log}");
    assert_eq!(mtimes(&vis_sem)[0], first_vis_sem, "VisSem started over instead of resuming:\n{log}");
    // (a checkpoint more where the kill stopped it between two)
    let kept = mtimes(&vis_sem);
    assert!(kept.last().unwrap().0.ends_with("ckpt-00000004.safetensors"), "{kept:?}");
    let table = std::fs::read_to_string(out.join("T4.2.md")).unwrap();
    for row in ["| Random | 1 |", "| VisSem | 1 |", "| +Both | 1 |", "49.2 / 28.7 / 1.976", "| +Both > VisSem |"] {
        assert!(table.contains(row), "no `{row}` in\n{table}");
    }
    for png in ["sr_spl.png", "learning_curves.png"] {
        assert!(out.join(png).is_file(), "no {png}");
    }
    // the ablation tables: breakdowns of test (T4.4, T4.5), train/val/test (T4.3), the blind
    // pass (T4.6) and the separately trained variant (T4.7)
    let read = |t: &str| std::fs::read_to_string(out.join(format!("{t}.md"))).unwrap_or_else(|e| panic!("{t}.md: {e}"));
    assert!(read("T4.3").contains("| Kitchen | VisSem | all types, broken down |"), "{}", read("T4.3"));
    assert!(read("T4.4").contains("(49.3) |"), "{}", read("T4.4"));
    assert!(read("T4.5").contains("| +Both |"), "{}", read("T4.5"));
    assert!(read("T4.6").contains("| Random |") && read("T4.6").contains("| +Both |"), "{}", read("T4.6"));
    let t47 = read("T4.7");
    assert!(t47.contains("| RGB+Semantic+Both |") && t47.contains("| RGBD+Semantic+Both |"), "{t47}");
    let test = std::fs::read_to_string(out.join("runs/both-seed1/test/tables.csv")).unwrap();
    assert!(test.lines().any(|l| l.contains(",test,blind,all,all,1,")), "{test}");
    // +Both is shown the referencing gesture: also tested with another room's
    assert!(test.lines().any(|l| l.contains(",test,other_gesture,all,all,1,")), "{test}");
    assert!(read("pointing").contains("| +Both |") && !read("pointing").contains("| VisSem |"), "{}", read("pointing"));
    let results: Value = serde_json::from_str(&std::fs::read_to_string(out.join("study.json")).unwrap()).unwrap();
    assert_eq!(results.as_array().unwrap().len(), 4);
    // every evenly spaced checkpoint and the final one were evaluated on val; a checkpoint the
    // kill left between two (ckpt 3) was not: a study run through would not have it
    let mut selected: Vec<String> = std::fs::read_dir(out.join("runs/vis_sem-seed1/select"))
        .unwrap()
        .flatten()
        .filter(|e| e.path().join("tables.csv").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    selected.sort();
    assert_eq!(selected, ["ckpt-00000002", "ckpt-00000004"], "for {kept:?}\n{log}");
}

fn mtimes_or_empty(dir: &Path) -> Vec<(PathBuf, SystemTime)> {
    if dir.is_dir() { mtimes(dir) } else { vec![] }
}

#[test]
fn a_study_sent_sigterm_stops_its_running_step() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = configs(tmp.path());
    let out = tmp.path().join("study");
    // 64 frames an update: this budget is thousands of updates, far more than run before the kill
    sigterm_once_training(study_of(&cfg, &out, "vis_sem", 200_000), &out, &["vis_sem-seed1"]);
    let ckpts = out.join("runs/vis_sem-seed1/checkpoints");
    // the step stopped short of its budget (its first periodic checkpoint is half way) and wrote
    // a checkpoint to resume from
    let kept = mtimes(&ckpts);
    let last = kept.last().unwrap().0.file_name().unwrap().to_string_lossy().to_string();
    let update: u64 = last.trim_start_matches("ckpt-").trim_end_matches(".safetensors").parse().unwrap();
    assert!(update < 200_000 / 64, "{last}");
    let up_log = std::fs::read_to_string(out.join("runs/vis_sem-seed1.log")).unwrap();
    assert!(!up_log.contains("budget reached"), "the step ran to its end:\n{up_log}");
}

#[test]
fn a_published_study_continues_from_its_records_without_its_folder() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = configs(tmp.path());
    let docs = tmp.path().join("docs");
    let publish = |c: &mut Command| {
        c.arg("--publish").arg(&docs);
    };

    // +Both and Random on "this machine", published
    let first = tmp.path().join("here");
    let mut c = study(&cfg, &first, "both,random");
    publish(&mut c);
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = std::fs::read_to_string(docs.join("T4.2.md")).unwrap();
    assert_eq!(table, std::fs::read_to_string(first.join("T4.2.md")).unwrap(), "the same tables in both folders");
    for f in [
        "records/both-seed1/record.json",
        "records/both-seed1/test.csv",
        "records/both-seed1/test-episodes.csv",
        "records/both-seed1/curve.jsonl",
    ] {
        assert!(docs.join(f).is_file(), "no {f}");
    }
    // the published results name the records, inside the folder, not the run folders
    let results = std::fs::read_to_string(docs.join("study.json")).unwrap();
    assert!(
        results.contains("\"records/both-seed1/test.csv\"") && !results.contains(&*first.to_string_lossy()),
        "{results}"
    );

    // "another machine": the run folders are gone; VisSem is added
    std::fs::remove_dir_all(&first).unwrap();
    let second = tmp.path().join("there");
    let mut c = study(&cfg, &second, "both,vis_sem,random");
    publish(&mut c);
    let o = c.output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("+Both seed 1: recorded in"), "{log}");
    assert!(!second.join("runs/both-seed1").exists(), "+Both was trained again:\n{log}");
    assert!(second.join("runs/vis_sem-seed1/checkpoints").is_dir(), "VisSem was not trained:\n{log}");
    let table = std::fs::read_to_string(docs.join("T4.2.md")).unwrap();
    for row in ["| +Both | 1 |", "| VisSem | 1 |", "| Random | 1 |", "| +Both > VisSem |"] {
        assert!(table.contains(row), "no `{row}` in\n{table}");
    }
    // the ablation tables read the recorded model's tables
    assert!(std::fs::read_to_string(docs.join("T4.6.md")).unwrap().contains("| +Both |"));
    // and the pairing, program by program, reads the recorded model's test episodes
    let paired = std::fs::read_to_string(docs.join("paired.md")).unwrap();
    assert!(paired.contains("## +Both against VisSem") && paired.contains("| 1 | 1 |"), "{paired}");
    assert!(paired.contains("the gesture at the start (+Both / VisSem)"), "{paired}");

    // a study of one method publishes tables that keep every other recorded model
    let mut c = study(&cfg, &tmp.path().join("one"), "vis_sem");
    publish(&mut c);
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = std::fs::read_to_string(docs.join("T4.2.md")).unwrap();
    for row in ["| +Both | 1 |", "| VisSem | 1 |", "| Random | 1 |"] {
        assert!(table.contains(row), "no `{row}` after a VisSem-only study in\n{table}");
    }

    // a study of another budget is refused by the record, which is left as it was
    let record = std::fs::read_to_string(docs.join("records/both-seed1/record.json")).unwrap();
    let mut c = study_of(&cfg, &tmp.path().join("longer"), "both", 512);
    publish(&mut c);
    let o = c.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("both-seed1/record.json") && err.contains("field `config`"), "{err}");
    assert_eq!(std::fs::read_to_string(docs.join("records/both-seed1/record.json")).unwrap(), record);
}

/// Starts `study` (into `out`), sends it SIGTERM — the study alone, as `kill PID` does (its steps
/// run in process groups of their own) — once each of `runs` has finished an update, and checks
/// it stopped as a signal should: failing, saying how to continue, no step left running. Its log.
fn sigterm_once_training(mut study: Command, out: &Path, runs: &[&str]) -> String {
    let mut child = study.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let metrics = |name: &str| out.join("runs").join(name).join("metrics.jsonl");
    let started = Instant::now();
    while runs.iter().any(|n| std::fs::metadata(metrics(n)).map_or(0, |m| m.len()) == 0) {
        assert!(started.elapsed() < DEADLINE, "{runs:?} never all finished an update");
        assert!(child.try_wait().unwrap().is_none(), "the study ended before {runs:?} each finished an update");
        std::thread::sleep(Duration::from_millis(100));
    }
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), nix::sys::signal::Signal::SIGTERM).unwrap();
    let o = child.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "{log}");
    assert!(log.contains("stopped by a signal; run the same command again to continue"), "{log}");
    assert!(processes_mentioning(&out.display().to_string()).is_empty(), "a step outlived the study");
    log
}

/// When run `name` of study `out` started training, and when it wrote its last checkpoint.
fn trained_between(out: &Path, name: &str) -> (u64, u64) {
    let run = out.join("runs").join(name);
    let info: Value = serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).unwrap()).unwrap();
    let last = mtimes(&run.join("checkpoints")).last().unwrap().1;
    (info["started"].as_u64().unwrap(), last.duration_since(SystemTime::UNIX_EPOCH).unwrap().as_secs())
}

#[test]
fn a_parallel_study_trains_two_models_at_once_into_one_folder() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = configs(tmp.path());
    let (out, docs) = (tmp.path().join("study"), tmp.path().join("docs"));
    let o = study(&cfg, &out, "both,vis_sem").args(["--parallel", "2", "--publish"]).arg(&docs).output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("2 runs (256 frames each, 2 workers; 2 at once)"), "{log}");
    // side by side: each training started before the other had written its last checkpoint
    let (both, vis_sem) = (trained_between(&out, "both-seed1"), trained_between(&out, "vis_sem-seed1"));
    assert!(both.0 <= vis_sem.1 && vis_sem.0 <= both.1, "one after the other: {both:?} {vis_sem:?}\n{log}");
    // both finished, recorded and in the one set of tables, in the plan's order
    for name in ["both-seed1", "vis_sem-seed1"] {
        for f in ["record.json", "test.csv", "val.csv", "train.csv", "curve.jsonl"] {
            assert!(docs.join("records").join(name).join(f).is_file(), "no records/{name}/{f}\n{log}");
        }
        let info: Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("runs").join(name).join("run.json")).unwrap())
                .unwrap();
        let run_id = info["run_id"].as_str().unwrap();
        assert!(gesthor_tests::shm_leftovers(run_id).is_empty(), "{name}'s crew left shared memory");
    }
    for dir in [&out, &docs] {
        let table = std::fs::read_to_string(dir.join("T4.2.md")).unwrap();
        for row in ["| VisSem | 1 |", "| +Both | 1 |", "| +Both > VisSem |"] {
            assert!(table.contains(row), "no `{row}` in {}:\n{table}", dir.display());
        }
        let results: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("study.json")).unwrap()).unwrap();
        let stems: Vec<&str> = results.as_array().unwrap().iter().map(|r| r["stem"].as_str().unwrap()).collect();
        assert_eq!(stems, ["both", "vis_sem"], "{results}");
    }
    assert!(processes_mentioning(&out.display().to_string()).is_empty(), "a step outlived the study");

    // the same command again: everything is recorded, nothing is trained again
    let before =
        (mtimes(&out.join("runs/both-seed1/checkpoints")), mtimes(&out.join("runs/vis_sem-seed1/checkpoints")));
    let o = study(&cfg, &out, "both,vis_sem").args(["--parallel", "2", "--publish"]).arg(&docs).output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && log.matches(": recorded in").count() == 2, "{log}");
    let after = (mtimes(&out.join("runs/both-seed1/checkpoints")), mtimes(&out.join("runs/vis_sem-seed1/checkpoints")));
    assert_eq!(before, after, "{log}");
}

#[test]
fn a_parallel_study_sent_sigterm_stops_every_model_in_flight() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = configs(tmp.path());
    let out = tmp.path().join("study");
    // thousands of updates each, far more than run before the kill
    let mut study = study_of(&cfg, &out, "both,vis_sem", 200_000);
    study.args(["--parallel", "2"]);
    let log = sigterm_once_training(study, &out, &["both-seed1", "vis_sem-seed1"]);
    // each stopped short of its budget and wrote a checkpoint to resume from
    for name in ["both-seed1", "vis_sem-seed1"] {
        let kept = mtimes(&out.join("runs").join(name).join("checkpoints"));
        assert!(!kept.is_empty(), "{name} kept no checkpoint\n{log}");
        let up_log = std::fs::read_to_string(out.join("runs").join(format!("{name}.log"))).unwrap();
        assert!(!up_log.contains("budget reached"), "{name}'s step ran to its end:\n{up_log}");
    }
}
