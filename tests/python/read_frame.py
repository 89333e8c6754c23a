#!/usr/bin/env python3
"""Reads one observation of a live GesTHOR-RS run, zero-copy, with iceoryx2's Python binding.

Attaches to the observation service of one worker (`gesthor/<run>/obs/<k>`), takes one sample,
views the records, RGB, depth and gesture sections in place with numpy (no copy of the shared
memory), writes one env's RGB frame as a PNG, and prints the header and that env's record.

    source ~/.cache/gesthor/env.sh     # puts iceoryx2 and numpy on PYTHONPATH
    python3 tests/python/read_frame.py --run-dir runs/up-... --worker 0 --env 0 --out frame.png

The layout is documented in shm_schema/README.md; the reading is `gesthor.FarmReader`
(python/gesthor/farm_reader.py). The run id comes from RUN/run.json (or
--run-id); every resource of a run carries the iceoryx2 prefix `gesthor_<run id>_`.
Exits 0 after writing the PNG, 1 on error, 3 when no sample arrived in time.
"""

import argparse
import json
import os
import struct
import sys
import zlib

import numpy as np
import iceoryx2 as iox2

# The package's pure-Python half, from the repository (no build needed).
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
from gesthor.farm_reader import FarmReader  # noqa: E402


def write_png(path: str, rgb: np.ndarray) -> None:
    """A minimal PNG encoder: 8-bit RGB, no filtering, one zlib stream."""
    h, w, c = rgb.shape
    assert c == 3 and rgb.dtype == np.uint8
    raw = np.zeros((h, 1 + 3 * w), dtype=np.uint8)  # filter byte 0 before each row
    raw[:, 1:] = rgb.reshape(h, 3 * w)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
    png += chunk(b"IEND", b"")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(png)
    os.replace(tmp, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--run-dir", help="run directory (its run.json names the run id)")
    src.add_argument("--run-id", help="run id")
    ap.add_argument("--worker", type=int, default=0)
    ap.add_argument("--env", type=int, default=0)
    ap.add_argument("--out", default="frame.png")
    ap.add_argument("--timeout", type=float, default=10.0)
    args = ap.parse_args()
    iox2.set_log_level_from_env_or(iox2.LogLevel.Warn)

    reader = FarmReader(args.run_dir, worker=args.worker, run_id=args.run_id)
    try:
        obs = reader.read(timeout=args.timeout)
    except ValueError as err:
        print(err, file=sys.stderr)
        return 1
    if obs is None:
        print(f"no observation from worker {args.worker} within {args.timeout} s", file=sys.stderr)
        return 3
    h, rgb, depth, gesture, records = obs.header, obs.rgb, obs.depth, obs.gesture, obs.records
    n, w, ht = h.num_envs, h.width, h.height
    assert rgb.base is not None and not rgb.flags.owndata  # views into shared memory
    run_id = reader.run_id

    e = args.env
    if not 0 <= e < n:
        print(f"--env {e}: the worker has {n} envs", file=sys.stderr)
        return 1
    write_png(args.out, rgb[e])
    r = records[e]
    print(
        json.dumps(
            {
                "run_id": run_id,
                "worker_id": h.worker_id,
                "generation": h.generation,
                "step": h.step,
                "num_envs": n,
                "width": w,
                "height": ht,
                "finished": h.finished,
                "env": e,
                "env_step": int(r["env_step"]),
                "episode": int(r["episode"]),
                "program": int(r["program"]),
                "episode_step": int(r["episode_step"]),
                "reward": float(r["reward"]),
                "target_category": int(r["target_category"]),
                "gesture_kind": int(r["gesture_kind"]),
                "depth_m_mean": float(depth[e].mean()) * 10.0 / 65535.0,
                "gesture_abs_mean": float(np.abs(gesture[e].astype(np.float32)).mean()),
                "png": os.path.abspath(args.out),
            }
        )
    )
    # Give the sample back before the node goes away.
    del records, rgb, depth, gesture
    obs.release()
    reader.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
