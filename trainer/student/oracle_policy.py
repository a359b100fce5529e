"""The "oracle:CKPT[@BIAS_CM]" policy of ``trainer evaluate`` and the DAgger rounds: a
``perception="privileged"`` student (milestone M0: the action head alone, with perfect perception) run in
torch on the true object facts, read off the env's observation as ``trainer.sim.labels.facts`` computes them
for every recorded frame.

``@BIAS_CM`` adds a constant error of that many centimetres to the facts' object offset, in a horizontal
direction drawn from the episode's seed: how precisely perception must place the object for the head to grasp.
Chunks are executed as the ONNX student's are (``exec_horizon`` actions, then a new inference), from start
noise drawn from the episode's seed.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np
import torch

from trainer.policies import Observation, PolicyError, aim_bias_m
from trainer.sim.labels import OFFSET, facts
from trainer.student import checkpoint
from trainer.student.ddim import ddim_plan, denoise
from trainer.student.onnx_policy import to_env_actions
from trainer.teacher.scripted import aim_bias

DDIM_STEPS = 4
"""The exported students' default (``python -m export --ddim-steps``)."""


class OraclePolicy:
    def __init__(self, path: str | Path, bias_m: float = 0.0) -> None:
        ckpt = checkpoint.load(Path(path))
        if ckpt.config.perception != "privileged":
            raise PolicyError(f"{path} is not a privileged (oracle) student: perception="
                              f"{ckpt.config.perception!r}")
        torch.set_num_threads(1)  # one per rollout worker
        self.net, self.config = ckpt.policy(), ckpt.config
        self.plan = ddim_plan(ckpt.config.train_timesteps, DDIM_STEPS)
        self.bias_m = bias_m
        self.queue: deque[np.ndarray] = deque()
        self._extent, self._bias = np.zeros(3), np.zeros(3)
        self._rng = np.random.default_rng(0)

    def reset(self, env_info: dict) -> None:
        self.queue.clear()
        self._extent = np.asarray(env_info["object_half_extent"], float)
        self._rng = np.random.default_rng(env_info["episode"]["seed"])
        self._bias = aim_bias(self._rng, self.bias_m)

    def read_facts(self, obs: Observation) -> np.ndarray:
        """The facts the head reads at a new chunk: the true ones, the offset biased by ``bias_m``."""
        row = facts(obs.privileged, self._extent)
        row[OFFSET] += self._bias
        return row

    def act(self, obs: Observation) -> np.ndarray:
        if not self.queue:
            row = self.read_facts(obs)
            noise = self._rng.standard_normal((1, self.config.action_horizon, self.config.action_dim))
            with torch.no_grad():
                obs_t = self.net.encode(torch.from_numpy(row[None]), torch.from_numpy(obs.state[None]))
                x = denoise(self.net, obs_t, torch.from_numpy(noise.astype(np.float32)), self.plan,
                            self.config.prediction)
                chunk = self.net.action_norm.unnormalise(x)[0].numpy()
            self.queue.extend(to_env_actions(chunk[: self.config.exec_horizon], 1.0))  # env units already
        return self.queue.popleft()


def load(spec: str) -> OraclePolicy:
    path, _, bias = spec.partition("@")
    return OraclePolicy(path, aim_bias_m(f"oracle:{spec}", bias))
