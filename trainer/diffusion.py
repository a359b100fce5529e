"""What the trainer's two denoisers (the DDG's U-Net and the student's action head) learn to output."""

from __future__ import annotations

import torch
from diffusers import DDPMScheduler


def training_target(scheduler: DDPMScheduler, clean: torch.Tensor, noise: torch.Tensor,
                    steps: torch.Tensor) -> torch.Tensor:
    """The network's target for ``scheduler.add_noise(clean, noise, steps)``: the noise (epsilon), or for a
    v-prediction scheduler the velocity sqrt(abar) noise - sqrt(1 - abar) clean."""
    if scheduler.config.prediction_type == "epsilon":
        return noise
    return scheduler.get_velocity(clean, noise, steps)
