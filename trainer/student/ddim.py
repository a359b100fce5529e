"""Noise schedules: diffusers' DDPMScheduler for training, and the ONE DDIM update used at inference.

The DDIM update is written out here (not called through diffusers) so that export can unroll K steps into
the ONNX graph with each step's timestep and coefficients baked in as constants. Its coefficients are read
from diffusers' DDIMScheduler, which is also the reference the tests and ``export.check`` compare against.
Schedule settings follow diffusion_policy: 100 training steps, squared-cosine betas, x0 clipped to [-1, 1]
(actions are normalised to that range); the network predicts the noise (epsilon, diffusion_policy's choice) or
the velocity (``v_prediction``, Salimans & Ho 2022), as its ``StudentConfig.prediction`` says.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from diffusers import DDIMScheduler, DDPMScheduler

from runtime.metadata import DDIM_SPACINGS

_SCHEDULE = {"beta_schedule": "squaredcos_cap_v2", "clip_sample": True}


class DdimError(ValueError):
    """A DDIM step count the training schedule cannot provide."""


def training_scheduler(train_timesteps: int, prediction: str) -> DDPMScheduler:
    return DDPMScheduler(num_train_timesteps=train_timesteps, prediction_type=prediction, **_SCHEDULE)


def reference_scheduler(train_timesteps: int, steps: int, spacing: str = "leading",
                        prediction: str = "epsilon") -> DDIMScheduler:
    """diffusers' DDIM with ``steps`` inference steps: the reference our unrolled update must match."""
    if not 1 <= steps <= train_timesteps:
        raise DdimError(f"DDIM steps must be in 1..{train_timesteps}, got {steps}")
    if spacing not in DDIM_SPACINGS:
        raise DdimError(f"DDIM spacing must be one of {DDIM_SPACINGS}, got {spacing!r}")
    sched = DDIMScheduler(num_train_timesteps=train_timesteps, set_alpha_to_one=True, steps_offset=0,
                          timestep_spacing=spacing, prediction_type=prediction, **_SCHEDULE)
    sched.set_timesteps(steps)
    return sched


@dataclass(frozen=True)
class DdimStep:
    timestep: int
    sqrt_alpha: float
    sqrt_one_minus_alpha: float
    sqrt_alpha_prev: float
    sqrt_one_minus_alpha_prev: float


def ddim_plan(train_timesteps: int, steps: int, spacing: str = "leading") -> list[DdimStep]:
    """Timesteps and coefficients of a deterministic (eta=0) DDIM run, in diffusers' float32 arithmetic."""
    sched = reference_scheduler(train_timesteps, steps, spacing)
    stride = train_timesteps // steps
    plan = []
    for t in sched.timesteps.tolist():
        alpha = sched.alphas_cumprod[t]
        alpha_prev = sched.alphas_cumprod[t - stride] if t - stride >= 0 else sched.final_alpha_cumprod
        plan.append(DdimStep(int(t), (alpha ** 0.5).item(), ((1 - alpha) ** 0.5).item(),
                             (alpha_prev ** 0.5).item(), ((1 - alpha_prev) ** 0.5).item()))
    return plan


def clean_and_noise(sample: torch.Tensor, output: torch.Tensor, sqrt_alpha: float | torch.Tensor,
                    sqrt_one_minus_alpha: float | torch.Tensor,
                    prediction: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The clean chunk and the noise that the network's output (noise or velocity) says make up ``sample``."""
    if prediction == "epsilon":
        return (sample - sqrt_one_minus_alpha * output) / sqrt_alpha, output
    # v = sqrt(alpha) eps - sqrt(1 - alpha) x0: at pure noise it is -x0, read off the observation alone
    clean = sqrt_alpha * sample - sqrt_one_minus_alpha * output
    return clean, sqrt_alpha * output + sqrt_one_minus_alpha * sample


def ddim_update(sample: torch.Tensor, output: torch.Tensor, step: DdimStep, prediction: str) -> torch.Tensor:
    """One eta=0 DDIM step x_t -> x_{t-stride} from the network's output."""
    x0, eps = clean_and_noise(sample, output, step.sqrt_alpha, step.sqrt_one_minus_alpha, prediction)
    return step.sqrt_alpha_prev * x0.clamp(-1.0, 1.0) + step.sqrt_one_minus_alpha_prev * eps


def denoise(policy, obs: torch.Tensor, noise: torch.Tensor, plan: list[DdimStep],
            prediction: str) -> torch.Tensor:
    """The DDIM run of ``plan`` from ``noise`` [B, Ha, A] with the denoiser ``policy(sample, steps, obs)``:
    normalised actions. Timesteps are Python constants, so tracing it unrolls the loop (``export.graph``)."""
    x = noise
    for step in plan:
        steps = torch.full((x.shape[0],), step.timestep, dtype=torch.int64)
        x = ddim_update(x, policy(x, steps, obs), step, prediction)
    return x
