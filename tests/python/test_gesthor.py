"""Checks the `gesthor` package from Python and prints what it measured as one JSON object
(tests/python_package.rs runs it and compares with the farm):

    python3 tests/python/test_gesthor.py DATASET [--steps 10000] [--envs 8]

- `gymnasium.utils.env_checker.check_env` passes on a single env (`GesthorEnv`);
- the vector env's spaces hold its observations; the same seed gives the same observations;
- a random rollout of --steps env steps: its episodes, success rate and frames/s.
"""

import argparse
import json
import sys
import time

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import gesthor


def rollout(envs, steps, seed):
    """Uniformly random actions for `steps` env steps; (episodes, successes, seconds)."""
    rng = np.random.default_rng(seed)
    envs.reset(seed=seed)
    episodes = successes = 0
    t = time.perf_counter()
    for _ in range(steps // envs.num_envs):
        _, _, term, trunc, info = envs.step(rng.integers(0, 4, envs.num_envs))
        done = term | trunc
        episodes += int(done.sum())
        successes += int((info["success"] & done).sum())
    return episodes, successes, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--config", default=None)
    a = ap.parse_args()
    common = dict(split="train", method="both", width=64, height=64, dataset=a.dataset, config=a.config)

    single = gymnasium.make("GesTHOR-v0", render_mode="rgb_array", **common)
    check_env(single.unwrapped, skip_render_check=False)
    single.close()

    envs = gesthor.make_vec(num_envs=a.envs, seed=5, **common)
    obs, info = envs.reset(seed=5)
    assert envs.observation_space.contains(obs), {k: (v.dtype, v.shape) for k, v in obs.items()}
    assert obs["rgb"].shape == (a.envs, 64, 64, 3) and obs["gesture"].shape == (a.envs, 100, 95)
    twin = gesthor.make_vec(num_envs=a.envs, seed=5, **common)
    twin_obs, _ = twin.reset(seed=5)
    actions = np.random.default_rng(1).integers(0, 4, (20, a.envs))
    same = all(np.array_equal(obs[k], twin_obs[k]) for k in obs)
    for act in actions:
        o1, r1, *_ = envs.step(act)
        o2, r2, *_ = twin.step(act)
        same &= all(np.array_equal(o1[k], o2[k]) for k in o1) and np.array_equal(r1, r2)
    assert envs.observation_space.contains(o1)
    twin.close()

    episodes, successes, secs = rollout(envs, a.steps, seed=11)
    envs.close()
    json.dump(
        {
            "check_env": "passed",
            "same_seed_same_observations": bool(same),
            "steps": a.steps // a.envs * a.envs,
            "episodes": episodes,
            "successes": successes,
            "success_rate": successes / max(episodes, 1),
            "frames_per_s": a.steps // a.envs * a.envs / secs,
        },
        sys.stdout,
    )
    print()


if __name__ == "__main__":
    main()
