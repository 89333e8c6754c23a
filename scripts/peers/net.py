"""The default's network (configs/tiny/both.toml) in PyTorch, for both peers: the frozen
pretrained RGB-D encoder, and the layers PPO trains above it, as learner/src/net builds them.

    frames 64x64 RGB-D ─ frozen encoder (encoders/contrast64.safetensors) ─ 64x8x8       (stored)
    64x8x8 ─ 1x1 conv 64→16, ReLU ─ flatten ─ FC 1024→256, ReLU ──────────────────────┐
    gesture 100x95 ─ flat_and_turned (below) ─ 256 ────────────────────────────────────┤ concat 1024
    target category ─ embedding 37→256, ReLU ──────────────────────────────────────────┤ → GRU 1x256
    person pose (right m, forward m, yaw/360) ─ FC 3→256, ReLU ─────────────────────────┘  ├ actor  256-256-4
                                                                                           └ critic 256-256-1
The gesture's flat_and_turned reading (learner/src/net/gesture_net.rs), hidden 256:
    flat:    100x95 ─ flatten ─ FC 9500→128, ReLU
    turned:  each frame 95 ─ FC 64, ReLU ─ FC 64, ReLU; mean and max over the 100 frames → p (128);
             ReLU(A·p + b + shown·(cos·B·p + sin·C·p + D·pose4)), A: 128→128, B and C one 128→256
             layer without bias, D: 4→128 without bias, pose4 = (right, forward, cos, sin of the
             facing) rounded to half precision, shown: the gesture is not all zero
    the two concatenated (256).
The actor and critic are two ReLU layers of 256 and a linear output each. Layer sizes and
activations are the default's; the initialisation is PyTorch's (orthogonal for the heads and the
GRU, as the default's), not the default's seeds.

Inputs in the stored form of the default's rollout: `visual` f32 [B,64,8,8] (the encoder's
features, computed once when acting), `gesture` f16 [B,100,95] (zeroed where none is shown, as
the default's mask), `target` i64 [B], `pose` f32 [B,3]. The per-frame network reads each
distinct gesture of a batch once, given ids that say which rows show the same gesture
(common.GestureIds; the default reads each once too: its gesture memo and the rollout's gesture
index) — gestures change only when an episode starts or intervention switches.
"""

import json
import math
import struct

import numpy as np
import torch
from torch import nn

TARGET_CATEGORIES = 37
GESTURE_FRAMES, GESTURE_DIMS = 100, 95
FRAME_WIDTH = 64  # the per-frame network's layers
HEAD_CHANNELS = 16  # the 1x1 reduction above the encoder (layers.rs PRETRAINED_HEAD_CHANNELS)
ENCODER_FORMAT = "gesthor-rgbd-encoder-1"


def read_safetensors(path):
    """A safetensors file → (metadata dict, {name: float32 tensor}): 8-byte little-endian header
    length, the JSON header, then the raw little-endian data (F32 only, as the encoder writes)."""
    with open(path, "rb") as f:
        raw = f.read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    meta = header.pop("__metadata__", {}) or {}
    data = raw[8 + n :]
    tensors = {}
    for name, h in header.items():
        if h["dtype"] != "F32":
            raise ValueError(f"{path}: tensor {name} is {h['dtype']}, expected F32")
        a, b = h["data_offsets"]
        tensors[name] = torch.from_numpy(np.frombuffer(data[a:b], dtype="<f4").reshape(h["shape"]).copy())
    return meta, tensors


class RgbdEncoder(nn.Module):
    """learner/src/encoder/net.rs: [B,4,H,W] in 0..1 → [B,64,H/8,W/8]."""

    def __init__(self):
        super().__init__()
        self.patch = nn.Conv2d(4, 32, 4, stride=4)
        self.down = nn.Conv2d(32, 64, 3, stride=2, padding=1)
        self.context_dw = nn.Conv2d(64, 64, 3, padding=1, groups=64)
        self.context_pw = nn.Conv2d(64, 64, 1)

    def forward(self, x):
        y = torch.relu(self.down(torch.relu(self.patch(x))))
        return torch.relu(y + self.context_pw(torch.relu(self.context_dw(y))))


def load_encoder(path, width=64, height=64):
    """The frozen encoder from its weights file (no gradients, eval mode)."""
    meta, tensors = read_safetensors(path)
    info = json.loads(meta.get("gesthor_encoder", "{}"))
    if info.get("format") != ENCODER_FORMAT:
        raise ValueError(f"{path}: not an RGB-D encoder weights file ({info})")
    if (info.get("width"), info.get("height")) != (width, height):
        raise ValueError(f"{path}: trained on {info.get('width')}x{info.get('height')}, frames are {width}x{height}")
    enc = RgbdEncoder()
    enc.load_state_dict(tensors, strict=True)
    enc.requires_grad_(False)
    return enc.eval()


