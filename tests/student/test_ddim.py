"""Our unrolled DDIM update is diffusers' DDIMScheduler.step, coefficient for coefficient."""

from __future__ import annotations

import pytest
import torch

from trainer.diffusion import training_target
from trainer.student.config import PREDICTIONS
from trainer.student.ddim import (
    DdimError,
    ddim_plan,
    ddim_update,
    reference_scheduler,
    training_scheduler,
)


@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("spacing", ["leading", "trailing"])
@pytest.mark.parametrize("steps", [1, 4, 8, 16, 100])
def test_update_matches_diffusers(steps, spacing, prediction):
    sched = reference_scheduler(100, steps, spacing, prediction)
    plan = ddim_plan(100, steps, spacing)
    assert [s.timestep for s in plan] == sched.timesteps.tolist()
    g = torch.Generator().manual_seed(steps)
    x_ours = x_ref = torch.randn(2, 16, 8, generator=g)
    for step, t in zip(plan, sched.timesteps, strict=True):
        out = torch.randn(2, 16, 8, generator=g) * 2.0  # large enough that x0 clipping kicks in
        x_ours = ddim_update(x_ours, out, step, prediction)
        x_ref = sched.step(out, t, x_ref).prev_sample
        torch.testing.assert_close(x_ours, x_ref, atol=1e-6, rtol=0)
        if prediction == "epsilon":  # the exported graph's arithmetic, operation for operation
            assert torch.equal(x_ours, x_ref)


def test_last_step_lands_on_clean_sample():
    last = ddim_plan(100, 4)[-1]
    assert last.sqrt_alpha_prev == 1.0 and last.sqrt_one_minus_alpha_prev == 0.0


@pytest.mark.parametrize("steps", [0, 101])
def test_impossible_step_count_is_refused(steps):
    with pytest.raises(DdimError, match=str(steps)):
        ddim_plan(100, steps)


def test_trailing_starts_from_pure_noise():
    """Leading K=4 starts at 75, where a sample is still 37 % signal; trailing at the last training step."""
    assert [s.timestep for s in ddim_plan(100, 4)] == [75, 50, 25, 0]
    trailing = ddim_plan(100, 4, "trailing")
    assert [s.timestep for s in trailing] == [99, 74, 49, 24] and trailing[0].sqrt_alpha < 1e-3
    with pytest.raises(DdimError, match="spacing"):
        ddim_plan(100, 4, "linspace")


@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("spacing", ["leading", "trailing"])
@pytest.mark.parametrize("steps", [1, 4, 8, 16])
def test_perfect_prediction_recovers_the_clean_chunk(steps, spacing, prediction):
    """With the training target's ideal value (what a perfectly trained network predicts), K steps land on
    x0: the training target and the update agree on what the network's output means."""
    g = torch.Generator().manual_seed(0)
    x0 = torch.rand(1, 16, 8, generator=g) * 2 - 1
    x = torch.randn(1, 16, 8, generator=g)
    plan, training = ddim_plan(100, steps, spacing), training_scheduler(100, prediction)
    for step in plan:
        eps = (x - step.sqrt_alpha * x0) / step.sqrt_one_minus_alpha
        ideal = training_target(training, x0, eps, torch.tensor([step.timestep]))
        x = ddim_update(x, ideal, step, prediction)
    # float32 rounding of eps is magnified 1/sqrt(alpha) in the first x0 estimate: 2000x at t = 99
    torch.testing.assert_close(x, x0, atol=max(1e-5, 3e-7 / plan[0].sqrt_alpha), rtol=0)
