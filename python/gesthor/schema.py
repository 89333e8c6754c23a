"""The farm's observation layout (shm_schema/README.md) as ctypes structures and numpy views.

`EnvRecord` viewed with `numpy.dtype(EnvRecord)` reads the records of a buffer in place; `views`
cuts a whole observation payload into records, RGB, depth and gesture arrays without copying.
"""

import ctypes

import numpy as np

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


def views(buf: np.ndarray, layout, num_envs: int, height: int, width: int):
    """(records, rgb [N,H,W,3] u8, depth [N,H,W] u16, gesture [N,100,95] f16), views of `buf`
    (a uint8 array over one observation payload) at the offsets of `layout` (an ObsLayout, or a
    dict with the same names)."""
    get = (lambda k: layout[k]) if isinstance(layout, dict) else (lambda k: getattr(layout, k))
    n, h, w = num_envs, height, width
    records = np.frombuffer(buf, dtype=np.dtype(EnvRecord), count=n, offset=get("records_offset"))
    rgb = np.frombuffer(buf, dtype=np.uint8, count=n * h * w * 3, offset=get("rgb_offset")).reshape(n, h, w, 3)
    depth = np.frombuffer(buf, dtype=np.uint16, count=n * h * w, offset=get("depth_offset")).reshape(n, h, w)
    gesture = np.frombuffer(buf, dtype=np.float16, count=n * GESTURE_FRAMES * GESTURE_DIMS, offset=get("gesture_offset"))
    return records, rgb, depth, gesture.reshape(n, GESTURE_FRAMES, GESTURE_DIMS)


DEPTH_MAX_M = 10.0  # depth is stored linear 0..10 m as 0..65535


def observation(records, rgb, depth, gesture):
    """`make_vec`'s observation, copied out of a pool's views (`views`): RGB u8, depth in
    metres, the gesture as f32 muscle values, the target category."""
    return {
        "rgb": rgb.copy(),
        "depth": depth.astype(np.float32) * np.float32(DEPTH_MAX_M / 65535.0),
        "gesture": gesture.astype(np.float32),
        "target": records["target_category"].astype(np.int64),
    }

