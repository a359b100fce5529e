"""Training samples from a demo store: (3 stacked depth frames, state, action chunk) per time step.

Depth goes through ``runtime.preprocess.normalise`` (the one implementation) and is stacked with the
FrameStack rule (an episode's first frame fills the history), so a sample equals what the runtime feeds
the policy at that step; tests/student/test_preprocess_parity.py proves it bit for bit. Action chunks
that run past the episode end repeat its last action (diffusion_policy pads the same way).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hil_sim.kinematics import ArmKinematics
from hil_sim.world import TABLE_Z
from runtime.preprocess import DepthSpec, normalise
from trainer.dataset import DEPTH_SOURCES, DatasetError, DemoStore, sizes


class DemoDataError(ValueError):
    """A demo store or depth source the student cannot train on."""


@dataclass(frozen=True)
class Batch:
    depth: torch.Tensor
    """float32 [B, To, H, W], preprocessed, oldest frame first."""
    state: torch.Tensor
    """float32 [B, 8], raw units."""
    action: torch.Tensor
    """float32 [B, Ha, 8], env units (joint deltas in [-1, 1] before s, gripper -1/+1)."""
    targets: torch.Tensor | None
    """float32 [B, 2 or 5]: ``privileged_targets`` standardised over the demos (sim-only: the auxiliary
    loss's target, never a policy input); None when the store does not record the object's position."""


def frame_augmenter(depth_source: str) -> Callable[[np.ndarray, np.random.Generator], np.ndarray] | None:
    """The procedural noise for ``randnoise`` (trainer.ddg's baseline), None for stored sources."""
    if depth_source != "randnoise":
        return None
    from trainer.ddg.baselines import randnoise
    return randnoise


class DemoDataset:
    """All of a store's steps in memory (uint16 depth: ~25 kB per step)."""

    def __init__(self, path: str | Path, depth_source: str, obs_horizon: int, action_horizon: int,
                 hand_target: bool = False, episodes: int = 0) -> None:
        """``episodes``: only the store's first this many (0 = all). ``hand_target``: the privileged targets'
        columns (``privileged_targets``)."""
        if depth_source not in DEPTH_SOURCES:
            raise DemoDataError(f"unknown depth source {depth_source!r}; "
                                f"choose one of {sorted(DEPTH_SOURCES)}")
        store = DemoStore.open(path)
        self.ends = first_episodes(store.episode_ends, episodes, path)
        n = int(self.ends[-1])
        try:
            self.depth = store.depth(depth_source, n)
        except DatasetError as exc:  # the student's own error: a depth source it cannot train on
            raise DemoDataError(str(exc)) from None
        self.state = np.asarray(store.root["data/state"][:n], dtype=np.float32)
        self.action = np.asarray(store.root["data/action"][:n], dtype=np.float32)
        attrs = store.attrs
        self.spec = DepthSpec.from_dict(attrs["depth_spec"])
        self.depth_scale = float(attrs["depth_scale"])
        self.action_scale = float(attrs["action_scale"])
        self.control_rate_hz = float(attrs["control_rate_hz"])
        self.depth_source, self.path = depth_source, Path(path)
        self.obs_horizon, self.action_horizon = obs_horizon, action_horizon
        self.augment = frame_augmenter(depth_source)
        starts = np.concatenate([[0], self.ends[:-1]])
        steps_per_ep = self.ends - starts
        self._start = np.repeat(starts, steps_per_ep)
        self._end = np.repeat(self.ends, steps_per_ep)
        self.raw_targets = privileged_targets(store, hand_target, n)
        self.targets = None if self.raw_targets is None else standardise(self.raw_targets)

    @classmethod
    def stacked_as(cls, path: str | Path, depth_source: str, policy, spec: DepthSpec | None = None,
                   **kwargs) -> DemoDataset:
        """The store's steps stacked as ``policy`` reads them: its ``StudentConfig`` or its file's
        ``PolicyMetadata`` (``obs_horizon``, ``action_horizon``). ``spec``: the crop and resolution the policy
        was trained on; a store of other depth is refused (the encoder would run on it)."""
        data = cls(path, depth_source, policy.obs_horizon, policy.action_horizon, **kwargs)
        if spec is not None and data.spec != spec:
            raise DemoDataError(f"{path} holds {sizes(data.spec)}; the policy reads {sizes(spec)}")
        return data

    def __len__(self) -> int:
        return len(self.action)

    def frame_indices(self, i: int) -> np.ndarray:
        """Steps of the depth frames stacked at step ``i``, oldest first, clamped to the episode start."""
        return np.maximum(np.arange(i - self.obs_horizon + 1, i + 1), self._start[i])

    def action_indices(self, i: int) -> np.ndarray:
        return np.minimum(np.arange(i, i + self.action_horizon), self._end[i] - 1)

    def depth_stack(self, i: int, rng: np.random.Generator | None = None) -> np.ndarray:
        frames = self.depth[self.frame_indices(i)]
        if self.augment is not None:
            rng = rng if rng is not None else np.random.default_rng()
            frames = np.stack([self.augment(f, rng) for f in frames])
        return np.stack([normalise(f, self.depth_scale, self.spec) for f in frames])

    def batch(self, indices: np.ndarray, rng: np.random.Generator | None = None) -> Batch:
        depth = np.stack([self.depth_stack(int(i), rng) for i in indices])
        action = np.stack([self.action[self.action_indices(int(i))] for i in indices])
        targets = None if self.targets is None else torch.from_numpy(self.targets[indices])
        return Batch(torch.from_numpy(depth), torch.from_numpy(self.state[indices]), torch.from_numpy(action),
                     targets)

    def fingerprint(self) -> dict:
        """Identifies the training data in the policy file's metadata."""
        h = hashlib.sha256()
        for arr in (self.ends, self.state, self.action):
            h.update(np.ascontiguousarray(arr).tobytes())
        return {"demos": str(self.path.resolve()), "depth_source": self.depth_source,
                "episodes": len(self.ends), "steps": len(self),
                "demos_sha256": h.hexdigest()[:16]}


def first_episodes(ends: np.ndarray, episodes: int, path: str | Path) -> np.ndarray:
    """The episode ends of the store's first ``episodes`` episodes (0 = all of them)."""
    if len(ends) == 0:
        raise DemoDataError(f"{path} holds no episodes")
    if not 0 <= episodes <= len(ends):
        raise DemoDataError(f"--episodes {episodes}: {path} holds {len(ends)} episodes")
    return ends[:episodes or len(ends)]


def object_positions(store: DemoStore) -> np.ndarray | None:
    """Per step [N, 2], metres: where the step's object was placed (``object_xy`` of the episode's recorded
    randomisation), or None if an episode does not record it."""
    return per_step(store, "object_xy", 2)


def per_step(store: DemoStore, key: str, width: int) -> np.ndarray | None:
    """The episodes' recorded randomisation ``key`` repeated over their steps [N, width], or None if an
    episode does not record it."""
    draws = [json.loads(str(r)) for r in store.root["meta/randomisation"][:]]
    if not all(key in d for d in draws):
        return None
    per_episode = np.array([d[key] for d in draws], dtype=np.float32).reshape(-1, width)
    return np.repeat(per_episode, store.episode_lengths, axis=0)


def privileged_targets(store: DemoStore, hand_target: bool, steps: int | None = None) -> np.ndarray | None:
    """Per step [N, 2], metres: the object's table position (``object_positions``); with ``hand_target``
    [N, 5]: then the hand relative to it, from the recorded joint state by forward kinematics (object minus
    grasp site in x and y, and the grasp site's height above the table), which decides where to move and
    when to close. None if an episode does not record the object's position. ``steps``: the first this many
    steps only."""
    placed = object_positions(store)
    if placed is None:
        return None
    placed = placed[:steps]
    if not hand_target:
        return placed
    kinematics = ArmKinematics()
    state = np.asarray(store.root["data/state"][: len(placed)], dtype=np.float64)
    hand = np.array([kinematics.site(np.r_[q[:7], 0.0, 0.0])[0] for q in state])  # fingers: no effect
    return np.column_stack([placed, placed - hand[:, :2], hand[:, 2] - TABLE_Z]).astype(np.float32)


def training_targets(data: dict, hand_target: bool) -> np.ndarray | None:
    """``privileged_targets`` of the demos a checkpoint was trained on (its ``info.data`` fingerprint): the
    reference its object head's units are standardised over."""
    return privileged_targets(DemoStore.open(data["demos"]), hand_target, data.get("steps"))


def column_scale(reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and (floored) std of each column of ``reference``: the auxiliary loss's units."""
    return reference.mean(0), np.maximum(reference.std(0), 1e-6)


def standardise(values: np.ndarray) -> np.ndarray:
    """Metres -> the auxiliary loss's units: zero mean, unit std per column over the training demos."""
    mean, std = column_scale(values)
    return ((values - mean) / std).astype(np.float32)
