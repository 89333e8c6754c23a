//! `orchestrator dataset stats` on a built dataset: the summary a researcher reads beside the
//! dissertation's Figs 3.8–3.12, with what the starts give away without the target.

use std::process::Command;

use gesthor_tests::{bin, dataset};

#[test]
fn stats_say_how_often_the_target_is_the_object_nearest_the_start() {
    let tmp = tempfile::tempdir().unwrap();
    let out = Command::new(bin("orchestrator"))
        .args(["dataset", "stats", "--dataset"])
        .arg(dataset())
        .arg("--out")
        .arg(tmp.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(tmp.path().join("summary.md")).unwrap();
    for fig in ["fig3_8_scene_types.png", "fig3_12a_geodesic.png"] {
        assert!(tmp.path().join(fig).is_file(), "no {fig}");
    }
    let head = "| split | target the nearest object | among the 3 nearest | median rank (1: nearest) |";
    let table = md.split(head).nth(1).unwrap_or_else(|| panic!("no nearest-object table in\n{md}"));
    let rows: Vec<Vec<&str>> = table
        .lines()
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| l.trim_matches('|').split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.iter().map(|r| r[0]).collect::<Vec<_>>(), ["train", "val", "test"], "{table}");
    for r in &rows {
        let pct = |s: &str| s.trim_end_matches('%').parse::<f64>().unwrap();
        let (nearest, three, median) = (pct(r[1]), pct(r[2]), r[3].parse::<usize>().unwrap());
        assert!((0.0..=100.0).contains(&nearest) && nearest <= three && three <= 100.0, "{r:?}");
        assert!(median >= 1, "ranks count from the nearest, 1: {r:?}");
    }
}
