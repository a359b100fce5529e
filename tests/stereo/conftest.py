"""Stereo fixtures: a rig without a scene (fast, analytic views) and one small MuJoCo world per module."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.camera import d455_intrinsics
from hil_sim.stereo import StereoParams, StereoSensor
from hil_sim.stereo.ir import Materials
from hil_sim.stereo.render import ViewImage
from hil_sim.stereo.sensor import Rig
from hil_sim.world import World

WALL, BOX = 0, 1


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig(StereoParams.load(), d455_intrinsics())


def box_scene(rig: Rig, box_z: float = 0.6, wall_z: float = 1.0, half: float = 0.06) -> list[ViewImage]:
    """Each view's picture of a square (geom BOX, side 2 * half, facing the sensor at box_z on its optical
    axis) in front of a wall (geom WALL at wall_z), found by casting every pixel's ray analytically."""
    views = []
    for view in rig.views:
        intr = view.intr
        v, u = np.mgrid[0:intr.height, 0:intr.width].astype(np.float64)
        x, y = (u - intr.cx) / intr.fx * box_z + view.offset_m, (v - intr.cy) / intr.fy * box_z
        on_box = (np.abs(x) < half) & (np.abs(y) < half)
        views.append(ViewImage(np.where(on_box, box_z, wall_z).astype(np.float32),
                               np.where(on_box, BOX, WALL).astype(np.int64)))
    return views


def materials(box_albedo: float, wall_albedo: float = 0.6) -> Materials:
    mats = Materials.uniform(2, wall_albedo)
    mats.albedo[BOX] = box_albedo
    return mats


def box_columns(rig: Rig, box_z: float = 0.6, half: float = 0.06) -> tuple[int, int]:
    """First and last working-image column of the box in the left image."""
    i = rig.intr
    return int(np.ceil(i.cx - half / box_z * i.fx)), int(np.floor(i.cx + half / box_z * i.fx))


@pytest.fixture(scope="module")
def world() -> World:
    w = World(("cube",))
    yield w
    w.close()


@pytest.fixture()
def sensor(world) -> StereoSensor:
    s = StereoSensor()
    yield s
    s.close()
