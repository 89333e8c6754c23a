"""What both peers share: the val programs `orchestrator eval --max-programs` picks, the rule of
SR at the first stop, and a plain N-env vector over the native pool for code that cannot import
`gesthor.vector` (Sample Factory pins gymnasium < 1.0; `gesthor.vector` needs 1.x).

Works under numpy 1 and 2 and without gymnasium.
"""

import ctypes
import json
import os
import time

import numpy as np

from gesthor import _quiet_headless_display, schema

_quiet_headless_display()  # before the native module starts a renderer
from gesthor import _gesthor  # noqa: E402

SEED = 1  # farm/src/config.rs's default run.seed: evaluation pairs programs with gestures by it


def choose_programs(total, max_programs):
    """`orchestrator eval --max-programs`: `m` programs spread evenly over the split."""
    if max_programs is None or max_programs >= total:
        return list(range(total))
    return [i * total // max_programs for i in range(max_programs)]


def split_size(dataset, split):
    with open(os.path.join(dataset, "manifest.json")) as f:
        return int(json.load(f)["splits"][split]["programs"])


def val_programs(dataset, n):
    return choose_programs(split_size(dataset, "val"), n)


def encoder_weights(config):
    """The config's model.encoder_weights (the frozen encoder's file)."""
    import tomllib

    with open(config, "rb") as f:
        return tomllib.load(f)["model"]["encoder_weights"]


def _toml_string(s):
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


class PoolVec:
    """`num_envs` envs of one native pool, as `gesthor.make_vec` steps them (the farm's episode
    protocol: the step after an episode's last observation ignores its action and starts the
    next episode). Observations and infos use make_vec's keys and units."""

    def __init__(self, split, num_envs, config, dataset, seed, method="both", programs=None, width=64, height=64):
        with open(config) as f:
            text = f.read()
        sets = [
            f"run.method={_toml_string(method)}",
            f"run.split={_toml_string(split)}",
            f"run.dataset={_toml_string(os.path.abspath(dataset))}",
            f"env.envs_per_worker={int(num_envs)}",
            f"env.width={int(width)}",
            f"env.height={int(height)}",
            f"run.seed={int(seed)}",
            # programs given by index run whatever room they are in (as orchestrator eval)
            *(["run.scenes=[]"] if programs is not None else []),
        ]
        progs = None if programs is None else [int(p) for p in programs]
        self.pool = _gesthor.Pool(text, sets, os.fspath(config), progs)
        self.num_envs, self.width, self.height = int(num_envs), int(width), int(height)
        addr, n = self.pool.buffer()
        buf = np.ctypeslib.as_array((ctypes.c_uint8 * n).from_address(addr))
        self._records, self._rgb, self._depth, self._gesture = schema.views(
            buf, self.pool.layout(), self.num_envs, self.height, self.width
        )

    def reset(self):
        self.pool.reset()
        return self._observation(), self._info()

    def step(self, actions):
        a = np.asarray(actions, dtype=np.int64).reshape(self.num_envs)
        self.pool.step(a.astype(np.uint8).tobytes())
        r = self._records
        return self._observation(), r["reward"].astype(np.float32), r["terminated"] != 0, r["truncated"] != 0, self._info()

    def finished(self):
        return self.pool.finished()

    def _observation(self):
        return schema.observation(self._records, self._rgb, self._depth, self._gesture)

    def _info(self):
        r = self._records
        s = r["summary"]
        done = (r["terminated"] != 0) | (r["truncated"] != 0)
        return {
            "program": r["program"].astype(np.int64),
            "success": np.where(done, s["success"] != 0, False),
            "_success": done,
            "stops": np.where(done, s["num_stops"].astype(np.int64), 0),
            "_stops": done,
        }


def policy_inputs(vec):
    """What the default's network reads of each env's current step, from a vector's own buffers
    (`gesthor.make_vec`'s env or PoolVec: `_records`, `_rgb`, `_depth`, `_gesture`), read before
    its next step: RGB u8 [N,H,W,3] and depth u16 [N,H,W] (the encoder's input), the gesture f16
    [N,100,95] zeroed where none is shown, the target category (0 for an idle env), and the
    person's pose relative to the robot f32 [N,3]: right (m), forward (m), yaw difference / 360
    (the records' `person_rel`, which the default reads as it is: learner/src/obs.rs)."""
    r = vec._records
    idle = r["idle"] != 0
    shown = (r["gesture_kind"] != 0) & ~idle
    return {
        "rgb": vec._rgb.copy(),
        "depth": vec._depth.copy(),
        "gesture": np.where(shown[:, None, None], vec._gesture, np.float16(0)).astype(np.float16),
        "target": np.where(idle, 0, r["target_category"]).astype(np.int64),
        "pose": np.ascontiguousarray(r["person_rel"], dtype=np.float32),
    }


class GestureIds:
    """An id per env and step, equal where an env shows the same gesture as at its previous step
    (compared exactly): the network reads each distinct gesture of a batch once. Env `i`'s ids are
    `base + i` plus a multiple of 2**20 that grows with each change."""

    def __init__(self, num_envs, base=0):
        self.base = np.arange(num_envs, dtype=np.int64) + int(base)
        self.count = np.zeros(num_envs, dtype=np.int64)
        self.last = None

    def __call__(self, gesture):
        if self.last is not None:
            changed = (gesture != self.last).reshape(len(gesture), -1).any(1)
            self.count += changed
        self.last = gesture.copy()
        return self.base + (self.count << 20)


def first_stop_successes(info, done):
    """Per env: whether the episode that just ended succeeded at its first stop. Evaluation
    allows unlimited stops (orchestrator eval sets task.max_stops = 0) and an episode ends at
    its first successful stop, so success at the first stop is success with exactly one stop."""
    return done & info["success"].astype(bool) & (info["stops"] == 1)


def evaluate(vec, act, programs, finished=None, log_every=30.0):
    """Runs every program once (`vec` made with `programs=...`); `act(obs, first)` → actions,
    `first[i]`: obs[i] starts an episode (reset recurrent state). Returns SR at the first stop
    (%), SR with unlimited stops (%), episodes, seconds."""
    want = set(int(p) for p in programs)
    got = {}
    t0 = last = time.time()
    obs, info = vec.reset()
    first = np.ones(vec.num_envs, dtype=bool)
    ended = np.zeros(vec.num_envs, dtype=bool)
    # an episode lasts at most max_steps (+1 for the step that starts the next)
    limit = (len(want) // vec.num_envs + 2) * 1000
    for _ in range(limit):
        obs, _, term, trunc, info = vec.step(act(obs, first))
        done = np.asarray(term | trunc, dtype=bool)
        records = getattr(vec, "_records", None)
        if records is not None:  # an env out of programs idles: never an episode's end
            done &= records["idle"] == 0
        ok = first_stop_successes(info, done)
        for i in np.flatnonzero(done):
            p = int(info["program"][i])
            if p in want and p not in got:
                got[p] = (bool(ok[i]), bool(info["success"][i]))
        # obs is an episode's final observation where done; the next step's obs starts the next
        first, ended = ended, done
        if len(got) == len(want) or (finished is not None and finished()):
            break
        if time.time() - last > log_every:
            last = time.time()
            print(f"[eval] {len(got)}/{len(want)} episodes, {time.time() - t0:.0f} s", flush=True)
    n = max(len(got), 1)
    return {
        "sr_first_stop": 100.0 * sum(v[0] for v in got.values()) / n,
        "sr_unlimited": 100.0 * sum(v[1] for v in got.values()) / n,
        "episodes": len(got),
        "programs": len(want),
        "seconds": time.time() - t0,
    }
