"""GesTHOR from Python: the simulator as a Gymnasium vector environment (`make_vec`, stepped
in native code), the live frames of a running farm (`FarmReader`, zero-copy), and a person's own
gesture captured from a video and followed by a trained agent (`capture`, `follow`).

    import gesthor
    envs = gesthor.make_vec(split="train", num_envs=8, method="both", dataset="data/gond")
    obs, info = envs.reset(seed=0)
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())

Observation spec: docs/python.md.
"""

import os
import tempfile

__all__ = ["make_vec", "GesthorVectorEnv", "GesthorEnv", "FarmReader", "capture", "follow", "ACTIONS", "METHODS"]

ACTIONS = ("MoveAhead", "RotateLeft", "RotateRight", "Stop")
METHODS = ("random", "vision_only", "vis_sem", "referencing", "intervention", "both")


def _quiet_headless_display() -> None:
    # Mesa probes Wayland, whose client library prints "error: XDG_RUNTIME_DIR is invalid" on
    # headless machines; a private empty folder keeps it quiet (left alone when RUST_LOG is set).
    d = os.environ.get("XDG_RUNTIME_DIR")
    if (d and os.path.isdir(d)) or "RUST_LOG" in os.environ:
        return
    path = os.path.join(tempfile.gettempdir(), f"gesthor-runtime-{os.getuid()}")
    os.makedirs(path, mode=0o700, exist_ok=True)
    os.environ["XDG_RUNTIME_DIR"] = path


def __getattr__(name):
    # Loaded on first use: FarmReader needs iceoryx2 but no native build, make_vec the reverse.
    if name in ("make_vec", "GesthorVectorEnv", "GesthorEnv"):
        from gesthor import vector

        return getattr(vector, name)
    if name in ("capture", "follow", "GestureError"):
        from gesthor import gesture

        return getattr(gesture, name)
    if name == "FarmReader":
        from gesthor.farm_reader import FarmReader

        return FarmReader
    raise AttributeError(f"module 'gesthor' has no attribute {name!r}")


try:
    import gymnasium

    # gymnasium.make("GesTHOR-v0", ...) and gymnasium.make_vec("GesTHOR-v0", num_envs=N,
    # vectorization_mode="vector_entry_point", ...), with make_vec's arguments.
    gymnasium.register(
        id="GesTHOR-v0",
        entry_point="gesthor.vector:GesthorEnv",
        vector_entry_point="gesthor.vector:GesthorVectorEnv",
    )
except ImportError:  # FarmReader alone needs no gymnasium
    pass
