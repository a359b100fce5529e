"""Depth frames -> 3D point patches (Stable-Sim2Real §3.3): each frame is split into p x p pixel patches and
each pixel back-projected through the frame's pinhole K to a point in the camera's frame (OpenCV axes: x
right, y down, z forward; ``hil_sim.stereo.ir.backproject``, the stereo sensor's own).

A patch's points are given relative to a centre, by default the mean of its valid points; the discriminator
centres the sensor's (or generated) patch on the simulated patch's centre, so what sets it apart from the
simulated surface, its offset included, is kept. They are in decimetres (``POINT_SCALE``: a 16-pixel patch at
1 m spans ~1.2 and a 2 cm error is 0.2, values a freshly initialised MLP can read). A fourth feature is 1
where the pixel has depth and 0 where it has none, whose point then sits at the centre: a sensor's holes are
much of what tells its depth apart.
"""

from __future__ import annotations

import numpy as np

from hil_sim.camera import Intrinsics
from hil_sim.stereo.ir import backproject

POINT_SCALE = 10.0
"""Metres -> the units of a patch's points (decimetres)."""
POINT_FEATURES = 4
"""x, y, z relative to the patch's centre, and valid (1) / no depth (0)."""


class PatchError(ValueError):
    """A patch size that does not tile the frames."""


def patch_grid(shape: tuple[int, int], p: int) -> tuple[int, int]:
    """(rows, columns) of p x p patches in a frame of ``shape``; refused unless p divides both sides."""
    h, w = shape
    if p < 1 or h % p or w % p:
        raise PatchError(f"patch size {p} does not tile the {w}x{h} frames: it must divide {h} and {w}")
    return h // p, w // p


def tile(a: np.ndarray, p: int) -> np.ndarray:
    """[N, H, W, *F] -> [N, P, p * p, *F]: patches in row-major order, each one's pixels row-major too."""
    n, h, w, *features = a.shape
    rows, cols = patch_grid((h, w), p)
    grid = a.reshape(n, rows, p, cols, p, *features).swapaxes(2, 3)
    return grid.reshape(n, rows * cols, p * p, *features)


def untile(values: np.ndarray, shape: tuple[int, int], p: int) -> np.ndarray:
    """One value per patch [N, P] -> the frame [N, H, W] that holds it on each of the patch's pixels."""
    rows, cols = patch_grid(shape, p)
    grid = values.reshape(len(values), rows, cols)
    return np.repeat(np.repeat(grid, p, axis=1), p, axis=2)


def points(depth_mm: np.ndarray, K: np.ndarray) -> np.ndarray:
    """uint16 mm [N, H, W] and each frame's K [N, 3, 3] -> float32 [N, H, W, 3] metres (0 where no depth)."""
    h, w = depth_mm.shape[1:]
    return np.stack([backproject(d.astype(np.float32) / 1000.0,
                                 Intrinsics(w, h, k[0, 0], k[1, 1], k[0, 2], k[1, 2]))
                     for d, k in zip(depth_mm, K, strict=True)])


def point_patches(depth_mm: np.ndarray, K: np.ndarray, p: int, centre: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Frames -> (point patches float32 [N, P, p * p, 4], their centres [N, P, 3] metres), the patches
    relative to ``centre`` when given (another frame's centres) else to the mean of their own valid points."""
    xyz = tile(points(depth_mm, K), p)
    valid = tile(depth_mm > 0, p)
    if centre is None:
        count = np.maximum(valid.sum(axis=2), 1)[..., None]
        centre = (xyz * valid[..., None]).sum(axis=2) / count
    relative = np.where(valid[..., None], (xyz - centre[:, :, None]) * POINT_SCALE, 0.0)
    return np.concatenate([relative, valid[..., None]], axis=-1).astype(np.float32), centre
