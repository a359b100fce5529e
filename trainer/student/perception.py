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
        return self.locate(x).flatten(1)

    def locate(self, x: torch.Tensor) -> torch.Tensor:
        """The keypoints [B, K, 2]: the cells' positions weighted by each map's softmax over them."""
        _, _, h, w = x.shape
        grid = torch.stack([_coords(w, x.device).repeat(h), _coords(h, x.device).repeat_interleave(w)],
                           dim=-1)  # [h*w, (x, y)]
        attention = torch.softmax(self.keypoints(x).flatten(2), dim=-1)
        return attention @ grid


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


class Perception(nn.Module):
    """Depth stack [B, To, H, W] (newest frame last) + normalised hand pose [B, 9] -> (features [B, F],
    readout [B, READOUT] in standardised label units, fine keypoints [B, K, 2] in [-1, 1] image
    coordinates)."""

    def __init__(self, config: StudentConfig) -> None:
        super().__init__()
        width = config.width
        self.resnet = ResNet18(config.obs_horizon, width, config.keypoints)
        self.fine = SpatialSoftmax(2 * width, config.fine_keypoints)
        self.out_features = self.resnet.out_features + self.fine.out_features + 8 * width
        self.readout = nn.Sequential(nn.Linear(self.out_features + HAND_FEATURES, 256), nn.ReLU(),
                                     nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, READOUT))

    def forward(self, depth: torch.Tensor, hand: torch.Tensor) -> tuple[torch.Tensor, ...]:
        r = self.resnet
        stride8 = r.blocks[:4](r.stem(depth))  # stages 1 and 2
        last = r.blocks[4:](stride8)
        fine = self.fine.locate(stride8)
        features = torch.cat([r.pool(last), fine.flatten(1), last.mean(dim=(2, 3))], dim=-1)
        return features, self.readout(torch.cat([features, hand], dim=-1)), fine
