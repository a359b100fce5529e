"""Student network: ResNet-18 (GroupNorm) over stacked depth + MLP over joint state, fused into the
condition of a 1-D conditional U-Net that predicts the noise added to a normalised action chunk.

Why a 1-D U-Net head rather than an MLP: its temporal convolutions share weights along the chunk, which
is what keeps diffusion_policy's action chunks smooth, and it is small at our Ha=16 (three levels, 16->8->4).
GroupNorm instead of BatchNorm: batch statistics drift under EMA and tiny batches (diffusion_policy does
the same); it also exports as plain ONNX ops with no running statistics to carry.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from runtime.franka_driver.kinematics import HIL_SIM_Q_OFFSET, tcp_frame
from trainer.sim.labels import GRASP_YAW, READOUT
from trainer.student.config import StudentConfig
from trainer.student.data import column_scale
from trainer.student.normaliser import RangeNormaliser
from trainer.student.perception import HAND_FEATURES, Perception, ResNet18


def step_embedding(steps: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding of diffusion steps [B] -> [B, dim]."""
    half = dim // 2
    k = torch.arange(half, dtype=torch.float32, device=steps.device)
    freqs = torch.exp(-math.log(10000.0) * k / max(half - 1, 1))
    angles = steps.float()[:, None] * freqs[None, :]
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


class ConvBlock1d(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int = 5) -> None:
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(8, c_out),
                         nn.Mish())


