"""Noise Grafting (paper eq. 9) and the generator's depth scale.

The generator works on a per-frame relative scale, the one its condition ``c`` has: valid depth in [0, 1] is
``(c + 1) / 2`` of the same frame (``frame_scale``: its 1st-99th percentile of ``normalise``d depth), holes
are -1. So for the geometry it only has to copy ``c``; what it learns is where a D4xx loses depth. (A metric
target would ask it to guess absolute depth from relative ``c``, which it cannot.) ``encode`` makes training
targets from real crops, ``decode`` turns output back into uint16 mm with the simulated frame's own scale.

A predicted pixel is a hole when its value is below ``HOLE_THRESHOLD`` = -0.5 (dimensionless, on that
scale): half way between "no data" (-1) and the nearest valid depth of the frame (0). Grafting then keeps the
simulator's exact depth wherever the generator did not predict a hole: ``d = d_sim * (1 - M) + d_pred * M``
with ``d_pred = 0`` (uint16 "no data") under M. M also covers the sensor's near limit: simulated pixels
closer than ``near_m`` become holes, as a D4xx returns no depth below its min-z. Beyond ``far_m`` the
simulator's value is kept (a D455 still measures there; ``normalise`` clips it).

Edge grafting (``graft_edges``) is the same idea for a generator of the sensor's whole frame (the residual
diffusion): it keeps the generator's depth only near the simulated frame's depth edges, where a stereo
sensor's wrong depth lives, and its holes everywhere.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from runtime.preprocess import DepthSpec, normalise

from .prior import fill_holes, relative_depth

HOLE_THRESHOLD = -0.5
EDGE_MM_PER_PX = 20.0
"""A depth step above this between neighbouring pixels (of the hole-filled depth) is an edge."""
EDGE_BAND_PX = 2
"""Pixels within this distance of an edge count as "near an edge"."""
X0_SCALE = "relative"
"""Recorded in a model's config: models trained on another target scale (the first: metric) are refused."""


class GraftError(ValueError):
    """Mismatched or non-uint16 depth maps handed to grafting."""


def encode(depth_mm: np.ndarray, scale: tuple[float, float], spec: DepthSpec) -> np.ndarray:
    """uint16 mm frame -> float32 on the relative scale ``scale`` = (lo, span) of ``normalise``d depth: the
    condition's own map (``relative_depth``) moved from [-1, 1] to [0, 1], holes -1."""
    rel = (relative_depth(normalise(depth_mm, 0.001, spec), scale) + 1.0) / 2.0
    return np.where(depth_mm == 0, np.float32(-1.0), rel).astype(np.float32)


def decode(pred: np.ndarray, scales: np.ndarray, spec: DepthSpec, threshold: float = HOLE_THRESHOLD
           ) -> np.ndarray:
    """Generator output [B, H, W] on each frame's relative scale (``scales`` [B, 2] = lo, span, as a crop bank
    stores them) -> uint16 mm, holes = 0."""
    lo, span = (np.asarray(scales, np.float32)[:, i, None, None] for i in (0, 1))
    metres = spec.near_m + (lo + np.clip(pred, 0.0, 1.0) * span) * np.float32(spec.far_m - spec.near_m)
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


def edge_band(frame: np.ndarray) -> np.ndarray:
    """bool [H, W]: the pixels within ``EDGE_BAND_PX`` of a depth edge of the uint16 mm frame's geometry (its
    holes filled first, so a hole's rim is not an edge)."""
    return ndimage.binary_dilation(depth_steps(fill_holes(frame), EDGE_MM_PER_PX), iterations=EDGE_BAND_PX)


def edge_bands(frames_mm: np.ndarray) -> np.ndarray:
    """bool [N, H, W]: each uint16 mm frame's ``edge_band``."""
    return np.stack([edge_band(f) for f in frames_mm])


def depth_steps(depth_mm: np.ndarray, step_mm: float) -> np.ndarray:
    """bool [H, W]: the pixels whose depth differs by more than ``step_mm`` from the pixel above or to the
    left of them (holes count as depth 0 here; ``edge_band`` fills them first)."""
    z = depth_mm.astype(np.float32)
    steps = np.zeros(z.shape, bool)
    steps[1:] |= np.abs(np.diff(z, axis=0)) > step_mm
    steps[:, 1:] |= np.abs(np.diff(z, axis=1)) > step_mm
    return steps


def graft_edges(sim_mm: np.ndarray, made_mm: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
    """uint16 mm frames [N, H, W] of equal shape: a generated sensor frame's depth within the simulated
    frame's ``edge_band`` (where stereo matching fattens and smears edges), the simulator's depth elsewhere
    (where the residual diffusion's noise is its own: 47 % of flat pixels more than 2 cm off against the
    sensor's 7 %, docs/residual.md), and the generated frame's holes everywhere. ``near``: the simulated
    frames' ``edge_bands`` where the caller has them already."""
    if sim_mm.dtype != np.uint16 or made_mm.dtype != np.uint16:
        raise GraftError(f"edge grafting needs uint16 mm maps, got {sim_mm.dtype} and {made_mm.dtype}")
    if sim_mm.shape != made_mm.shape or sim_mm.ndim != 3:
        raise GraftError(f"sim {sim_mm.shape} and generated {made_mm.shape} must be equal [N, H, W] stacks")
    near = edge_bands(sim_mm) if near is None else near
    return np.where(made_mm == 0, np.uint16(0), np.where(near, made_mm, sim_mm))
