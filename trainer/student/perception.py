"""Dense privileged perception: the depth encoder of a ``perception="depth"`` student and what it reads.

The old students pooled a ResNet-18's last map, 4 x 3 cells at 128 x 96 (stride 32), and read the object's
position off it to ~0.8 cm, about a pixel, while the world tolerates ~0.5 cm of constant aiming bias. Here:
- keypoints (spatial softmax) also on the stride-8 map (16 x 12 cells), the first two of them supervised to
  the object centre's and the grasp site's pixels (``trainer.sim.labels``): dense, simulator-only labels
  that tie the attention to where the object and the hand are, to a fraction of a cell;
- a readout MLP from the features and the hand's pose (forward kinematics) to the object's offset from the
  hand, its grasp direction and its size (``labels.READOUT``), trained on every frame of the expert's demos
  and the student's own DAgger rollouts, whose hand positions the expert never shows.
The action head reads the readout (standardised, as the labels are) beside the features: the facts the
oracle head grasps with, estimated from depth.
"""

from __future__ import annotations

import torch
from torch import nn

from trainer.sim.labels import READOUT
from trainer.student.config import StudentConfig

SUPERVISED_KEYPOINTS = 2
"""Fine keypoints 0 and 1 are pulled to the object's and the hand's pixels."""
HAND_FEATURES = 9
"""The hand's pose by forward kinematics (``trainer.student.model.hand_pose``): position and two axes."""


