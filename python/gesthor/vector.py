"""GesTHOR as a `gymnasium.vector.VectorEnv`: N environments of one worker's pool, stepped in
native code (the GIL released) into one buffer that numpy views without copying.

Episode ends follow the farm (Gymnasium's NEXT_STEP autoreset): the step that ends an episode
returns its final observation with `terminated` (success, or out of stops) or `truncated` (step
limit); the next step ignores that env's action and returns the first observation of its next
episode, reward 0.
"""

import ctypes
import os

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from gesthor import METHODS, _quiet_headless_display, schema

_quiet_headless_display()  # before the native module starts a renderer
from gesthor import _gesthor  # noqa: E402

SPLITS = ("train", "val", "test")
DEPTH_MAX_M = schema.DEPTH_MAX_M


def _toml_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


class GesthorVectorEnv(gym.vector.VectorEnv):
    """GesTHOR environments stepped together; the arguments are `make_vec`'s."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        split="train",
        num_envs=8,
        method="both",
        width=64,
        height=64,
        seed=0,
        dataset=None,
        config=None,
        overrides=(),
        programs=None,
        render_mode=None,
    ):
        if split not in SPLITS:
            raise ValueError(f"split: {split!r} is not one of {', '.join(SPLITS)}")
        if method not in METHODS:
            raise ValueError(f"method: {method!r} is not one of {', '.join(METHODS)}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode: {render_mode!r} is not None or 'rgb_array'")
        dataset = dataset or os.environ.get("GESTHOR_DATASET", "data/gond")
        if not os.path.isfile(os.path.join(dataset, "manifest.json")):
            raise FileNotFoundError(
                f"{dataset}: no GOND dataset there (make one with `orchestrator dataset build --out {dataset}`)"
            )
        if config is not None:
            with open(config) as f:
                self._config_text, self._config_source = f.read(), os.fspath(config)
        else:
            # every other setting at the dissertation's defaults (farm/src/config.rs)
            self._config_text, self._config_source = '[run]\nmethod = "both"\n', "(gesthor.make_vec)"
        self._sets = [
            f"run.method={_toml_string(method)}",
            f"run.split={_toml_string(split)}",
            f"run.dataset={_toml_string(os.path.abspath(dataset))}",
            f"env.envs_per_worker={int(num_envs)}",
            f"env.width={int(width)}",
            f"env.height={int(height)}",
            *overrides,
        ]
        self._programs = None if programs is None else [int(p) for p in programs]
        self.num_envs, self.width, self.height = int(num_envs), int(width), int(height)
        self.render_mode = render_mode
        self._seed = int(seed)
        self._open(self._seed)

        h, w = self.height, self.width
        self.single_observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (h, w, 3), np.uint8),
                "depth": spaces.Box(0.0, DEPTH_MAX_M, (h, w), np.float32),
                # Unity muscle values, -1..1 (zeros when no gesture is perceived)
                "gesture": spaces.Box(-1.0, 1.0, (schema.GESTURE_FRAMES, schema.GESTURE_DIMS), np.float32),
                "target": spaces.Discrete(_gesthor.TARGET_CATEGORIES),
            }
        )
        self.single_action_space = spaces.Discrete(4)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def _open(self, seed):
        """(Re)makes the native pool with `seed`: every draw (programs, noise) follows from it."""
        sets = [*self._sets, f"run.seed={int(seed)}"]
        self._pool = _gesthor.Pool(self._config_text, sets, self._config_source, self._programs)
        addr, n = self._pool.buffer()
        # A view of the pool's own buffer: the pool writes, numpy reads, nothing is copied.
        buf = np.ctypeslib.as_array((ctypes.c_uint8 * n).from_address(addr))
        self._records, self._rgb, self._depth, self._gesture = schema.views(
            buf, self._pool.layout(), self.num_envs, self.height, self.width
        )
        self._seed = int(seed)

    @property
    def config(self) -> str:
        """The effective run configuration (TOML)."""
        return self._pool.config

    def reset(self, *, seed=None, options=None):
        """Starts a new episode in every env; `seed` remakes the pool's random streams."""
        super().reset(seed=seed)
        if seed is not None:
            self._open(seed)
        self._pool.reset()
        return self._observation(), self._info()

    def step(self, actions):
        a = np.asarray(actions, dtype=np.int64).reshape(self.num_envs)
        if ((a < 0) | (a > 3)).any():
            raise ValueError(f"actions must be in 0..3, got {a.tolist()}")
        self._pool.step(a.astype(np.uint8).tobytes())
        r = self._records
        return (
            self._observation(),
            r["reward"].astype(np.float32),
            r["terminated"].astype(bool),
            r["truncated"].astype(bool),
            self._info(),
        )

    def _observation(self):
        return schema.observation(self._records, self._rgb, self._depth, self._gesture)

    def _info(self):
        """Every step: where each env is; at an episode's end (masked `_key` as Gymnasium's
        vector infos): success, SPL, stops, return, length."""
        r = self._records
        s = r["summary"]
        done = (r["terminated"] | r["truncated"]).astype(bool)
        every = np.ones(self.num_envs, dtype=bool)
        shortest, taken = s["shortest_path"].astype(np.float64), s["path_length"].astype(np.float64)
        spl = np.where(
            s["success"] != 0,
            np.where((shortest <= 0) & (taken <= 0), 1.0, shortest / np.maximum(taken, np.maximum(shortest, 1e-12))),
            0.0,
        )
        info = {}
        for key, value in (
            ("program", r["program"].astype(np.int64)),
            ("episode_step", r["episode_step"].astype(np.int64)),
            ("gesture_kind", r["gesture_kind"].astype(np.int64)),
            ("collided", r["collided"].astype(bool)),
            ("distance", r["distance"].astype(np.float32)),
            ("geodesic", r["geodesic"].astype(np.float32)),
            ("robot", r["robot"].astype(np.float32)),
        ):
            info[key], info["_" + key] = value, every
        for key, value in (
            ("success", s["success"] != 0),
            ("spl", spl),
            ("stops", s["num_stops"].astype(np.int64)),
            ("episode_return", s["total_reward"].astype(np.float32)),
            ("episode_length", s["steps"].astype(np.int64)),
            ("shortest_path", shortest),
        ):
            info[key], info["_" + key] = np.where(done, value, np.zeros_like(value)), done
        return info

    def render(self):
        """The robot's current view of every env (render_mode "rgb_array")."""
        if self.render_mode != "rgb_array":
            return None
        return tuple(self._rgb.copy())

    def close_extras(self, **kwargs):
        self._records = self._rgb = self._depth = self._gesture = None
        self._pool = None


