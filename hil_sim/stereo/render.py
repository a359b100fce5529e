"""Depth + geom ids of a MuJoCo scene seen from virtual pinhole cameras placed beside a model camera.

The D455 has three optical parts on one rigid bar: the left IR imager (the depth frame's origin, the
model's camera), the right IR imager and the projector, both shifted along the camera's x axis. One
``mjv_updateScene`` per frame gives the model camera's pose; each view then moves the OpenGL camera along
x and sets its frustum from its own intrinsics. Segmentation and depth come out of one pass
(``mjRND_SEGMENT`` + ``mjRND_IDCOLOR`` colours, read together with the depth buffer).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hil_sim.camera import Intrinsics


@dataclass(frozen=True)
class View:
    """A pinhole camera with the model camera's orientation, ``offset_m`` along its x axis (right)."""

    offset_m: float
    intr: Intrinsics


@dataclass(frozen=True)
class ViewImage:
    """What a view sees: z-depth in metres (inf where nothing is hit) and the model geom id (-1 there)."""

    z: np.ndarray
    geom: np.ndarray


class MultiViewRenderer:
    """Offscreen renderer of several ``View``s around one model camera (views at most ``max_size``)."""

    def __init__(self, model: mujoco.MjModel, camera: str, max_size: tuple[int, int]) -> None:
        width, height = max_size
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(f"views of {width}x{height} exceed the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        self._model = model
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._scene = mujoco.MjvScene(model, maxgeom=10_000)
        self._option, self._perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = model.camera(camera).id
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        extent = model.stat.extent
        self._near, self._far = model.vis.map.znear * extent, model.vis.map.zfar * extent

    def render(self, data: mujoco.MjData, views: list[View]) -> list[ViewImage]:
        self._gl.make_current()
        mujoco.mjv_updateScene(self._model, data, self._option, self._perturb, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        base = self._scene.camera[0]
        pos, forward, up = np.array(base.pos), np.array(base.forward), np.array(base.up)
        right = np.cross(forward, up)
        geom_of_seg = self._segment_table()
        return [self._render_view(pos + v.offset_m * right, v.intr, geom_of_seg) for v in views]

    def _render_view(self, pos: np.ndarray, intr: Intrinsics, geom_of_seg: np.ndarray) -> ViewImage:
        near = self._scene.camera[0].frustum_near
        left, right = -(intr.cx + 0.5) / intr.fx * near, (intr.width - intr.cx - 0.5) / intr.fx * near
        for cam in self._scene.camera:  # mono rendering averages the two eye cameras: set both
            cam.pos[:] = pos
            cam.frustum_center, cam.frustum_width = (left + right) / 2, (right - left) / 2
            cam.frustum_top = (intr.cy + 0.5) / intr.fy * near
            cam.frustum_bottom = -(intr.height - intr.cy - 0.5) / intr.fy * near
        rect = mujoco.MjrRect(0, 0, intr.width, intr.height)
        mujoco.mjr_render(rect, self._scene, self._ctx)
        rgb = np.empty((intr.height, intr.width, 3), np.uint8)
        buf = np.empty((intr.height, intr.width), np.float32)
        mujoco.mjr_readPixels(rgb, buf, rect, self._ctx)
        rgb, buf = rgb[::-1], buf[::-1]
        seg = rgb[..., 0].astype(np.int64) + (rgb[..., 1].astype(np.int64) << 8) + (
            rgb[..., 2].astype(np.int64) << 16)
        geom = geom_of_seg[np.clip(seg, 0, len(geom_of_seg) - 1)]
        z = self._near / (1.0 - buf * (1.0 - self._near / self._far))
        z = np.where((seg == 0) | (z >= 0.99 * self._far), np.inf, z).astype(np.float32)
        return ViewImage(z, np.where(seg == 0, -1, geom))

    def _segment_table(self) -> np.ndarray:
        """Segmentation colour (scene geom index + 1, 0 = nothing) -> model geom id, -1 for non-geoms."""
        table = np.full(self._scene.ngeom + 1, -1, np.int64)
        for i in range(self._scene.ngeom):
            g = self._scene.geoms[i]
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                table[i + 1] = g.objid
        return table

    def close(self) -> None:
        """Free the GL resources (the MuJoCo context inside its own GL context, as mujoco.Renderer does)."""
        if self._ctx is not None:
            with self._gl.as_current():
                self._ctx.free()
            self._ctx = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __del__(self) -> None:
        self.close()
