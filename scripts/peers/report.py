"""One table of scripts/peers.sh's run: per trainer, end-to-end frames/s, frames/s while
collecting, the update's seconds per 4,096 frames, SR at the first stop on the val programs, and
wall time. Reads what each trainer left in OUT; writes OUT/results.md and OUT/results.json.

Usage: report.py OUT FRAMES PROGRAMS
"""

import csv
import json
import os
import re
import sys


def read_json(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def last_json_line(path):
    try:
        with open(path) as f:
            lines = [line for line in f if line.strip()]
        return json.loads(lines[-1]) if lines else None
    except (OSError, ValueError):
        return None


def ours(d):
    times = read_json(os.path.join(d, "times.json")) or {}
    farm = last_json_line(os.path.join(d, "run", "farm.jsonl")) or {}
    frames, t = farm.get("frames"), farm.get("t")
    updates = []
    try:
        with open(os.path.join(d, "run", "metrics.jsonl")) as f:
            updates = [json.loads(line)["update_seconds"] for line in f if '"update_seconds"' in line]
    except OSError:
        pass
    learner = farm.get("profile", {}).get("learner", {})
    update_total = learner.get("update_s")
    sr = n = None
    # orchestrator eval's table: SR at k stops per scene type; the first stop over all rooms
    try:
        with open(os.path.join(d, "eval", "tables.csv")) as f:
            for r in csv.DictReader(f):
                if (r["mode"], r["scene_type"], r["instances"], r["stops"]) == ("normal", "all", "all", "1"):
                    sr, n = float(r["sr"]), int(r["episodes"])
    except (OSError, KeyError, ValueError):
        pass
    return {
        "trainer": "GesTHOR farm (ours, configs/tiny/both.toml)",
        "frames": frames,
        "fps": frames / t if frames and t else None,
        "collect_fps": frames / (t - update_total) if frames and t and update_total else None,
        "update_s_per_4096": sum(updates) / len(updates) if updates else None,
        "sr_first_stop": sr,
        "eval_episodes": n,
        "train_seconds": times.get("train_s"),
        "eval_seconds": times.get("eval_s"),
    }


def cleanrl(d):
    times = read_json(os.path.join(d, "times.json")) or {}
    r = read_json(os.path.join(d, "results.json")) or {}
    ev = r.get("eval", {})
    per = r.get("update_s_per_batch")
    return {
        "trainer": "CleanRL-style PPO (scripts/peers/cleanrl_ppo.py)",
        "frames": r.get("frames"),
        "fps": r.get("fps"),
        "collect_fps": r.get("collect_fps"),
        "update_s_per_4096": per * 4096 / r["batch"] if per is not None and r.get("batch") else None,
        "sr_first_stop": ev.get("sr_first_stop"),
        "eval_episodes": ev.get("episodes"),
        "train_seconds": times.get("train_s"),
        "eval_seconds": times.get("eval_s"),
    }


def sample_factory(d):
    times = read_json(os.path.join(d, "times.json")) or {}
    ev = read_json(os.path.join(d, "eval.json")) or {}
    frames = ev.get("env_steps")
    train_s = times.get("train_s")
    update_per = None
    try:
        with open(os.path.join(d, "train.log")) as f:
            log = f.read()
        # its own count at exit: "Collected {0: FRAMES}, FPS: ..." (the env steps its learner
        # trained on, batches in flight when it stopped included)
        c = re.search(r"Collected \{0: (\d+)\}", log)
        if c:
            frames = int(c.group(1))
        # the learner's profile at exit: its seconds in `train` (every epoch and minibatch)
        i = log.find("Learner 0 profile tree view:")
        t = re.search(r"\ntrain: ([0-9.]+)", log[i : i + 2000]) if i >= 0 else None
        if t and frames:
            update_per = float(t.group(1)) * 4096 / frames
    except OSError:
        pass
    return {
        "trainer": "Sample Factory 2.1.1 APPO (scripts/peers/sf_gesthor.py)",
        "frames": frames,
        "fps": frames / train_s if frames and train_s else None,
        "collect_fps": None,  # asynchronous: collection and learning overlap, no collecting-only span
        "update_s_per_4096": update_per,
        "sr_first_stop": ev.get("sr_first_stop"),
        "eval_episodes": ev.get("episodes"),
        "train_seconds": train_s,
        "eval_seconds": times.get("eval_s"),
    }


def fmt(v, digits=0):
    if v is None:
        return "–"
    return f"{v:,.{digits}f}"


def main():
    out, frames, programs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rows = []
    for name, read in (("ours", ours), ("sf", sample_factory), ("cleanrl", cleanrl)):
        d = os.path.join(out, name)
        if os.path.isdir(d):
            rows.append({"name": name, **read(d)})
    meta = read_json(os.path.join(out, "meta.json")) or {}
    lines = [
        f"# GesTHOR: the farm and its peers, {fmt(frames)} frames each",
        "",
        f"{meta.get('date', '')}, commit {meta.get('commit', '?')}, {meta.get('cpus', '?')} CPUs "
        f"({meta.get('cpu', '')}); SR at the first stop on {programs} val programs "
        "(`orchestrator eval --max-programs`'s choice), sampled actions. Command: "
        f"`{meta.get('command', 'scripts/peers.sh')}`.",
        "",
        "| trainer | frames | frames/s end to end | frames/s collecting | update s per 4,096 frames "
        "| SR first stop (%) | episodes | train wall (s) | eval wall (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['trainer']} | {fmt(r['frames'])} | {fmt(r['fps'])} | {fmt(r['collect_fps'])} "
            f"| {fmt(r['update_s_per_4096'], 2)} | {fmt(r['sr_first_stop'], 1)} | {fmt(r['eval_episodes'])} "
            f"| {fmt(r['train_seconds'])} | {fmt(r['eval_seconds'])} |"
        )
    lines += [
        "",
        "End to end: frames over the training's wall time (ours: the learner's own clock; the peers: "
        "from the trainer's start, process start-up included). Collecting: frames over the time not "
        "spent updating (synchronous PPO); Sample Factory overlaps them. Frames are the env steps each "
        "trained on, the step that starts an episode included (all three count it, and keep it out "
        "of the loss); Sample Factory stops at the budget and trains on the batches then in flight "
        "too. Every peer has the default's network: the frozen encoder's features stored, the "
        "layers above trained (scripts/peers/net.py).",
        "",
    ]
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write("\n".join(lines))
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump({"frames": frames, "programs": programs, **meta, "trainers": rows}, f, indent=1)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
