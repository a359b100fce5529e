"""Simulated Intel RealSense D455: intrinsics of the 848x480 depth mode, uint16 millimetre output, mount pose.

Intrinsics come from a real D455's factory calibration at 1280x720 (librealsense issue #8577:
f = [636.763, 636.356], p = [627.562, 374.707]) scaled to 848x480 the way the D4xx firmware derives
that mode (scale 2/3, then 2.67 px cropped from each side): fx 424.51, fy 424.24, cx 415.71, cy 249.80.
Lens distortion of the depth stream is reported as zero by the D4xx family, so none is modelled.

Like the real sensor, a pixel reads 0 ("no data") when the surface is nearer than min-z (~0.34 m at
848x480 per the D455 datasheet), farther than ``max_z_m``, or when nothing is there at all (sky).
Poses use two conventions: MuJoCo's camera frame (x right, y up, looking along -z) inside the model,
OpenCV's (x right, y down, z forward) for the extrinsics written to datasets.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from runtime.preprocess import DepthSpec

_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])
_PIXEL_M = 1e-5


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole model of the depth stream (pixel centres at integer coordinates, OpenCV style)."""

    width: int = 848
    height: int = 480
    fx: float = 424.51
    fy: float = 424.24
    cx: float = 415.71
    cy: float = 249.80
    min_z_m: float = 0.34
    """D455 minimum depth at 848x480 (datasheet)."""
    max_z_m: float = 6.0
    """Beyond this the D455's depth error grows past use; the sensor reports 0."""

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def mjcf_attributes(self) -> str:
        """MuJoCo camera attributes giving this projection (offsets measured against renders, see tests)."""
        ppx, ppy = self._principal_offset()
        return (f'resolution="{self.width} {self.height}" focalpixel="{self.fx} {self.fy}" '
                f'principalpixel="{ppx:.4f} {ppy:.4f}" '
                f'sensorsize="{self.width * _PIXEL_M} {self.height * _PIXEL_M}"')

    def mj_intrinsic(self) -> np.ndarray:
        """The same projection as MuJoCo's ``cam_intrinsic`` row (lengths on a sensor of 10 um pixels)."""
        return np.array([self.fx, self.fy, *self._principal_offset()]) * _PIXEL_M

    def _principal_offset(self) -> tuple[float, float]:
        # MuJoCo's principalpixel is measured from the image centre towards -u / -v (found against renders)
        return (self.width - 1) / 2 - self.cx, (self.height - 1) / 2 - self.cy

    def window(self, top: int, left: int, spec: DepthSpec) -> Intrinsics:
        """The camera that sees only the crop window at ``(top, left)``, at the policy resolution: the rays
        of ``crop_resize``'s output pixels to within half a stream pixel (nearest-neighbour sampling)."""
        sx, sy = spec.crop_width / spec.out_width, spec.crop_height / spec.out_height
        return Intrinsics(spec.out_width, spec.out_height, self.fx / sx, self.fy / sy,
                          (self.cx - left + 0.5) / sx - 0.5, (self.cy - top + 0.5) / sy - 0.5,
                          self.min_z_m, self.max_z_m)


def d455_intrinsics(spec: DepthSpec | None = None) -> Intrinsics:
    """The D455 depth intrinsics for ``spec``'s stream size (848x480 is the calibrated mode)."""
    spec = spec or DepthSpec()
    base = Intrinsics()
    if (spec.stream_width, spec.stream_height) == (base.width, base.height):
        return base
    sx, sy = spec.stream_width / base.width, spec.stream_height / base.height
    return Intrinsics(spec.stream_width, spec.stream_height, base.fx * sx, base.fy * sy,
                      (base.cx + 0.5) * sx - 0.5, (base.cy + 0.5) * sy - 0.5)


def look_at_quat(pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """MuJoCo camera quaternion (w, x, y, z) looking from ``pos`` at ``target`` with world z up."""
    forward = np.asarray(target, float) - np.asarray(pos, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([right, up, -forward]).ravel())
    return quat


def extrinsics(cam_pos: np.ndarray, cam_xmat: np.ndarray) -> np.ndarray:
    """4x4 world-from-camera transform in OpenCV axes, from MuJoCo's camera position and 3x3 frame."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(cam_xmat, float).reshape(3, 3) @ _MJ_TO_CV
    T[:3, 3] = cam_pos
    return T


def to_millimetres(depth_m: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Metric z-depth -> uint16 mm, 0 where the D455 gives no data (too near, too far, nothing hit)."""
    valid = (depth_m >= intr.min_z_m) & (depth_m <= intr.max_z_m)
    return np.where(valid, np.rint(depth_m * 1000.0), 0).astype(np.uint16)


class DepthCamera:
    """One offscreen renderer for one MuJoCo camera; created on first use, depth-only unless RGB is asked."""

    def __init__(self, model: mujoco.MjModel, camera: str, intr: Intrinsics) -> None:
        self._model, self._camera, self.intr = model, camera, intr
        self._depth: mujoco.Renderer | None = None
        self._rgb: mujoco.Renderer | None = None

    def depth_mm(self, data: mujoco.MjData) -> np.ndarray:
        if self._depth is None:
            self._depth = mujoco.Renderer(self._model, self.intr.height, self.intr.width)
            self._depth.enable_depth_rendering()
        self._depth.update_scene(data, self._camera)
        return to_millimetres(self._depth.render(), self.intr)

    def rgb(self, data: mujoco.MjData) -> np.ndarray:
        if self._rgb is None:
            self._rgb = mujoco.Renderer(self._model, self.intr.height, self.intr.width)
        self._rgb.update_scene(data, self._camera)
        return self._rgb.render()

    def close(self) -> None:
        for r in (self._depth, self._rgb):
            if r is not None:
                r.close()
        self._depth = self._rgb = None