@torch.no_grad()
def encoder_features(encoder, rgb, depth):
    """encoder_input + the trunk: RGB u8 [B,H,W,3] and depth u16 [B,H,W] (numpy) → f32 [B,64,H/8,W/8]."""
    rgb = torch.from_numpy(np.ascontiguousarray(rgb)).float().permute(0, 3, 1, 2) / 255.0
    depth = torch.from_numpy(np.asarray(depth, dtype=np.int32)).float().unsqueeze(1) / 65535.0
    return encoder(torch.cat([rgb, depth], 1))


def frame_pose(pose):
    """inputs::frame_pose: [B,3] (right, forward, yaw/360) → [B,4] (right, forward, cos, sin),
    rounded to half precision."""
    turn = pose[:, 2] * (2.0 * math.pi)
    return torch.stack([pose[:, 0], pose[:, 1], turn.cos(), turn.sin()], 1).half().float()


def distinct_rows(ids):
    """Rows sharing a gesture id (common.GestureIds) → (one row of each [G], index [R] into them)."""
    keys, index = torch.unique(ids, return_inverse=True)
    first = torch.zeros(len(keys), dtype=torch.long).scatter_(0, index, torch.arange(len(ids)))  # any row of each
    return first, index


class FlatAndTurned(nn.Module):
    """learner/src/net/gesture_net.rs's FlatAndTurned with the pose (hidden = 256: 128 + 128)."""

    def __init__(self, hidden, dims=GESTURE_DIMS, pose_dims=4):
        super().__init__()
        w = hidden - hidden // 2
        self.flat = nn.Linear(GESTURE_FRAMES * dims, hidden // 2)
        self.frame0 = nn.Linear(dims, FRAME_WIDTH)
        self.frame1 = nn.Linear(FRAME_WIDTH, FRAME_WIDTH)
        self.out = nn.Linear(2 * FRAME_WIDTH, w)  # A (with b)
        self.turn = nn.Linear(2 * FRAME_WIDTH, 2 * w, bias=False)  # B and C
        self.place = nn.Linear(pose_dims, w, bias=False)  # D
        self.w = w

    def part(self, g):
        """What the gestures alone give: [flat, A·p + b, B·p, C·p, shown], [G, 128 + 3w + 1]."""
        g = g.float()
        flat = torch.relu(self.flat(g.flatten(1)))
        f = torch.relu(self.frame1(torch.relu(self.frame0(g))))
        p = torch.cat([f.mean(1), f.amax(1)], 1)
        shown = (g != 0).flatten(1).any(1, keepdim=True).float()
        return torch.cat([flat, self.out(p), self.turn(p), shown], 1)

    def forward(self, g, pose4, ids=None):
        """`ids` [R] (optional): equal where rows show the same gesture; each is read once."""
        if ids is None:
            part = self.part(g)
        else:
            first, rows = distinct_rows(ids)
            part = self.part(g[first])[rows]
        h, w = self.flat.out_features, self.w
        a, b, c = part[:, h : h + w], part[:, h + w : h + 2 * w], part[:, h + 2 * w : h + 3 * w]
        shown = part[:, -1:]
        turned = b * pose4[:, 2:3] + c * pose4[:, 3:4] + self.place(pose4)
        return torch.cat([part[:, :h], torch.relu(a + shown * turned)], 1)


def mlp(hidden, out, out_gain):
    layers = [nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out)]
    for layer in layers[::2]:
        nn.init.orthogonal_(layer.weight, math.sqrt(2) if layer is not layers[-1] else out_gain)
        nn.init.zeros_(layer.bias)
    return nn.Sequential(*layers)


class Above(nn.Module):
    """Every trained layer below the GRU: the stored inputs → [B, 4 x hidden]."""

    def __init__(self, hidden=256, cells=8 * 8):
        super().__init__()
        self.reduce = nn.Conv2d(64, HEAD_CHANNELS, 1)
        self.fc = nn.Linear(HEAD_CHANNELS * cells, hidden)
        self.gesture = FlatAndTurned(hidden)
        self.target = nn.Embedding(TARGET_CATEGORIES, hidden)
        self.pose = nn.Linear(3, hidden)
        self.out_size = 4 * hidden

    def forward(self, visual, gesture, target, pose, gesture_ids=None):
        v = torch.relu(self.fc(torch.relu(self.reduce(visual)).flatten(1)))
        g = self.gesture(gesture, frame_pose(pose), gesture_ids)
        return torch.cat([v, g, torch.relu(self.target(target)), torch.relu(self.pose(pose))], 1)


class Heads(nn.Module):
    """The actor and critic: 256-256-4 and 256-256-1 (output gains 0.01 and 1, as the default's)."""

    def __init__(self, hidden=256, actions=4):
        super().__init__()
        self.actor = mlp(hidden, actions, 0.01)
        self.critic = mlp(hidden, 1, 1.0)
