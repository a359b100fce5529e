"""Simulated D455: 848x480 intrinsics, uint16 mm, 0 = no data, geometry consistent with K and pose."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.camera import Intrinsics, d455_intrinsics, to_millimetres
from hil_sim.world import TABLE_Z, World
from runtime.preprocess import DepthSpec


def test_intrinsics_are_the_d455_848x480_mode() -> None:
    intr = d455_intrinsics(DepthSpec())
    assert (intr.width, intr.height) == (848, 480)
    # 1280x720 factory calibration (f 636.76/636.36, p 627.56/374.71) scaled by 2/3, cropped to 848 wide
    assert intr.fx == pytest.approx(636.763 * 2 / 3, abs=0.05)
    assert intr.fy == pytest.approx(636.356 * 2 / 3, abs=0.05)
    assert intr.cx == pytest.approx(627.562 * 2 / 3 - (1280 * 2 / 3 - 848) / 2, abs=0.05)
    assert intr.cy == pytest.approx(374.707 * 2 / 3, abs=0.05)
    hfov = np.degrees(2 * np.arctan(intr.width / 2 / intr.fx))
    assert 85 < hfov < 92  # datasheet: 87 +- 3 degrees
    assert intr.min_z_m == pytest.approx(0.34, abs=0.01)


def test_millimetres_and_no_data_rule() -> None:
    intr = Intrinsics()
    depth = np.array([[0.2, 0.339, 0.34, 0.9004, 5.9, 6.5, 10.0]], np.float32)
    mm = to_millimetres(depth, intr)
    assert mm.dtype == np.uint16
    assert mm.tolist() == [[0, 0, 340, 900, 5900, 0, 0]]


def _backproject(world: World, depth_mm: np.ndarray, rows: slice, cols: slice) -> np.ndarray:
    intr = world.intr
    v, u = np.mgrid[rows, cols]
    z = depth_mm[rows, cols].astype(float) / 1000.0
    cam = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z, np.ones_like(z)], -1)
    return (cam.reshape(-1, 4) @ world.camera_extrinsics().T)[:, :3]


@pytest.mark.parametrize("randomise", [False, True])
def test_table_pixels_backproject_onto_the_table_plane(world: World, randomise: bool) -> None:
    world.reset("cube", seed=5, randomise=randomise)
    depth = world.render_depth()
    assert depth.dtype == np.uint16 and depth.shape == (480, 848)
    points = _backproject(world, depth, slice(420, 480, 7), slice(250, 600, 11))
    assert np.all(depth[420:480:7, 250:600:11] > 0)
    assert np.abs(points[:, 2] - TABLE_Z).max() < 0.002  # 20 px of cy error gives 26 mm


def test_object_projects_where_the_camera_sees_it(world: World) -> None:
    world.reset("can", seed=2)
    pos, _ = world.object_pose()
    top = pos + [0, 0, world.object_extent()[2]]  # centre of the can's lid
    T = np.linalg.inv(world.camera_extrinsics())
    cam = T[:3, :3] @ top + T[:3, 3]
    u, v = (world.intr.K @ (cam / cam[2]))[:2]
    depth = world.render_depth()
    seen = depth[int(round(v)), int(round(u))] / 1000.0
    assert seen == pytest.approx(cam[2], abs=0.01)
    lid = _backproject(world, depth, slice(0, 480), slice(0, 848))
    near = np.linalg.norm(lid[:, :2] - pos[:2], axis=1) < 0.06
    lid = lid[(depth.ravel() > 0) & near & (np.abs(lid[:, 2] - top[2]) < 0.004)]
    assert len(lid) > 50
    assert np.linalg.norm(lid[:, :2].mean(axis=0) - pos[:2]) < 0.006  # 15 px of cx error gives 30 mm


def test_sky_and_far_floor_read_zero(world: World) -> None:
    world.reset("cube", seed=0, randomise=False)
    depth = world.render_depth()
    assert (depth == 0).any(), "beyond max range must be no data"
    valid = depth[depth > 0]
    assert valid.min() >= 340 and valid.max() <= 6000


@pytest.mark.parametrize("seed", [0, 1])
def test_policy_camera_matches_crop_resize_of_the_stream(world: World, seed: int) -> None:
    from runtime.preprocess import crop_resize, normalise

    ep = world.reset("banana", seed=seed, randomise=bool(seed))
    exact = crop_resize(world.render_depth(), world.spec, ep.crop_window)
    fast = world.render_policy_depth()
    assert fast.shape == exact.shape and fast.dtype == np.uint16
    diff = np.abs(normalise(exact, 0.001, world.spec) - normalise(fast, 0.001, world.spec))
    assert (diff < 0.01).mean() > 0.99  # sub-pixel sampling differs only at depth edges
    assert ((exact == 0) != (fast == 0)).mean() < 0.005