class CondResBlock1d(nn.Module):
    """Two conv blocks with FiLM (per-channel scale and bias) from the condition in between."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int) -> None:
        super().__init__()
        self.block1 = ConvBlock1d(c_in, c_out)
        self.block2 = ConvBlock1d(c_out, c_out)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.shortcut = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        scale, bias = self.film(cond)[:, :, None].chunk(2, dim=1)
        y = self.block1(x) * scale + bias
        return self.block2(y) + self.shortcut(x)


class ConditionalUnet1d(nn.Module):
    """Noise prediction over an action chunk [B, Ha, A], conditioned on the diffusion step and observation."""

    def __init__(self, action_dim: int, obs_dim: int, dims: tuple[int, ...], step_features: int) -> None:
        super().__init__()
        self.step_features = step_features
        self.step_mlp = nn.Sequential(nn.Linear(step_features, 4 * step_features), nn.Mish(),
                                      nn.Linear(4 * step_features, step_features))
        cond = step_features + obs_dim
        chans = [action_dim, *dims]
        self.down = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(zip(chans[:-1], chans[1:], strict=True)):
            last = i == len(dims) - 1
            self.down.append(nn.ModuleList([
                CondResBlock1d(c_in, c_out, cond), CondResBlock1d(c_out, c_out, cond),
                nn.Identity() if last else nn.Conv1d(c_out, c_out, 3, 2, 1)]))
        self.mid = nn.ModuleList([CondResBlock1d(dims[-1], dims[-1], cond) for _ in range(2)])
        self.up = nn.ModuleList()
        for c_out, c_in in reversed(list(zip(dims[:-1], dims[1:], strict=True))):
            self.up.append(nn.ModuleList([
                CondResBlock1d(2 * c_in, c_out, cond), CondResBlock1d(c_out, c_out, cond),
                nn.ConvTranspose1d(c_out, c_out, 4, 2, 1)]))
        self.final = nn.Sequential(ConvBlock1d(dims[0], dims[0]), nn.Conv1d(dims[0], action_dim, 1))

    def forward(self, sample: torch.Tensor, steps: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        cond = torch.cat([self.step_mlp(step_embedding(steps, self.step_features)), obs], dim=-1)
        x = sample.transpose(1, 2)
        skips = []
        for res1, res2, down in self.down:
            x = res2(res1(x, cond), cond)
            skips.append(x)
            x = down(x)
        for res in self.mid:
            x = res(x, cond)
        # As diffusion_policy: the deepest skips feed the up path; each up level restores one halving.
        for (res1, res2, up), skip in zip(self.up, reversed(skips[1:]), strict=True):
            x = up(res2(res1(torch.cat([x, skip], dim=1), cond), cond))
        return self.final(x).transpose(1, 2)


def state_inputs(config: StudentConfig) -> int:
    """Width of the state MLP's input: the state, the hand pose (9) and the object's offset from it (2 for
    each of ``object_offset`` and ``seen_offset``)."""
    readings = config.object_offset + config.seen_offset
    return config.state_dim + HAND_FEATURES * config.hand_pose + 2 * readings


def object_outputs(config: StudentConfig) -> int:
    """Outputs of the object head: the object's table position (2), then with ``hand_target`` the hand
    relative to it (3)."""
    return 2 + 3 * config.hand_target


def into_fingers(doubled_yaw: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
    """(cos, sin) of twice the object's yaw on the table [B, 2] -> of twice its yaw from the fingers'
    closing axis, the hand frame's second axis (``hand_pose`` [B, 9], features 6:9), by the identities of an
    angle difference: no atan2 in the exported graph."""
    axis = hand[:, 6:8] / hand[:, 6:8].norm(dim=-1, keepdim=True).clamp_min(1e-6)
    cos_f, sin_f = axis[:, 0] ** 2 - axis[:, 1] ** 2, 2 * axis[:, 0] * axis[:, 1]  # twice the fingers' yaw
    cos_o, sin_o = doubled_yaw[:, 0], doubled_yaw[:, 1]
    return torch.stack([cos_o * cos_f + sin_o * sin_f, sin_o * cos_f - cos_o * sin_f], dim=-1)


def hand_pose(state: torch.Tensor) -> torch.Tensor:
    """Joint state [B, 8] -> [B, 9]: the hand's position (robot base frame, m) and the first two axes of its
    frame, by the Panda's forward kinematics (traced into the graph as constants and trigonometry) of the
    simulator's joint angles, which the students are trained on, made libfranka's."""
    offset = torch.tensor(HIL_SIM_Q_OFFSET, dtype=state.dtype, device=state.device)
    pos, rot = tcp_frame(state[:, :7] + offset, torch)
    return torch.cat([pos, rot[..., 0], rot[..., 1]], dim=-1)


class StudentPolicy(nn.Module):
    """epsilon_phi(a_k, k, obs) of paper eq. 10. States enter raw and are normalised inside; actions are
    handled in normalised units, ``action_norm`` converts them back to env units."""

    def __init__(self, config: StudentConfig) -> None:
        super().__init__()
        self.config = config
        self.state_norm = RangeNormaliser(config.state_dim)
        self.action_norm = RangeNormaliser(config.action_dim)
        self.hand_norm = RangeNormaliser(HAND_FEATURES) if config.hand_pose else None
        self.object_norm = RangeNormaliser(2) if config.object_offset else None
        """The object head's units (standardised table position) -> metres: centre = mean, half_range = std
        of the training demos' object positions, as ``trainer.student.data.standardise``."""
        self.offset_norm = RangeNormaliser(2) if config.object_offset else None
        self.encoder = ResNet18(config.obs_horizon, config.width, config.keypoints)
        self.state_mlp = nn.Sequential(nn.Linear(state_inputs(config), config.state_features),
                                       nn.ReLU(), nn.Linear(config.state_features, config.state_features))
        obs_dim = self.encoder.out_features + config.state_features
        self.head = ConditionalUnet1d(config.action_dim, obs_dim, config.head_dims, config.step_features)
        self.object_head = nn.Linear(self.encoder.out_features, object_outputs(config))
        """Training only unless a state input reads it: the object's table position from the depth features,
        then (``hand_target``) the hand's offset from it (``trainer.student.data.privileged_targets``)."""

    def encode(self, depth: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Preprocessed depth [B, To, H, W] + raw state [B, S] -> observation feature [B, F]."""
        return self.fuse(self.encoder(depth), state)

    def fuse(self, depth_features: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        return torch.cat([depth_features, self.state_mlp(self.state_input(depth_features, state))], dim=-1)

    def state_input(self, depth_features: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The state MLP's input: the normalised state, then (``hand_pose``) the normalised hand pose, then
        (``object_offset``) the normalised offset of the object head's estimate from the hand, then
        (``seen_offset``) the object head's own reading of that offset, in its standardised units."""
        parts = [self.state_norm.normalise(state)]
        if self.config.hand_pose:
            hand = hand_pose(state)
            parts.append(self.hand_norm.normalise(hand))
        if not (self.config.object_offset or self.config.seen_offset):
            return torch.cat(parts, dim=-1)
        estimate = self.object_head(depth_features)
        if self.config.object_offset:
            # world-frame table position; the robot base is at the world's x, y origin, so frames agree
            located = self.object_norm.unnormalise(estimate[:, :2])
            parts.append(self.offset_norm.normalise(located - hand[:, :2]))
        if self.config.seen_offset:
            parts.append(estimate[:, 2:4])
        return torch.cat(parts, dim=-1)

    def fit_normalisers(self, state: np.ndarray, action: np.ndarray,
                        targets: np.ndarray | None = None) -> None:
        """Statistics of the training demos: min-max of states, actions and (``hand_pose``) hand poses;
        with ``object_offset`` also the object positions (``targets`` [N, 2+], the privileged targets: mean,
        std) and their offsets from the hand (min-max)."""
        self.state_norm.fit(state.min(0), state.max(0))
        self.action_norm.fit(action.min(0), action.max(0))
        if not self.config.hand_pose:
            return
        with torch.no_grad():
            hands = hand_pose(torch.from_numpy(np.asarray(state, np.float32))).numpy()
        self.hand_norm.fit(hands.min(0), hands.max(0))
        if not self.config.object_offset:
            return
        if targets is None:
            raise ValueError("object_offset needs the demos' privileged targets")
        objects = targets[:, :2]
        mean, std = column_scale(objects)
        self.object_norm.fit(mean - std, mean + std)
        offsets = objects - hands[:, :2]
        self.offset_norm.fit(offsets.min(0), offsets.max(0))

    def forward(self, noisy_actions: torch.Tensor, steps: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.head(noisy_actions, steps, obs)


class PerceptionStudent(nn.Module):
    """The recipe's student (``StudentConfig.perception``): the action head conditioned on the depth features
    and on the state MLP's reading of the joint state, the hand's pose by forward kinematics and the object's
    facts (``trainer.sim.labels.READOUT``: offset from the hand, grasp direction, size) with the grasp
    direction turned into the fingers' frame. The facts come from ``Perception``'s readout of depth, or, for
    the "privileged" oracle, from the simulator. Same interface as ``StudentPolicy`` for export."""

    def __init__(self, config: StudentConfig) -> None:
        super().__init__()
        self.config = config
        self.state_norm = RangeNormaliser(config.state_dim)
        self.action_norm = RangeNormaliser(config.action_dim)
        self.hand_norm = RangeNormaliser(HAND_FEATURES)
        self.label_norm = RangeNormaliser(READOUT)
        """Facts in metres -> standardised units: centre = mean, half_range = std over the training steps."""
        depth = config.perception == "depth"
        self.perception = Perception(config) if depth else None
        self.partners = nn.ModuleList(Perception(config) for _ in range(config.perceptions - 1))
        """More perceptions whose facts are averaged with the first's (``StudentConfig.perceptions``)."""
        features = self.perception.out_features if depth and config.head_features else 0
        inputs = config.state_dim + HAND_FEATURES + READOUT + 2
        self.state_mlp = nn.Sequential(nn.Linear(inputs, config.state_features), nn.ReLU(),
                                       nn.Linear(config.state_features, config.state_features))
        self.head = ConditionalUnet1d(config.action_dim, features + config.state_features, config.head_dims,
                                      config.step_features)

    def perceive(self, depth: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(features, standardised facts, fine keypoints) of a depth stack: ``Perception``'s outputs, the
        facts averaged over the partners' where there are partners."""
        hand = self.hand_norm.normalise(hand_pose(state))
        features, facts, fine = self.perception(depth, hand)
        if self.partners:
            facts = torch.stack([facts, *(partner(depth, hand)[1] for partner in self.partners)]).mean(dim=0)
        return features, facts, fine

    def encode(self, observation: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Depth stack [B, To, H, W] (or, privileged, the true label rows [B, >= READOUT]) + raw state [B, S]
        -> observation feature [B, F]."""
        if self.perception is None:
            features = observation.new_zeros(observation.shape[0], 0)
            return self.fuse(features, self.label_norm.normalise(observation[:, :READOUT]), state)
        features, facts, _ = self.perceive(observation, state)
        return self.fuse(features, facts, state)

    def fuse(self, features: torch.Tensor, facts: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        if not self.config.head_features:
            features = features[:, :0]
        hand = hand_pose(state)
        turn = into_fingers(self.label_norm.unnormalise(facts)[:, GRASP_YAW], hand)
        x = torch.cat([self.state_norm.normalise(state), self.hand_norm.normalise(hand), facts, turn], dim=-1)
        return torch.cat([features, self.state_mlp(x)], dim=-1)

    def fit_normalisers(self, state: np.ndarray, action: np.ndarray, labels: np.ndarray) -> None:
        """Min-max of states, actions and hand poses; mean and std of the facts (``labels`` [N, >= 8])."""
        self.state_norm.fit(state.min(0), state.max(0))
        flat = action.reshape(-1, action.shape[-1])  # steps' actions or chunks
        self.action_norm.fit(flat.min(0), flat.max(0))
        with torch.no_grad():
            hands = hand_pose(torch.from_numpy(np.asarray(state, np.float32))).numpy()
        self.hand_norm.fit(hands.min(0), hands.max(0))
        mean, std = column_scale(labels[:, :READOUT])
        self.label_norm.fit(mean - std, mean + std)

    def forward(self, noisy_actions: torch.Tensor, steps: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.head(noisy_actions, steps, obs)


def build_policy(config: StudentConfig) -> nn.Module:
    """The network a configuration describes: the recipe's ``PerceptionStudent`` or the earlier
    ``StudentPolicy``."""
    return PerceptionStudent(config) if config.perception else StudentPolicy(config)
