"""Simulated clean depth at the policy resolution: from a demo store, or rendered from randomised world
scenes, seen by the robot's camera (``policy``) or from views matched to the real captures (``matched``)."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from runtime.preprocess import DepthSpec, crop_resize
from trainer.ddg.data import RealDataError, policy_crop

VIEWS = ("policy", "matched")
MATCHED_DISTANCE_M = (0.5, 1.0)
"""Camera-to-object distance of the matched views: the held-out real D4xx captures see their scenes at
0.3-1.1 m (median depth per frame), the D455's min-z is 0.34 m, the arm's hand hangs 40 cm over the table."""
MATCHED_ELEVATION_DEG = (45.0, 85.0)
MAX_VOID_FRACTION = 0.002
"""A matched view with more "no data" in its crop (part of the arm nearer than min-z, or the sky) is drawn
again: the real captures' holes are the sensor's, never the scene's range."""


def void_as_far(sim_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """Simulated "no data" pixels (the void past hil_sim's table, beyond the D455's range) -> ``far_m``: the
    frame as it would be with a wall in range behind the table (a metrics diagnostic)."""
    return np.where(sim_mm == 0, np.uint16(round(1000 * spec.far_m)), sim_mm)


def from_demos(path: str, n: int) -> np.ndarray:
    """``n`` frames of ``data/depth`` evenly spread over the store."""
    import zarr

    from trainer.ddg.generate import DemoStoreError

    root = zarr.open_group(path, mode="r")
    if "data/depth" not in root:
        raise DemoStoreError(f"{path}: no data/depth array")
    depth = root["data/depth"]
    idx = np.unique(np.linspace(0, depth.shape[0] - 1, min(n, depth.shape[0])).astype(int))
    return np.stack([np.asarray(depth[i]) for i in idx])


def rendered(n: int, seed: int = 0, views: str = "policy") -> np.ndarray:
    """``n`` frames from ``hil_sim.world`` scenes: a random object of every kind in play, the arm at its
    (jittered) home pose. ``policy``: the robot's randomised camera and crop window, as in the demos.
    ``matched``: a close view of the object like the real captures' (``matched_view``), cut at a random
    policy crop as they are."""
    from hil_sim.objects import GROUPS
    from hil_sim.world import World

    if views not in VIEWS:
        raise RealDataError(f"views must be one of {', '.join(VIEWS)}, got {views!r}")
    world = World()
    kinds, rng = GROUPS["all"], np.random.default_rng(seed)
    frames, draws = [], 0
    try:
        with tqdm(total=n, desc=f"render sim scenes ({views} views)", leave=False) as bar:
            while len(frames) < n:
                ep = world.reset(kinds[draws % len(kinds)], seed=seed * 100_003 + draws)
                draws += 1
                crop = _view(world, ep, views, rng)
                if crop is not None:
                    frames.append(crop)
                    bar.update()
    finally:
        world.close()
    return np.stack(frames)


def _view(world, ep, views: str, rng: np.random.Generator) -> np.ndarray | None:
    """The policy-resolution crop of the episode's scene as ``views`` sees it; None for a matched view to draw
    again (``MAX_VOID_FRACTION``)."""
    if views == "policy":
        return crop_resize(world.render_depth(), world.spec, ep.crop_window)
    world.aim_camera(*matched_view(world.object_pose()[0], rng))
    crop = policy_crop(world.render_depth(), rng)[0]
    return crop if np.mean(crop == 0) <= MAX_VOID_FRACTION else None


def matched_view(obj: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, target): looking down at ``obj`` from ``MATCHED_DISTANCE_M`` (log-uniform) and
    ``MATCHED_ELEVATION_DEG``, from the side away from the robot's base (the arm behind the object, as from
    the robot's own camera), aimed within 5 cm of the object."""
    target = np.asarray(obj, float) + np.r_[rng.uniform(-0.05, 0.05, 2), 0.0]
    dist = np.exp(rng.uniform(*np.log(MATCHED_DISTANCE_M)))
    elev, azim = np.deg2rad(rng.uniform(*MATCHED_ELEVATION_DEG)), rng.uniform(-np.pi / 2, np.pi / 2)
    direction = np.r_[np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)]
    return target + dist * direction, target
