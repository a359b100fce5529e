"""Hole and depth-gradient statistics of uint16 mm frames at the policy resolution (0 = hole)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from trainer.ddg.graft import EDGE_MM_PER_PX, edge_band

SIZE_BINS = (1, 2, 5, 17, 65, 257)
"""Hole-component area bins (pixels): 1, 2-4, 5-16, 17-64, 65-256, >256."""


def hole_stats(frames: np.ndarray) -> dict:
    """Hole fraction, component sizes, hole rate near edges vs in flat regions, gradient statistics."""
    holes = frames == 0
    sizes = np.concatenate([_component_sizes(h) for h in holes]) if holes.any() else np.zeros(0)
    near, flat = _edge_rates(frames)
    grads = np.concatenate([_valid_gradients(f) for f in frames])
    hist = np.histogram(sizes, bins=[*SIZE_BINS, np.inf])[0] if len(sizes) else np.zeros(len(SIZE_BINS))
    return {
        "hole_fraction": float(holes.mean()),
        "hole_fraction_p10_p50_p90": [float(v) for v in np.percentile(holes.mean((1, 2)), [10, 50, 90])],
        "holes_per_frame": float(len(sizes) / len(frames)),
        "hole_size_px_p50_p90": [float(v) for v in np.percentile(sizes, [50, 90])] if len(sizes) else [0, 0],
        "hole_size_hist": [float(v) for v in hist / max(hist.sum(), 1)],
        "hole_rate_near_edges": near,
        "hole_rate_flat": flat,
        "edge_flat_ratio": float(near / flat) if flat > 0 else None,
        "grad_mm_per_px_p50_p90_p99": [float(v) for v in np.percentile(grads, [50, 90, 99])]
        if len(grads) else [0, 0, 0],
        "grad_jump_fraction": float(np.mean(grads > EDGE_MM_PER_PX)) if len(grads) else 0.0,
    }


def _component_sizes(hole: np.ndarray) -> np.ndarray:
    labels, n = ndimage.label(hole, structure=np.ones((3, 3)))
    return np.bincount(labels.ravel())[1:] if n else np.zeros(0)


def _edge_rates(frames: np.ndarray) -> tuple[float, float]:
    near_h = near_n = flat_h = flat_n = 0
    for f in frames:
        if not (f > 0).any():
            continue
        near = edge_band(f)
        hole = f == 0
        near_h, near_n = near_h + hole[near].sum(), near_n + near.sum()
        flat_h, flat_n = flat_h + hole[~near].sum(), flat_n + (~near).sum()
    return float(near_h / max(near_n, 1)), float(flat_h / max(flat_n, 1))


def _valid_gradients(f: np.ndarray) -> np.ndarray:
    z = f.astype(np.float32)
    gx = np.abs(np.diff(z, axis=1))[(f[:, 1:] > 0) & (f[:, :-1] > 0)]
    gy = np.abs(np.diff(z, axis=0))[(f[1:] > 0) & (f[:-1] > 0)]
    return np.concatenate([gx, gy])
