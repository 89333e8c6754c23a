"""A person's own gesture from Python: `capture` a video into the recorder's files, then let a
trained agent `follow` it. Both run the `orchestrator` binary (found as GESTHOR_ORCHESTRATOR, on
PATH, or in this repository's target/release) and return what it wrote as a dict, so a notebook
can loop over a person's recordings:

    import gesthor
    for video in videos:
        g = gesthor.capture(video, out=f"mine/{video.stem}", program="val:61")
        r = gesthor.follow("runs/default", program="val:61", motion=g["motion"], out=f"follow/{video.stem}")
        print(video, r["success_first_stop"], r["spl_first_stop"], r["gif"])
"""

import json
import os
import shutil
import subprocess

__all__ = ["capture", "follow", "GestureError"]


class GestureError(RuntimeError):
    """The command's one-line reason (no person found, a video too short, ...)."""


def _orchestrator():
    exe = os.environ.get("GESTHOR_ORCHESTRATOR") or shutil.which("orchestrator")
    if exe:
        return exe
    here = os.path.dirname(os.path.abspath(__file__))
    built = os.path.join(here, "..", "..", "target", "release", "orchestrator")
    if os.path.isfile(built):
        return os.path.normpath(built)
    raise GestureError("no orchestrator binary: set GESTHOR_ORCHESTRATOR or build the repository (cargo build --release)")


def _run(args):
    p = subprocess.run([_orchestrator(), *args], capture_output=True, text=True)
    if p.returncode != 0:
        lines = [l for l in p.stderr.splitlines() if l.startswith("error:")]
        raise GestureError(lines[-1][len("error:"):].strip() if lines else p.stderr.strip())
    return p


def capture(source, out, program="val:0", dataset="data/gond", name=None, fps=None, hands_optional=False):
    """Captures `source` (a video file, a folder of frames or a camera index) into `out`;
    returns `out/capture.json`: the metadata, motion and BVH files, the gesturing arm, its span."""
    args = ["gesture", "capture", str(source), "--out", str(out), "--program", program, "--dataset", str(dataset)]
    if name:
        args += ["--name", name]
    if fps:
        args += ["--fps", str(fps)]
    if hands_optional:
        args.append("--hands-optional")
    _run(args)
    with open(os.path.join(out, "capture.json")) as f:
        return json.load(f)


def follow(checkpoint, program, out, motion=None, dataset="data/gond"):
    """Runs `checkpoint` (a checkpoint file, a run directory, or a shipped model such as
    "models/both") on `program` with the gesture `motion` (a motion CSV; default: the
    program's own); returns `out/result.json`: success and SPL at the first stop, where it
    stopped, success with unlimited stops, steps, and the GIF's path."""
    args = ["follow", "--checkpoint", str(checkpoint), "--program", program, "--out", str(out), "--dataset", str(dataset)]
    if motion:
        args += ["--motion", str(motion)]
    _run(args)
    with open(os.path.join(out, "result.json")) as f:
        return json.load(f)
