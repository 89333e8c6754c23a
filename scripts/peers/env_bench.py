"""The env alone, random actions, no learning: env steps per second of `gesthor.make_vec` (one
native pool of N envs in this process) against Gymnasium's `AsyncVectorEnv` over N single
`gesthor.make` envs (a process each), at 8, 32 and 160 envs. The farm's own workers are
measured by `orchestrator bench farm` (scripts/peers.sh runs both).

    python scripts/peers/env_bench.py --config configs/tiny/both.toml --dataset data/gond --out OUT.json

An AsyncVectorEnv whose processes would not fit in memory (each holds its own renderer and
dataset reader, measured at 8 envs) is not started; the row says so.
"""

import argparse
import json
import os
import time

import numpy as np


def rss_mib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def available_mib():
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024
    return 0.0


def steps_per_second(env, n, seconds, seed=0):
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for _ in range(3):  # first rooms loaded and uploaded
        env.step(rng.integers(0, 4, n))
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        env.step(rng.integers(0, 4, n))
        steps += n
    return steps / (time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--envs", default="8,32,160")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--mib-per-process", type=float, help="an AsyncVectorEnv process's memory, if measured before")
    a = ap.parse_args()
    import gymnasium as gym

    import gesthor
    from gesthor.vector import GesthorEnv

    kw = dict(split="train", config=a.config, dataset=a.dataset, seed=1)
    rows, per_process = [], a.mib_per_process
    for n in [int(x) for x in a.envs.split(",")]:
        try:
            env = gesthor.make_vec(num_envs=n, **kw)
        except ValueError as e:  # one pool holds at most 64 envs
            print(f"make_vec {n}: {e}", flush=True)
            rows.append({"envs": n, "kind": "make_vec", "steps_per_s": None, "note": str(e)})
        else:
            v = steps_per_second(env, n, a.seconds)
            env.close()
            print(f"make_vec {n}: {v:,.0f} steps/s", flush=True)
            rows.append({"envs": n, "kind": "make_vec", "steps_per_s": v})

        need = None if per_process is None else per_process * n
        if need is not None and need > 0.8 * available_mib():
            print(f"AsyncVectorEnv {n}: not started ({n} x {per_process:.0f} MiB > 80% of free memory)", flush=True)
            rows.append({"envs": n, "kind": "AsyncVectorEnv", "steps_per_s": None,
                         "note": f"{n} processes x {per_process:.0f} MiB would not fit"})
            continue
        env = gym.vector.AsyncVectorEnv([lambda: GesthorEnv(**kw) for _ in range(n)])
        v = steps_per_second(env, n, a.seconds)
        pids = [p.pid for p in env.processes]
        per_process = max(per_process or 0.0, sum(rss_mib(p) for p in pids) / max(len(pids), 1))
        env.close()
        print(f"AsyncVectorEnv {n}: {v:,.0f} steps/s ({per_process:.0f} MiB a process)", flush=True)
        rows.append({"envs": n, "kind": "AsyncVectorEnv", "steps_per_s": v, "mib_per_process": per_process})
    with open(a.out, "w") as f:
        json.dump({"seconds": a.seconds, "cpus": os.cpu_count(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
