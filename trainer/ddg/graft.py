"""Noise Grafting (paper eq. 9) and the decoding of generator output back to sensor units.

The generator works on ``normalise``'s scale: valid depth in [0, 1] (near_m..far_m), holes at -1. A predicted
pixel is a hole when its value is below ``HOLE_THRESHOLD`` = -0.5 (dimensionless, on that normalised scale):
half way between "no data" (-1) and the nearest valid depth (0 = near_m). Grafting then keeps the simulator's
exact depth wherever the generator did not predict a hole: ``d = d_sim * (1 - M) + d_pred * M`` with
``d_pred = 0`` (uint16 "no data") under M. M also covers the sensor's near limit: simulated pixels closer than
``near_m`` become holes, as a D4xx returns no depth below its min-z. Beyond ``far_m`` the simulator's value is
kept (a D455 still measures there; ``normalise`` clips it).
"""

from __future__ import annotations

import numpy as np

from runtime.preprocess import DepthSpec

HOLE_THRESHOLD = -0.5


class GraftError(ValueError):
    """Mismatched or non-uint16 depth maps handed to grafting."""


def decode(pred: np.ndarray, spec: DepthSpec, threshold: float = HOLE_THRESHOLD) -> np.ndarray:
    """Generator output (normalised scale, any float array) -> uint16 mm, holes = 0."""
    metres = spec.near_m + np.clip(pred, 0.0, 1.0) * (spec.far_m - spec.near_m)
    mm = np.clip(np.rint(metres * 1000.0), 1, 65535).astype(np.uint16)
    return np.where(pred < threshold, np.uint16(0), mm)


def hole_mask(pred_mm: np.ndarray, sim_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """M: True where the output must be "no data"."""
    return (pred_mm == 0) | (sim_mm < np.uint16(round(spec.near_m * 1000)))


def graft(sim_mm: np.ndarray, pred_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """Eq. 9 on uint16 mm maps of equal shape: simulator geometry, generator holes."""
    if sim_mm.dtype != np.uint16 or pred_mm.dtype != np.uint16:
        raise GraftError(f"grafting needs uint16 mm maps, got {sim_mm.dtype} and {pred_mm.dtype}")
    if sim_mm.shape != pred_mm.shape:
        raise GraftError(f"sim {sim_mm.shape} and predicted {pred_mm.shape} depth shapes differ")
    return np.where(hole_mask(pred_mm, sim_mm, spec), np.uint16(0), sim_mm)
