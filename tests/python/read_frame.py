#!/usr/bin/env python3
"""Reads one observation of a live GesTHOR-RS run, zero-copy, with iceoryx2's Python binding.

Attaches to the observation service of one worker (`gesthor/<run>/obs/<k>`), takes one sample,
views the records, RGB, depth and gesture sections in place with numpy (no copy of the shared
memory), writes one env's RGB frame as a PNG, and prints the header and that env's record.

    source ~/.cache/gesthor/env.sh     # puts iceoryx2 and numpy on PYTHONPATH
    python3 tests/python/read_frame.py --run-dir runs/up-... --worker 0 --env 0 --out frame.png

The layout is documented in shm_schema/README.md. The run id comes from RUN/run.json (or
--run-id); every resource of a run carries the iceoryx2 prefix `gesthor_<run id>_`.
Exits 0 after writing the PNG, 1 on error, 3 when no sample arrived in time.
"""

import argparse
import ctypes
import json
import os
import struct
import sys
import time
import zlib

import numpy as np
import iceoryx2 as iox2

OBS_MAGIC = 0x4753_4F42
SCHEMA_VERSION = 2
GESTURE_FRAMES, GESTURE_DIMS = 100, 95
SUMMARY_STOPS = 3

# Quality of service: must equal shm_schema::qos (iceoryx2 refuses a different overflow
# setting and requires at least these sizes).
SAFE_OVERFLOW = True
OBS_HISTORY = 1
OBS_SUBSCRIBER_BUFFER = 2
OBS_SUBSCRIBER_MAX_BORROWED = 2
OBS_MAX_SUBSCRIBERS = 3
OBS_MAX_PUBLISHERS = 2
OBS_MAX_NODES = 8