def make_vec(split="train", num_envs=8, **kwargs):
    """`num_envs` GesTHOR environments as one Gymnasium vector env.

    split: "train", "val" or "test" fold of the dataset; method: which gestures the robot is
    shown ("both", "referencing", "intervention", or none: "vis_sem", "vision_only", "random");
    dataset: a GOND folder (default $GESTHOR_DATASET or data/gond); config: a run config file
    whose [task] and [env] settings apply; overrides: `KEY=VALUE` as `orchestrator --set`;
    programs: run exactly these programs of the split in order (evaluation) instead of drawing
    them from the seeded stream; width, height: camera pixels (64); seed: every random draw
    follows from it (same seed, same observations); render_mode: None or "rgb_array".
    """
    return GesthorVectorEnv(split=split, num_envs=num_envs, **kwargs)


class GesthorEnv(gym.Env):
    """One GesTHOR environment as a plain `gymnasium.Env` (a one-env pool): for
    `gymnasium.utils.env_checker` and single-env code. Same arguments as `make_vec`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, render_mode=None, **kwargs):
        self._vec = GesthorVectorEnv(num_envs=1, render_mode=render_mode, **kwargs)
        self.render_mode = render_mode
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space

    @staticmethod
    def _first(batch):
        return {k: v[0] for k, v in batch.items()}

    @staticmethod
    def _first_info(info):
        return {k: v[0] for k, v in info.items() if not k.startswith("_") and info["_" + k][0]}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        obs, info = self._vec.reset(seed=seed)
        return self._first(obs), self._first_info(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self._vec.step(np.array([int(action)]))
        return self._first(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), self._first_info(info)

    def render(self):
        frames = self._vec.render()
        return None if frames is None else frames[0]

    def close(self):
        self._vec.close()

