"""Live frames of a running farm, zero-copy, with iceoryx2's Python binding (PyPI `iceoryx2`
0.10): attaches to one worker's observation service of a run started by `orchestrator up`.

    reader = FarmReader("runs/up-...", worker=0)
    with reader.read(timeout=10.0) as obs:     # None if nothing arrived in time
        obs.rgb[0]                             # numpy views into shared memory, no copy
"""

import ctypes
import json
import os
import time

import iceoryx2 as iox2
import numpy as np

from gesthor import schema


def prefix_of(run_id: str) -> str:
    """shm_schema::service::prefix: every resource of a run carries it."""
    safe = "".join(c if (c.isascii() and c.isalnum()) or c == "-" else "_" for c in run_id[:48])
    return f"gesthor_{safe}_"


class Observation:
    """One observation sample: its header and numpy views of its payload. Valid until
    `release()` (or the end of a `with` block); copy what must outlive it."""

    def __init__(self, sample):
        self._sample = sample
        self.header = sample.user_header().contents
        h = self.header
        if h.magic != schema.OBS_MAGIC or h.version != schema.SCHEMA_VERSION:
            raise ValueError(f"not a GesTHOR observation (magic {h.magic:#x}, version {h.version})")
        payload = sample.payload()
        if payload.len() < h.layout.total_len:
            raise ValueError(f"payload of {payload.len()} bytes, the layout needs {h.layout.total_len}")
        buf = np.frombuffer(payload.as_memory_view(), dtype=np.uint8)
        self.records, self.rgb, self.depth, self.gesture = schema.views(buf, h.layout, h.num_envs, h.height, h.width)

    def release(self) -> None:
        """Gives the sample back to the worker's pool (the views must not be used after)."""
        if self._sample is not None:
            self.records = self.rgb = self.depth = self.gesture = None
            self._sample.delete()
            self._sample = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


class FarmReader:
    """A subscriber to worker `worker`'s observations of the run in `run_dir` (or `run_id`)."""

    def __init__(self, run_dir: str = None, worker: int = 0, run_id: str = None):
        if run_id is None:
            with open(os.path.join(run_dir, "run.json")) as f:
                run_id = json.load(f)["run_id"]
        self.run_id, self.worker = run_id, worker
        cfg = iox2.config.default()
        cfg.global_cfg.prefix = iox2.FileName.new(prefix_of(run_id))
        self._node = (
            iox2.NodeBuilder.new()
            .config(cfg)
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        self._service = (
            self._node.service_builder(iox2.ServiceName.new(f"gesthor/{run_id}/obs/{worker}"))
            .publish_subscribe(iox2.Slice[ctypes.c_uint8])
            .user_header(schema.ObsHeader)
            .enable_safe_overflow(schema.SAFE_OVERFLOW)
            .history_size(schema.OBS_HISTORY)
            .subscriber_max_buffer_size(schema.OBS_SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(schema.OBS_SUBSCRIBER_MAX_BORROWED)
            .max_subscribers(schema.OBS_MAX_SUBSCRIBERS)
            .max_publishers(schema.OBS_MAX_PUBLISHERS)
            .max_nodes(schema.OBS_MAX_NODES)
            .open()  # attach to the live run only; never create its services
        )
        # history_request: the worker's last observation is handed over when it next updates
        # its connections (at the latest ~0.1 s later), even while it waits for the learner.
        self._sub = (
            self._service.subscriber_builder()
            .buffer_size(schema.OBS_SUBSCRIBER_BUFFER)
            .history_request(schema.OBS_HISTORY)
            .create()
        )

    def read(self, timeout: float = 10.0):
        """The next observation, or None when none arrives within `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            sample = self._sub.receive()
            if sample is not None:
                return Observation(sample)
            if time.monotonic() > deadline:
                return None
            time.sleep(0.01)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.delete()
            self._sub = None
