"""DDG test fixtures: clean synthetic scenes and tiny synthetic demo stores (the tiny DDG model is shared:
``tests/conftest.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from runtime.preprocess import DepthSpec


def scene(rng: np.random.Generator, h: int = 96, w: int = 128) -> np.ndarray:
    """A clean tabletop-like uint16 mm frame: a tilted plane with a few boxes standing on it."""
    yy, xx = np.mgrid[0:h, 0:w]
    depth = 900 + 0.8 * yy + rng.uniform(-50, 50)
    for _ in range(3):
        top, left = int(rng.integers(5, h - 25)), int(rng.integers(5, w - 25))
        rows, cols = int(rng.integers(8, 20)), int(rng.integers(8, 20))
        depth[top:top + rows, left:left + cols] -= rng.uniform(40, 150)
    return np.rint(depth).astype(np.uint16)


@pytest.fixture
def tiny_demos(tmp_path: Path) -> Path:
    import zarr

    rng = np.random.default_rng(0)
    path = tmp_path / "demos.zarr"
    root = zarr.open_group(str(path), mode="w")
    depth = np.stack([scene(rng) for _ in range(20)])
    root.create_array("data/depth", shape=depth.shape, dtype="uint16", chunks=(8, 96, 128))[:] = depth
    root.create_array("meta/episode_ends", shape=(2,), dtype="int64")[:] = [10, 20]
    root.attrs.update({"depth_spec": DepthSpec().to_dict(), "depth_scale": 0.001})
    return path
