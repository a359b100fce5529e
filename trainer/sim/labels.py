"""Dense privileged perception labels: what the simulator knows of a frame that a depth student must read.

One float32 row per frame (``LABELS`` names the columns):
    offset      object centre minus grasp site (m, robot base frame = world axes): where to move the hand
    grasp_yaw   (cos 2p, sin 2p) of the direction p of the object's narrow horizontal axis, the direction the
                fingers must close along (a grasp turned by pi is the same grasp); (0, 0) for kinds that are
                round in plan view, where any direction works, as the expert treats them
    size        the object's half extents: narrow and long horizontal, vertical (m)
    object_px   the object centre's pixel in the policy's depth image, x then y, in the [-1, 1] coordinates of
                the encoder's spatial softmax (pixel centres from -1 to 1)
    hand_px     the same for the grasp site; outside [-1, 1] when out of view
The first ``READOUT`` columns are what the student's perception head regresses and its action head reads; the
pixels supervise the encoder's keypoints (the heatmap labels).
"""

from __future__ import annotations

import numpy as np

from hil_sim.world import World
from trainer.sim.env import OBJECT_FROM_HAND, OBJECT_QUAT, GraspEnv

LABELS = ("offset_x", "offset_y", "offset_z", "yaw_cos2", "yaw_sin2", "half_narrow", "half_long",
          "half_height", "object_px_x", "object_px_y", "hand_px_x", "hand_px_y")
OFFSET = slice(0, 3)
GRASP_YAW = slice(3, 5)
SIZE = slice(5, 8)
OBJECT_PX = slice(8, 10)
HAND_PX = slice(10, 12)
READOUT = 8
"""Columns the perception head regresses (offset, grasp yaw, size)."""
ROUND_RATIO = 0.1
"""Plan-view extents closer than this share of the longer one count as round (as the expert's grasp yaw)."""


def grasp_yaw(object_quat: np.ndarray, half_extent: np.ndarray) -> np.ndarray:
    """(cos 2p, sin 2p) of the object's narrow horizontal axis as it lies, (0, 0) for a round kind."""
    ex, ey = half_extent[:2]
    if abs(ex - ey) < ROUND_RATIO * max(ex, ey):
        return np.zeros(2)
    axis = _axis(np.asarray(object_quat, float), 0 if ex <= ey else 1)
    p = np.arctan2(axis[1], axis[0])
    return np.array([np.cos(2 * p), np.sin(2 * p)])


def _axis(quat: np.ndarray, i: int) -> np.ndarray:
    """Column ``i`` (x or y axis) of the rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = quat
    if i == 0:
        return np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
    return np.array([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)])


def pixel(world: World, point: np.ndarray) -> np.ndarray:
    """A world point's position in the policy image, in spatial-softmax coordinates ([-1, 1] edge centres)."""
    # the policy camera shares the stream camera's pose
    return project(point, world.camera_extrinsics(), world.episode.crop_window, world)


def project(point: np.ndarray, extrinsics: np.ndarray, crop_window, world: World) -> np.ndarray:
    """``pixel`` for a camera given by its world-from-camera ``extrinsics`` and ``crop_window`` (as a store's
    ``meta`` records them per episode), with ``world``'s intrinsics and depth spec."""
    spec, intr = world.spec, world.intr.window(*crop_window, world.spec)
    x, y, z = extrinsics[:3, :3].T @ (np.asarray(point, float) - extrinsics[:3, 3])
    z = max(z, 1e-6)  # behind the camera: far off the image either way
    u, v = intr.fx * x / z + intr.cx, intr.fy * y / z + intr.cy
    return np.array([2 * u / (spec.out_width - 1) - 1, 2 * v / (spec.out_height - 1) - 1])


def facts(privileged: np.ndarray, half_extent: np.ndarray) -> np.ndarray:
    """The first ``READOUT`` columns (offset, grasp yaw, size) from the env's 40-d observation and the
    object's half extents (``GraspEnv.reset``'s ``object_half_extent``): what the oracle head reads."""
    size = [min(half_extent[:2]), max(half_extent[:2]), half_extent[2]]
    return np.concatenate([privileged[OBJECT_FROM_HAND], grasp_yaw(privileged[OBJECT_QUAT], half_extent),
                           size]).astype(np.float32)


def frame_labels(env: GraspEnv) -> np.ndarray:
    """The ``LABELS`` row of the env's current state."""
    world = env.world
    obj_pos, _ = world.object_pose()
    hand, _ = world.ee_pose()
    row = np.concatenate([facts(env.observation(), world.object_extent()), pixel(world, obj_pos),
                          pixel(world, hand)])
    return row.astype(np.float32)
