#!/usr/bin/env python3
"""What the robot's camera loses: a `robot sim` run against a node on `--gesture camera` (or
`skeleton`, with `--label skeleton`),
broken down by what the camera read of the person (each episode's camera.json), beside the
same programs with the true gesture (an `eval` run's normal/episodes.jsonl, or a `robot sim`
run). Prints Markdown tables (docs/robot.md).

    python3 scripts/robot_camera_report.py CAMERA_RUN... --truth EVAL_OR_SIM_RUN [--label skeleton]

Several CAMERA_RUNs (pairs of node and simulator that shared the programs) read as one.
"""

import argparse
import json
import statistics
import sys
from pathlib import Path


def camera_episodes(runs):
    """Per program index: (success at the first stop, SPL, DTS, camera.json)."""
    out = {}
    for d in sorted(e for run in runs for e in Path(run).glob("episode-*")):
        ep, cam = d / "episode.json", d / "camera.json"
        if not ep.is_file():
            continue  # under way
        e = json.loads(ep.read_text())
        if not cam.is_file():
            sys.exit(f"{cam}: missing (was the node on --gesture camera or skeleton?)")
        p = int(e["program"].split(":")[1])
        if p in out:
            sys.exit(f"{d}: {e['program']} is recorded twice")
        out[p] = (e["success"], e["spl"], e["dts"], json.loads(cam.read_text()))
    return out


def truth_episodes(run):
    """Per program index: success at the first stop."""
    run = Path(run)
    jsonl = run / "normal" / "episodes.jsonl"
    if jsonl.is_file():
        out = {}
        for line in jsonl.read_text().splitlines():
            e = json.loads(line)
            out[e["program"]] = bool(e["stops"]) and e["stops"][0]["success"]
        return out
    return {int(e["program"].split(":")[1]): e["success"] for e in camera_like(run)}


def camera_like(run):
    for d in sorted(run.glob("episode-*")):
        if (d / "episode.json").is_file():
            yield json.loads((d / "episode.json").read_text())


def pct(n, d):
    return f"{100 * n / d:.1f}" if d else ""


def row(name, programs, cam, truth):
    n = len(programs)
    sr = sum(cam[p][0] for p in programs)
    spl = sum(cam[p][1] for p in programs)
    paired = [p for p in programs if p in truth]
    true_sr = sum(truth[p] for p in paired)
    loss = f"{100 * (true_sr - sum(cam[p][0] for p in paired)) / len(paired):.1f}" if paired else ""
    return f"| {name} | {n} | {pct(sr, n)} | {pct(spl, n)} | {pct(true_sr, len(paired))} | {loss} |"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("camera_runs", nargs="+", metavar="camera_run")
    ap.add_argument("--truth", required=True, help="an eval run (normal/episodes.jsonl) or a robot sim run")
    ap.add_argument("--label", default="camera", help="how the node read the person, for the table's columns")
    a = ap.parse_args()
    cam, truth = camera_episodes(a.camera_runs), truth_episodes(a.truth)
    if not cam:
        sys.exit(f"{' '.join(a.camera_runs)}: no finished episodes")
    c = {p: v[3] for p, v in cam.items()}
    every = sorted(cam)
    read = [p for p in every if c[p]["read"]]
    right = [p for p in read if c[p]["arm_read"] == c[p]["arm"]]
    groups = [
        ("every episode", every),
        ("no gesture read", [p for p in every if not c[p]["read"]]),
        ("a gesture read", read),
        ("… with the other arm", [p for p in read if c[p]["arm_read"] != c[p]["arm"]]),
        ("… its line to the target within 15° of GOND's", [p for p in right if c[p]["arm_error_read"] - c[p]["arm_error"] < 15]),
        ("… its line 15° or more worse than GOND's", [p for p in right if c[p]["arm_error_read"] - c[p]["arm_error"] >= 15]),
        ("person in view at the start (within 45°)", [p for p in every if c[p]["bearing"] < 45]),
        ("person out of view at the start", [p for p in every if c[p]["bearing"] >= 45]),
        ("person nearer than 2.5 m", [p for p in every if c[p]["distance"] < 2.5]),
        ("person 2.5 m or farther", [p for p in every if c[p]["distance"] >= 2.5]),
        ("person facing the robot (within 45°)", [p for p in every if c[p]["turned"] < 45]),
        ("person turned 45° or more away", [p for p in every if c[p]["turned"] >= 45]),
    ]
    n = len(every)
    print(
        f"{n} episodes: SR {pct(sum(cam[p][0] for p in every), n)}, SPL {pct(sum(cam[p][1] for p in every), n)}, "
        f"DTS {statistics.mean(cam[p][2] for p in every):.3f} (the row of the first table)"
    )
    print()
    print(f"| episodes | n | SR 1 {a.label} (%) | SPL 1 {a.label} (%) | SR 1 true gesture (%) | lost (points) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, programs in groups:
        print(row(name, programs, cam, truth))
    print()
    med = lambda k, ps: statistics.median(c[p][k] for p in ps) if ps else float("nan")
    print(
        f"Of {len(read)} gestures read: the person placed {med('place_error', read):.2f} m and "
        f"{med('facing_error', read):.1f}° off (medians); the arm's line {med('arm_error_read', right):.1f}° "
        f"from the target where GOND's clip is {med('arm_error', right):.1f}° (medians, the arm read right); "
        f"GOND's gesture accuracy {med('accuracy_read', read):.2f} read, {med('accuracy', read):.2f} GOND's."
    )
    print()
    print("| interventions | decisions shown | person in the frame | read as a wave | % of those in the frame |")
    print("|---|---:|---:|---:|---:|")
    for name, keep in [("waves", lambda i: i.startswith("wave")), ("the others", lambda i: not i.startswith("wave"))]:
        ps = [p for p in every if keep(c[p]["intervention"])]
        shown, seen, got = (sum(c[p][k] for p in ps) for k in ("waves", "waves_in_view", "waves_read"))
        print(f"| {name} | {shown} | {seen} | {got} | {pct(got, seen)} |")
    false = sum(c[p]["false_waves"] for p in every)
    print(f"\nA wave read where none was shown: {false} decision{'' if false == 1 else 's'}.")


if __name__ == "__main__":
    main()
