"""Geometric prior ``c``: clean relative depth the generator is conditioned on.

Providers map a policy-resolution frame to float32 ``c`` in [-1, 1] (near -> -1, far -> +1). All of them end
in ``relative_depth``, so a real capture and a simulated frame go through the same normalisation.

``DepthPrior`` (offline default, no weights): the raw depth's holes are first filled from the same pixel in
neighbouring frames of a sequence where those agree (temporal fusion), then from the nearest valid pixel
(Euclidean distance transform), then a 5x5 median removes speckle and flying pixels. Why this does not leak
the artifacts into ``c``: a filled pixel carries the depth of the surface next to the hole, never a "no data"
value, so ``c`` has no holes at all; the median erases the seams of the nearest-neighbour fill, and the
per-frame affine normalisation keeps only relative geometry. What the generator must produce (where holes are)
is therefore absent from its condition; it has to learn it from the geometry, which is what sim gives it.

``OnnxPrior``: a Video Depth Anything / Depth Anything V2 ONNX export from a local path (input
``[1, 3, H, W]`` ImageNet-normalised RGB, output ``[1, H, W]`` or ``[1, 1, H, W]`` relative inverse depth).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from scipy import ndimage

from runtime.preprocess import DepthSpec, normalise

from .data import POLICY_SPEC


class PriorError(ValueError):
    """A frame the prior cannot be computed from (no valid depth, missing RGB, wrong shape)."""


class PriorProvider(Protocol):
    def __call__(self, depth_mm: np.ndarray, rgb: np.ndarray | None = None) -> np.ndarray:
        """uint16 mm frame [H, W] (+ its RGB [H, W, 3]) at the policy resolution -> float32 c [H, W]."""
        ...


def frame_scale(depth: np.ndarray, lo_pct: float = 1.0, hi_pct: float = 99.0) -> tuple[float, float]:
    """(lo, span): the robust percentile range of a hole-free depth-like array, which ``relative_depth``
    maps to [-1, 1]. The generator's target and output live on the same per-frame scale (``graft``)."""
    if not np.all(np.isfinite(depth)):
        raise PriorError("prior input holds NaN/inf")
    lo, hi = np.percentile(depth, [lo_pct, hi_pct])
    return float(lo), max(float(hi - lo), 1e-6)


def relative_depth(depth: np.ndarray, scale: tuple[float, float] | None = None) -> np.ndarray:
    """Per-frame affine map of a hole-free depth-like array to [-1, 1] (``frame_scale``, clipped)."""
    lo, span = frame_scale(depth) if scale is None else scale
    return np.clip(2.0 * (depth - lo) / span - 1.0, -1.0, 1.0).astype(np.float32)


def fill_holes(depth_mm: np.ndarray) -> np.ndarray:
    """Holes (0) take the nearest valid pixel's depth; a 5x5 median then removes speckle and seams."""
    holes = depth_mm == 0
    if holes.all():
        raise PriorError("frame has no valid depth to build a prior from")
    if holes.any():
        idx = ndimage.distance_transform_edt(holes, return_distances=False, return_indices=True)
        depth_mm = depth_mm[tuple(idx)]
    return cv2.medianBlur(np.ascontiguousarray(depth_mm, dtype=np.uint16), 5)


def temporal_fuse(frames_mm: np.ndarray, window: int = 2, tol_mm: int = 15) -> np.ndarray:
    """[T, H, W] uint16: a hole takes the median of the same pixel in frames t-window..t+window when
    at least two of them are valid and agree within ``tol_mm`` (under a
    moving camera, disagreeing pixels stay holes)."""
    out = frames_mm.copy()
    for t in range(len(frames_mm)):
        nb = frames_mm[max(0, t - window): t + window + 1].astype(np.float32)
        nb[nb == 0] = np.nan
        valid = np.sum(~np.isnan(nb), axis=0)
        with warnings.catch_warnings():  # all-hole pixels are expected; they stay holes
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(nb, axis=0)
            spread = np.nanmax(nb, axis=0) - np.nanmin(nb, axis=0)
        ok = (frames_mm[t] == 0) & (valid >= 2) & (spread <= tol_mm)
        out[t][ok] = np.rint(med[ok]).astype(np.uint16)
    return out


class DepthPrior:
    """Offline default: ``relative_depth(normalise(fill_holes(depth)))``. Simulated depth (no holes) goes
    through the very same call."""

    def __init__(self, spec: DepthSpec = POLICY_SPEC, depth_scale: float = 0.001) -> None:
        self.spec, self.depth_scale = spec, depth_scale

    def __call__(self, depth_mm: np.ndarray, rgb: np.ndarray | None = None) -> np.ndarray:
        return self.with_scale(depth_mm)[0]

    def with_scale(self, depth_mm: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
        """(c, its ``frame_scale`` on the normalised filled depth): the scale turns the generator's
        relative output back into this frame's metric depth."""
        if depth_mm.dtype != np.uint16 or depth_mm.ndim != 2:
            raise PriorError(f"prior wants a 2-D uint16 mm frame, got {depth_mm.dtype} {depth_mm.shape}")
        filled = normalise(fill_holes(depth_mm), self.depth_scale, self.spec)
        scale = frame_scale(filled)
        return relative_depth(filled, scale), scale


class OnnxPrior:
    """Relative depth from a local Depth Anything (V2 / Video) ONNX model, run on the frame's RGB."""

    MEAN = np.array([0.485, 0.456, 0.406], np.float32)
    STD = np.array([0.229, 0.224, 0.225], np.float32)

    def __init__(self, path: str | Path, input_size: tuple[int, int] = (518, 518), threads: int = 2) -> None:
        import onnxruntime as ort

        if not Path(path).is_file():
            raise PriorError(f"no ONNX depth model at {path}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        shape = self.session.get_inputs()[0].shape
        static = all(isinstance(d, int) for d in shape[2:])
        self.input_size = (shape[2], shape[3]) if static else input_size

    def __call__(self, depth_mm: np.ndarray | None, rgb: np.ndarray | None = None) -> np.ndarray:
        if rgb is None or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise PriorError("the ONNX depth prior needs an RGB frame [H, W, 3]")
        h, w = rgb.shape[:2]
        x = cv2.resize(rgb, self.input_size[::-1], interpolation=cv2.INTER_CUBIC).astype(np.float32) / 255.0
        x = ((x - self.MEAN) / self.STD).transpose(2, 0, 1)[None]
        disparity = np.asarray(self.session.run(None, {self.input_name: x})[0], np.float32).reshape(
            self.input_size)
        disparity = cv2.resize(disparity, (w, h), interpolation=cv2.INTER_LINEAR)
        # Depth Anything predicts inverse depth: flip the sign so that, as in c, larger means farther.
        return relative_depth(-disparity)
