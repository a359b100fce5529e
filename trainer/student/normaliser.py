"""Min-max normalisation to [-1, 1] (diffusion_policy's 'limits' mode), kept as buffers so it travels in
the checkpoint and is traced into the ONNX graph."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

# A dimension that never moves in the demos (e.g. a joint the teacher never uses) gets unit range
# instead of a division by ~0 that would blow up any deploy-time deviation.
_MIN_HALF_RANGE = 1e-4


class RangeNormaliser(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("centre", torch.zeros(dim))
        self.register_buffer("half_range", torch.ones(dim))

    def fit(self, low: np.ndarray, high: np.ndarray) -> None:
        """Set statistics from per-dimension minima and maxima of the training data."""
        low_t, high_t = torch.as_tensor(low, dtype=torch.float32), torch.as_tensor(high, dtype=torch.float32)
        if low_t.shape != self.centre.shape or high_t.shape != self.centre.shape:
            raise ValueError(f"normaliser statistics must have shape {tuple(self.centre.shape)}, "
                             f"got {tuple(low_t.shape)} and {tuple(high_t.shape)}")
        half = (high_t - low_t) / 2
        self.centre.copy_((high_t + low_t) / 2)
        self.half_range.copy_(torch.where(half < _MIN_HALF_RANGE, torch.ones_like(half), half))

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.centre) / self.half_range

    def unnormalise(self, y: torch.Tensor) -> torch.Tensor:
        return y * self.half_range + self.centre

    def summary(self) -> dict[str, list[float]]:
        """Statistics for the policy file's metadata (audit only; the graph carries its own copy)."""
        return {"low": (self.centre - self.half_range).tolist(),
                "high": (self.centre + self.half_range).tolist()}
