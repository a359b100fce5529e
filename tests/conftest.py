"""Shared fixtures. ``untrained_student_onnx``: a real, exported but untrained student.onnx (tiny width so
it builds in seconds) for runtime, HIL and evaluation tests that need a policy file, not a good policy."""

from __future__ import annotations

import os
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from runtime.preprocess import DepthSpec

# Headless rendering, as `make test` exports it; without it a bare `pytest` aborts in MuJoCo's GLFW default.
os.environ.setdefault("MUJOCO_GL", "egl")

TINY_STUDENT = ("--width", "8", "--head-dims", "16", "32", "--state-features", "16", "--step-features", "16")

SHORT_EPISODE_STEPS = 40


@pytest.fixture
def short_episodes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Episodes cut at ``SHORT_EPISODE_STEPS`` where the recipe and the success evaluation build their world:
    a toy recipe's untrained learner otherwise runs every episode to the full 150 steps, each labelled by
    looking the expert's chunk ahead, which was most of these tests' time."""
    from trainer.eval import success
    from trainer.sim.env import EnvConfig
    from trainer.student import recipe

    for module in (recipe, success):
        monkeypatch.setattr(module, "EnvConfig", partial(EnvConfig, max_steps=SHORT_EPISODE_STEPS))


@pytest.fixture(scope="session")
def untrained_student_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of a freshly initialised tiny student checkpoint (``trainer student init``)."""
    from trainer.student.cli import main as student_main

    path = tmp_path_factory.mktemp("student") / "untrained.pt"
    assert student_main(["init", "--out", str(path), *TINY_STUDENT]) == 0
    return path


@pytest.fixture(scope="session")
def untrained_student_onnx(untrained_student_checkpoint: Path) -> Path:
    """Path of ``student.onnx`` built by ``python -m export CKPT --ddim-steps 4`` from the untrained student:
    the real graph and metadata contract (trained=False), random weights."""
    from export.__main__ import main as export_main

    out = untrained_student_checkpoint.with_suffix(".onnx")
    assert export_main([str(untrained_student_checkpoint), "--ddim-steps", "4", "--out", str(out)]) == 0
    return out


def write_synthetic_demos(path: Path, episodes: int = 2, steps: int = 12, seed: int = 0,
                          spec: DepthSpec | None = None) -> Path:
    """A tiny demo store in the foundation's layout (trainer.dataset) whose actions are a function of what
    the depth shows: a box at an episode-specific column that comes nearer every step, with sensor holes
    (0) along its edge. Joint actions depend on the column and the step; the gripper closes half way.
    ``spec`` may shrink the policy resolution so training tests run in seconds."""
    from trainer.dataset import DemoStore, EpisodeRecord

    rng = np.random.default_rng(seed)
    spec = spec or DepthSpec()
    h, w = spec.out_height, spec.out_width
    store = DemoStore.create(path, spec=spec, action_scale=0.05, control_rate_hz=10.0)
    for ep in range(episodes):
        col = int(rng.integers(w // 16, w * 5 // 8))
        depth = np.full((steps, h, w), 900, np.uint16)
        action = np.zeros((steps, 8), np.float32)
        for t in range(steps):
            depth[t, h // 3:h * 3 // 4, col:col + w // 4] = 800 - 15 * t
            depth[t, h // 3:h * 3 // 4, col] = 0
            action[t, :7] = 0.8 * np.sin(np.pi * col / w + 0.5 * np.arange(7) + 0.3 * t)
            action[t, 7] = 1.0 if t >= steps // 2 else -1.0
        state = np.zeros((steps, 8), np.float32)
        state[:, :7] = np.cumsum(action[:, :7] * 0.05, axis=0)
        state[:, 7] = np.where(action[:, 7] > 0, 0.0, 0.08)
        store.append(EpisodeRecord(depth=depth, state=state, action=action, kind="box", seed=ep,
                                   crop_window=spec.centred_window(), camera_K=np.eye(3),
                                   camera_extrinsics=np.eye(4), randomisation={"object_xy": [col / w, 0.0],
                                                                  "object_yaw": 0.7 * ep - 0.4}))
    return path


@pytest.fixture(scope="session")
def tiny_demos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two synthetic 12-step episodes in a demo store (see ``write_synthetic_demos``)."""
    return write_synthetic_demos(tmp_path_factory.mktemp("demos") / "demos.zarr")


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny untrained DDG model directory (real ONNX export): for the generator's tests and the realism
    measurements that run it."""
    import torch

    from trainer.ddg.graft import HOLE_THRESHOLD
    from trainer.ddg.model import UNetConfig, build_unet, save_model

    torch.manual_seed(0)
    cfg = UNetConfig(channels=(8, 8, 16))
    out = tmp_path_factory.mktemp("ddg") / "model"
    save_model(out, build_unet(cfg).eval(), cfg, DepthSpec(), {"hole_threshold": HOLE_THRESHOLD})
    return out