def _groups(channels: int) -> int:
    return max(1, channels // 16)


class BasicBlock(nn.Module):
    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.norm1 = nn.GroupNorm(_groups(c_out), c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.norm2 = nn.GroupNorm(_groups(c_out), c_out)
        self.shortcut = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.shortcut = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False),
                                          nn.GroupNorm(_groups(c_out), c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = torch.relu(self.norm1(self.conv1(x)))
        return torch.relu(self.norm2(self.conv2(y)) + self.shortcut(x))


class SpatialSoftmax(nn.Module):
    """Feature map [B, C, h, w] -> [B, 2K]: the expected image position (x, y in [-1, 1]) of each of K
    learned keypoint maps. Global average pooling throws away *where* the object is, which is the one
    thing a grasping policy must read from depth; diffusion_policy (after robomimic) pools this way."""

    def __init__(self, channels: int, keypoints: int) -> None:
        super().__init__()
        self.keypoints = nn.Conv2d(channels, keypoints, 1)
        self.out_features = 2 * keypoints

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.locate(x)[0].flatten(1)

    def locate(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(keypoints [B, K, 2], their attention over the map's cells [B, K, h*w])."""
        _, _, h, w = x.shape
        grid = torch.stack([_coords(w, x.device).repeat(h), _coords(h, x.device).repeat_interleave(w)],
                           dim=-1)  # [h*w, (x, y)]
        attention = torch.softmax(self.keypoints(x).flatten(2), dim=-1)
        return attention @ grid, attention


def _coords(n: int, device: torch.device) -> torch.Tensor:
    """n pixel centres spread over [-1, 1] (float32 arithmetic, which exports as plain constants)."""
    return torch.arange(n, dtype=torch.float32, device=device) * (2.0 / max(n - 1, 1)) - 1.0


class ResNet18(nn.Module):
    """ResNet-18 layout (stem + 4 stages of 2 basic blocks), trained from scratch: no weights to fetch,
    pooled by ``SpatialSoftmax`` instead of the classifier's global average."""

    def __init__(self, in_channels: int, width: int, keypoints: int) -> None:
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(in_channels, width, 7, 2, 3, bias=False),
                                  nn.GroupNorm(_groups(width), width), nn.ReLU(), nn.MaxPool2d(3, 2, 1))
        chans = [width, 2 * width, 4 * width, 8 * width]
        blocks = []
        for i, c in enumerate(chans):
            c_in = chans[max(i - 1, 0)]
            blocks += [BasicBlock(c_in, c, 1 if i == 0 else 2), BasicBlock(c, c, 1)]
        self.blocks = nn.Sequential(*blocks)
        self.pool = SpatialSoftmax(chans[-1], keypoints)
        self.out_features = self.pool.out_features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.pool(self.blocks(self.stem(x)))


GEOMETRY_FEATURES = 5
"""``geometric`` readout inputs: the supervised keypoints' difference (x, y) and the depths under them."""
GEOMETRY_GAIN = 10.0
"""Scales those inputs so that a centimetre is ~0.1 (a pixel is 0.016 in keypoint units, a centimetre of depth
0.008 after ``runtime.preprocess.normalise``), where the readout's first layer starts out sensitive."""


class Perception(nn.Module):
    """Depth stack [B, To, H, W] (newest frame last) + normalised hand pose [B, 9] -> (features [B, F],
    readout [B, READOUT] in standardised label units, fine keypoints [B, K, 2] in [-1, 1] image
    coordinates)."""

    def __init__(self, config: StudentConfig) -> None:
        super().__init__()
        width, fine_keypoints = config.width, config.fine_keypoints
        self.resnet = ResNet18(config.obs_horizon, width, config.keypoints)
        # stride 4: the stride-8 map upsampled beside the first stage's (stride 4), mixed by one convolution
        self.pyramid = (nn.Sequential(nn.Conv2d(3 * width, 2 * width, 3, 1, 1, bias=False),
                                      nn.GroupNorm(_groups(2 * width), 2 * width), nn.ReLU())
                        if config.fine_stride == 4 else None)
        self.fine = SpatialSoftmax(2 * width, fine_keypoints)
        self.values = (nn.Conv2d(2 * width, fine_keypoints * config.keypoint_values, 1)
                       if config.keypoint_values else None)
        self.geometric, self.readout_global = config.geometric, config.readout_global
        self.out_features = self.resnet.out_features + self.fine.out_features + 8 * width
        self.layout = readout_layout(config)
        self.readout = nn.Sequential(nn.Linear(sum(n for _, n in self.layout), 256), nn.ReLU(),
                                     nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, READOUT))

    def forward(self, depth: torch.Tensor, hand: torch.Tensor) -> tuple[torch.Tensor, ...]:
        fine_map, last = self.maps(depth)
        fine, attention = self.fine.locate(fine_map)
        keypoints = torch.cat([self.resnet.pool(last), fine.flatten(1)], dim=-1)
        pooled = last.mean(dim=(2, 3))
        inputs = [keypoints, pooled, hand] if self.readout_global else [keypoints, hand]
        if self.geometric:
            inputs.append(geometry(fine, attention, depth[:, -1:], fine_map.shape[-2:]))
        if self.values is not None:
            inputs.append(looked_at(self.values(fine_map), attention))
        features = torch.cat([keypoints, pooled], dim=-1)
        return features, self.readout(torch.cat(inputs, dim=-1)), fine

    def columns(self, block: str) -> slice:
        """Where the readout's first layer reads the block of inputs named ``block`` (``readout_layout``)."""
        start = 0
        for name, n in self.layout:
            if name == block:
                return slice(start, start + n)
            start += n
        raise KeyError(f"the readout reads no {block!r} inputs")

    def maps(self, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(the fine keypoints' map, the last stage's map) of a depth stack."""
        r = self.resnet
        stride4 = r.blocks[:2](r.stem(depth))  # stage 1
        stride8 = r.blocks[2:4](stride4)  # stage 2
        last = r.blocks[4:](stride8)
        if self.pyramid is None:
            return stride8, last
        up = nn.functional.interpolate(stride8, size=stride4.shape[-2:], mode="nearest")
        return self.pyramid(torch.cat([stride4, up], dim=1)), last


def geometry(fine: torch.Tensor, attention: torch.Tensor, frame: torch.Tensor, cells: torch.Size
             ) -> torch.Tensor:
    """The object keypoint minus the hand keypoint (x, y), the depth under each (the frame averaged over each
    cell, weighted by the keypoint's attention) and their difference, times ``GEOMETRY_GAIN``: [B, 5]."""
    cell_depth = nn.functional.adaptive_avg_pool2d(frame, cells).flatten(1)  # [B, h*w]
    z = (attention[:, :SUPERVISED_KEYPOINTS] * cell_depth[:, None]).sum(-1)  # [B, 2]: object, hand
    return GEOMETRY_GAIN * torch.cat([fine[:, 0] - fine[:, 1], z, z[:, :1] - z[:, 1:]], dim=-1)


def looked_at(values: torch.Tensor, attention: torch.Tensor) -> torch.Tensor:
    """Each keypoint's values [B, K * V, h, w] averaged under its attention [B, K, h*w]: [B, K * V]."""
    b, k, cells = attention.shape
    per_keypoint = values.reshape(b, k, -1, cells)  # [B, K, V, h*w]
    return (per_keypoint * attention[:, :, None]).sum(-1).flatten(1)


def readout_layout(config: StudentConfig) -> list[tuple[str, int]]:
    """The readout's input columns in order, as (name, count): what a refit keeps of a source's first layer
    (``research/perception_arms.py``)."""
    layout = [("keypoints", 2 * (config.keypoints + config.fine_keypoints))]
    if config.readout_global:
        layout.append(("global", 8 * config.width))
    layout.append(("hand", HAND_FEATURES))
    if config.geometric:
        layout.append(("geometry", GEOMETRY_FEATURES))
    if config.keypoint_values:
        layout.append(("values", config.fine_keypoints * config.keypoint_values))
    return layout