class ObsLayout(ctypes.Structure):
    _fields_ = [
        ("records_offset", ctypes.c_uint64),
        ("rgb_offset", ctypes.c_uint64),
        ("rgb_stride", ctypes.c_uint64),
        ("depth_offset", ctypes.c_uint64),
        ("depth_stride", ctypes.c_uint64),
        ("gesture_offset", ctypes.c_uint64),
        ("gesture_stride", ctypes.c_uint64),
        ("total_len", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "gesthor::ObsLayout"


class WorkerTiming(ctypes.Structure):
    _fields_ = [
        ("sim_ns", ctypes.c_uint64),
        ("render_ns", ctypes.c_uint64),
        ("send_ns", ctypes.c_uint64),
        ("wait_ns", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "gesthor::WorkerTiming"


class ObsHeader(ctypes.Structure):
    _fields_ = [
        ("magic", ctypes.c_uint32),
        ("version", ctypes.c_uint32),
        ("worker_id", ctypes.c_uint32),
        ("generation", ctypes.c_uint32),
        ("step", ctypes.c_uint64),
        ("num_envs", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("gesture_frames", ctypes.c_uint32),
        ("gesture_dims", ctypes.c_uint32),
        ("finished", ctypes.c_uint32),
        ("layout", ObsLayout),
        ("timing", WorkerTiming),
    ]

    @staticmethod
    def type_name() -> str:
        return "gesthor::ObsHeader"


class StopSummary(ctypes.Structure):
    _fields_ = [
        ("step", ctypes.c_uint32),
        ("success", ctypes.c_uint32),
        ("distance", ctypes.c_float),
        ("path_length", ctypes.c_float),
    ]


class EpisodeSummary(ctypes.Structure):
    _fields_ = [
        ("steps", ctypes.c_uint32),
        ("success", ctypes.c_uint32),
        ("collisions", ctypes.c_uint32),
        ("num_stops", ctypes.c_uint32),
        ("path_length", ctypes.c_float),
        ("shortest_path", ctypes.c_float),
        ("final_distance", ctypes.c_float),
        ("total_reward", ctypes.c_float),
        ("intervention_steps", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("stops", StopSummary * SUMMARY_STOPS),
    ]


class EnvRecord(ctypes.Structure):
    _fields_ = [
        ("env_step", ctypes.c_uint64),
        ("episode", ctypes.c_uint64),
        ("program", ctypes.c_uint64),
        ("episode_step", ctypes.c_uint32),
        ("last_action", ctypes.c_uint32),
        ("reward", ctypes.c_float),
        ("terminated", ctypes.c_uint8),
        ("truncated", ctypes.c_uint8),
        ("episode_start", ctypes.c_uint8),
        ("success", ctypes.c_uint8),
        ("collided", ctypes.c_uint8),
        ("gesture_kind", ctypes.c_uint8),
        ("gesture_index", ctypes.c_uint8),
        ("idle", ctypes.c_uint8),
        ("expert_action", ctypes.c_uint8),
        ("_pad", ctypes.c_uint8 * 3),
        ("stops", ctypes.c_uint32),
        ("target_category", ctypes.c_uint32),
        ("target_instances", ctypes.c_uint32),
        ("visible_pixels", ctypes.c_uint32),
        ("robot", ctypes.c_float * 3),
        ("person_rel", ctypes.c_float * 3),
        ("distance", ctypes.c_float),
        ("geodesic", ctypes.c_float),
        ("summary", EpisodeSummary),
    ]


# The sizes readers hard-code (shm_schema's record_sizes_are_stable test pins the Rust side).
assert ctypes.sizeof(ObsHeader) == 144 and ctypes.sizeof(EnvRecord) == 184, "layout drifted from shm_schema"


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


def run_id_of(args) -> str:
    if args.run_id:
        return args.run_id
    with open(os.path.join(args.run_dir, "run.json")) as f:
        return json.load(f)["run_id"]


def prefix_of(run_id: str) -> str:
    """shm_schema::service::prefix."""
    safe = "".join(c if (c.isascii() and c.isalnum()) or c == "-" else "_" for c in run_id[:48])
    return f"gesthor_{safe}_"


def open_subscriber(run_id: str, worker: int):
    cfg = iox2.config.default()
    cfg.global_cfg.prefix = iox2.FileName.new(prefix_of(run_id))
    node = (
        iox2.NodeBuilder.new()
        .config(cfg)
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )
    service = (
        node.service_builder(iox2.ServiceName.new(f"gesthor/{run_id}/obs/{worker}"))
        .publish_subscribe(iox2.Slice[ctypes.c_uint8])
        .user_header(ObsHeader)
        .enable_safe_overflow(SAFE_OVERFLOW)
        .history_size(OBS_HISTORY)
        .subscriber_max_buffer_size(OBS_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(OBS_SUBSCRIBER_MAX_BORROWED)
        .max_subscribers(OBS_MAX_SUBSCRIBERS)
        .max_publishers(OBS_MAX_PUBLISHERS)
        .max_nodes(OBS_MAX_NODES)
        .open()  # attach to the live run only; never create its services
    )
    # history_request: the worker's last observation is handed over when it next updates
    # its connections (at the latest ~0.1 s later), even while it waits for the learner.
    sub = service.subscriber_builder().buffer_size(OBS_SUBSCRIBER_BUFFER).history_request(OBS_HISTORY).create()
    return node, service, sub


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

    run_id = run_id_of(args)
    node, service, sub = open_subscriber(run_id, args.worker)
    deadline = time.monotonic() + args.timeout
    sample = None
    while sample is None:
        sample = sub.receive()
        if sample is None:
            if time.monotonic() > deadline:
                print(f"no observation from worker {args.worker} within {args.timeout} s", file=sys.stderr)
                return 3
            time.sleep(0.01)

    h = sample.user_header().contents
    if h.magic != OBS_MAGIC or h.version != SCHEMA_VERSION:
        print(f"not a GesTHOR observation (magic {h.magic:#x}, version {h.version})", file=sys.stderr)
        return 1
    n, w, ht, lay = h.num_envs, h.width, h.height, h.layout
    payload = sample.payload()  # Slice[c_uint8] over the shared-memory payload
    assert payload.len() >= lay.total_len, (payload.len(), lay.total_len)
    buf = np.frombuffer(payload.as_memory_view(), dtype=np.uint8)  # no copy
    records = np.frombuffer(buf, dtype=np.dtype(EnvRecord), count=n, offset=lay.records_offset)
    rgb = np.frombuffer(buf, dtype=np.uint8, count=n * ht * w * 3, offset=lay.rgb_offset).reshape(n, ht, w, 3)
    depth = np.frombuffer(buf, dtype=np.uint16, count=n * ht * w, offset=lay.depth_offset).reshape(n, ht, w)
    gesture = np.frombuffer(buf, dtype=np.float16, count=n * GESTURE_FRAMES * GESTURE_DIMS, offset=lay.gesture_offset)
    gesture = gesture.reshape(n, GESTURE_FRAMES, GESTURE_DIMS)
    assert rgb.base is not None and not rgb.flags.owndata  # views into shared memory

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
    del records, rgb, depth, gesture, buf, payload
    sample.delete()
    sub.delete()
    return 0


if __name__ == "__main__":
    sys.exit(main())
