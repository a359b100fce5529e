"""The "student:ONNX" policy of ``trainer evaluate``: the exported file run exactly as the runtime runs it
(runtime.policy over onnxruntime, runtime.preprocess normalisation and FrameStack), never through torch.

The graph returns a chunk in robot units; the simulated env takes env actions, so the 7 joint deltas are
divided by the action scale again and the gripper value is thresholded at 0 to -1/+1. The first
``exec_horizon`` actions of each chunk are executed before the policy is asked again (receding horizon); only
the last ``obs_horizon`` frames before each inference are read (the others would leave the stack unused).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np

from runtime.policy import Policy as RuntimePolicy
from runtime.preprocess import FrameStack, normalise
from trainer.dataset import DEPTH_SCALE
from trainer.policies import Observation


class StudentOnnxPolicy:
    def __init__(self, path: str | Path, seed: int = 0) -> None:
        self.runtime = RuntimePolicy(path, seed=seed)
        self.meta = self.runtime.metadata
        self.frames = FrameStack(self.meta.obs_horizon)
        self.queue: deque[np.ndarray] = deque()

    def reset(self, env_info: dict | None = None) -> None:
        """A new episode: empty history; the start noise restarts from the episode's seed where the env names
        it, so an episode's actions do not depend on which episodes this process ran before."""
        self.frames.reset()
        self.queue.clear()
        seed = (env_info or {}).get("episode", {}).get("seed")
        if seed is not None:
            self.runtime.reseed(seed)

    def act(self, obs: Observation) -> np.ndarray:
        if len(self.queue) < self.meta.obs_horizon:  # older frames leave the stack before the next inference
            if obs.depth is None:
                raise ValueError("student policy needs depth observations (the env renders no depth)")
            stack = self.frames.push(normalise(obs.depth, DEPTH_SCALE, self.meta.preprocess))
        if not self.queue:  # (so the push above ran this step)
            chunk = self.runtime(stack, obs.state)
            self.queue.extend(to_env_actions(chunk[: self.meta.exec_horizon], self.meta.action_scale))
        return self.queue.popleft()


def to_env_actions(chunk: np.ndarray, action_scale: float) -> np.ndarray:
    """Robot-unit chunk [T, 8] -> env actions: joint deltas / s clipped to [-1, 1], gripper -1/+1."""
    env = np.empty_like(chunk, dtype=np.float32)
    env[:, :7] = np.clip(chunk[:, :7] / action_scale, -1.0, 1.0)
    env[:, 7] = np.where(chunk[:, 7] > 0, 1.0, -1.0)
    return env


def load(path: str | Path) -> StudentOnnxPolicy:
    return StudentOnnxPolicy(path)
