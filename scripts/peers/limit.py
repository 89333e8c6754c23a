"""The update's bound on this CPU: the default network's floating-point work per trained frame
(counted from its layer shapes, scripts/peers/net.py being the same network) over the rate at
which this CPU multiplies matrices (measured with torch on the same threads as the learner).

    python scripts/peers/limit.py [--threads 2] [--episode-frames 44] [--out OUT.json]

A dense layer of n inputs and m outputs costs 2·n·m FLOPs a row forward; backward costs twice
the forward (the gradients of the inputs and of the weights), so a trained row costs 3× its
forward. PPO trains each frame `epochs` times. The gesture network reads each distinct gesture
once (the gesture memo): its per-gesture work is spread over an episode's frames.
"""

import argparse
import json
import time

import torch

HIDDEN, CELLS, ENC_CH, HEAD_CH = 256, 8 * 8, 64, 16
FRAMES, DIMS, FRAME_W = 100, 95, 64
EPOCHS = 4  # configs/tiny/both.toml [ppo]


def mac(n, m):
    return n * m


def per_frame_macs():
    """Multiply-adds of one frame through the trained layers, forward (the frozen encoder not
    included: its features are stored when acting)."""
    h2 = HIDDEN // 2
    return {
        "1x1 conv 64→16 over 8x8 cells": CELLS * mac(ENC_CH, HEAD_CH),
        "FC 1024→256 (visual)": mac(HEAD_CH * CELLS, HIDDEN),
        "FC 3→256 (pose)": mac(3, HIDDEN),
        "gesture, per frame: pose 4→128": mac(4, h2),
        "GRU 1024+256→3x256": 3 * mac(4 * HIDDEN + HIDDEN, HIDDEN),
        "actor 256-256-256-4": mac(HIDDEN, HIDDEN) * 2 + mac(HIDDEN, 4),
        "critic 256-256-256-1": mac(HIDDEN, HIDDEN) * 2 + mac(HIDDEN, 1),
    }


def per_gesture_macs():
    """Multiply-adds of reading one gesture (flat layer, per-frame network, its output layers)."""
    h2 = HIDDEN // 2
    return {
        "flat 9500→128": mac(FRAMES * DIMS, h2),
        "per-frame net 100 x (95→64→64)": FRAMES * (mac(DIMS, FRAME_W) + mac(FRAME_W, FRAME_W)),
        "A 128→128, B and C 128→256": mac(2 * FRAME_W, h2) + mac(2 * FRAME_W, 2 * h2),
    }


def encoder_macs():
    """The frozen RGB-D encoder on one 64x64 frame (learner/src/encoder/net.rs), when acting."""
    return (
        16 * 16 * mac(4 * 4 * 4, 32)  # patch 4x4 stride 4: 16x16 outputs
        + 8 * 8 * mac(32 * 9, 64)  # 3x3 stride 2
        + 8 * 8 * 64 * 9  # depthwise 3x3
        + 8 * 8 * mac(64, 64)  # pointwise
    )


def matmul_rate(threads, n=1024, seconds=3.0):
    """FLOP/s of an n x n by n x n float32 product, best of repeated runs."""
    torch.set_num_threads(threads)
    a, b = torch.randn(n, n), torch.randn(n, n)
    for _ in range(3):
        a @ b
    best, t_end = 0.0, time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        t = time.perf_counter()
        for _ in range(5):
            a @ b
        best = max(best, 5 * 2 * n**3 / (time.perf_counter() - t))
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--episode-frames", type=float, default=44.0, help="mean frames per episode (one gesture each)")
    ap.add_argument("--out")
    a = ap.parse_args()
    frame, gesture = per_frame_macs(), per_gesture_macs()
    forward = 2 * (sum(frame.values()) + sum(gesture.values()) / a.episode_frames)
    trained = 3 * forward * EPOCHS
    acting = 2 * (sum(frame.values()) + sum(gesture.values()) / a.episode_frames + encoder_macs())
    rate = matmul_rate(a.threads)
    out = {
        "threads": a.threads,
        "matmul_flops_per_s": rate,
        "per_frame_forward_flops": forward,
        "update_flops_per_frame": trained,
        "acting_flops_per_frame": acting,
        "update_bound_frames_per_s": rate / trained,
        "acting_bound_frames_per_s": rate / acting,
        "per_frame_macs": frame,
        "per_gesture_macs": gesture,
        "encoder_macs": encoder_macs(),
        "episode_frames": a.episode_frames,
        "epochs": EPOCHS,
    }
    print(
        f"matmul {rate / 1e9:.1f} GFLOP/s on {a.threads} threads; the update {trained / 1e6:.1f} MFLOP a frame "
        f"({EPOCHS} epochs x forward and backward) → at most {rate / trained:,.0f} frames/s; acting "
        f"{acting / 1e6:.1f} MFLOP a frame → at most {rate / acting:,.0f} frames/s"
    )
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
