"""The "student:ONNX" policy of ``trainer evaluate``: the exported file run exactly as the runtime runs it
(runtime.policy over onnxruntime, runtime.preprocess normalisation and FrameStack), never through torch.

The graph returns a chunk in robot units; the simulated env takes env actions, so each action becomes this
step's joint step as the runtime computes it (``runtime.policy.joint_step``) divided by the action scale, and
the gripper value is thresholded at 0 to -1/+1. The first
``exec_horizon`` actions of each chunk are executed before the policy is asked again (receding horizon); only
the last ``obs_horizon`` frames before each inference are read (the others would leave the stack unused).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np

from runtime.metadata import PolicyMetadata
from runtime.policy import Policy as RuntimePolicy
from runtime.policy import joint_step
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
        self.frames.reset()
        self.queue.clear()

    def act(self, obs: Observation) -> np.ndarray:
        if len(self.queue) < self.meta.obs_horizon:  # older frames leave the stack before the next inference
            if obs.depth is None:
                raise ValueError("student policy needs depth observations (the env renders no depth)")
            stack = self.frames.push(normalise(obs.depth, DEPTH_SCALE, self.meta.preprocess))
        if not self.queue:  # (so the push above ran this step)
            chunk = self.runtime(stack, obs.state)
            self.queue.extend(chunk[: self.meta.exec_horizon])
        return to_env_action(self.queue.popleft(), obs.state, self.meta)


def to_env_action(action: np.ndarray, state: np.ndarray, meta: PolicyMetadata) -> np.ndarray:
    """One robot-unit action [8] at joint state ``state`` -> env action: the runtime's joint step / s clipped
    to [-1, 1], gripper -1/+1."""
    env = np.empty(8, dtype=np.float32)
    env[:7] = np.clip(joint_step(action, state, meta) / meta.action_scale, -1.0, 1.0)
    env[7] = 1.0 if action[7] > 0 else -1.0
    return env


def load(path: str | Path) -> StudentOnnxPolicy:
    return StudentOnnxPolicy(path)
