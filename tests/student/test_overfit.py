"""A tiny student trained by ``trainer student fit`` fits a tiny demo set: its eq. 10 noise-prediction
error on the training samples (fixed noise, several diffusion steps) falls well below the untrained one."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from runtime.preprocess import DepthSpec
from tests.conftest import write_synthetic_demos
from trainer.diffusion import training_target
from trainer.student import checkpoint
from trainer.student.data import DemoDataset
from trainer.student.ddim import training_scheduler
from trainer.student.model import StudentPolicy
from trainer.student.train import main as fit_main

TINY = ["--width", "8", "--head-dims", "32", "64", "--state-features", "16", "--step-features", "16",
        "--action-horizon", "8", "--exec-horizon", "8", "--threads", "1"]


def denoising_error(net: StudentPolicy, data: DemoDataset, steps=(30, 60, 84)) -> float:
    """Mean eq. 10 loss over all samples at fixed diffusion steps with fixed noise."""
    batch = data.batch(np.arange(len(data)))
    sched = training_scheduler(net.config.train_timesteps, net.config.prediction)
    clean = net.action_norm.normalise(batch.action)
    errors = []
    with torch.no_grad():
        obs = net.encode(batch.depth, batch.state)
        for k in steps:
            noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(k))
            kk = torch.full((len(clean),), k)
            target = training_target(sched, clean, noise, kk)
            errors.append(float(torch.mean((net(sched.add_noise(clean, noise, kk), kk, obs) - target) ** 2)))
    return float(np.mean(errors))


@pytest.mark.slow
def test_tiny_policy_fits_tiny_demo_set(tmp_path):
    demos = write_synthetic_demos(tmp_path / "demos.zarr", episodes=1, steps=6,
                                  spec=DepthSpec(out_height=24, out_width=32))
    out = tmp_path / "run"
    args = ["--demos", str(demos), "--out", str(out), "--batch", "36", "--lr", "2e-3", "--warmup", "10",
            "--ema-max", "0", "--ckpt-every", "1000", *TINY]
    assert fit_main([*args, "--steps", "1"]) == 0  # fits the normalisation; one tiny step barely trains
    data = DemoDataset(demos, "gt", 3, 8)
    before = denoising_error(checkpoint.load(out / "ckpt.pt").policy(), data)
    assert fit_main([*args, "--steps", "250"]) == 0
    ckpt = checkpoint.load(out / "ckpt.pt")
    after = denoising_error(ckpt.policy(), data)
    assert after < 0.5 * before, (before, after)
    assert np.mean(ckpt.losses[-20:]) < 0.5 * np.mean(ckpt.losses[:5])
