"""Simulated clean depth at the policy resolution: from a demo store, or rendered from randomised world
scenes."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from runtime.preprocess import DepthSpec, crop_resize


def void_as_far(sim_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """Simulated "no data" pixels (the void past hil_sim's table, beyond the D455's range) -> ``far_m``: the
    frame as it would be with a wall in range behind the table (a metrics diagnostic)."""
    return np.where(sim_mm == 0, np.uint16(round(1000 * spec.far_m)), sim_mm)


def from_demos(path: str, n: int) -> np.ndarray:
    """``n`` frames of ``data/depth`` evenly spread over the store."""
    import zarr

    from .generate import DemoStoreError

    root = zarr.open_group(path, mode="r")
    if "data/depth" not in root:
        raise DemoStoreError(f"{path}: no data/depth array")
    depth = root["data/depth"]
    idx = np.unique(np.linspace(0, depth.shape[0] - 1, min(n, depth.shape[0])).astype(int))
    return np.stack([np.asarray(depth[i]) for i in idx])


def rendered(n: int, seed: int = 0) -> np.ndarray:
    """``n`` frames from ``hil_sim.world`` scenes: a random object of every kind in play, randomised camera
    and crop window, the arm at its (jittered) home pose."""
    from hil_sim.objects import GROUPS
    from hil_sim.world import World

    world = World()
    kinds = GROUPS["all"]
    frames = []
    try:
        for i in tqdm(range(n), desc="render sim scenes", leave=False):
            ep = world.reset(kinds[i % len(kinds)], seed=seed * 100_003 + i)
            frames.append(crop_resize(world.render_depth(), world.spec, ep.crop_window))
    finally:
        world.close()
    return np.stack(frames)
