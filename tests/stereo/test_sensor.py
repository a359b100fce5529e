"""The D4xx signatures the stereo model must produce, on analytic scenes (fast) and in the MuJoCo world."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.camera import d455_intrinsics
from hil_sim.stereo import StereoParams
from hil_sim.stereo.ir import value_noise
from hil_sim.stereo.match import INVALID
from hil_sim.stereo.sensor import Rig, episode_material
from tests.stereo.conftest import box_columns, box_scene, materials


def _holes(rig, box_albedo=0.8, seed=0):
    frame = rig.frame(box_scene(rig), materials(box_albedo), np.random.default_rng(seed))
    return frame.disparity == INVALID


def test_occlusion_shadow_is_on_the_left_of_an_object(rig):
    """The right imager cannot see the wall just left of the box: fB(1/0.6 - 1/1.0) ~ 13 px of holes. On the
    right only the projector's own shadow (it sits between the imagers: ~7 px) may lack dots."""
    holes = _holes(rig)
    left, right = box_columns(rig)
    rows = slice(int(rig.intr.cy) - 15, int(rig.intr.cy) + 15)
    shadow = float(np.mean(holes[rows, left - 11:left - 2]))
    beside = float(np.mean(holes[rows, right + 9:right + 18]))
    assert shadow > 0.8, f"only {shadow:.0%} holes in the occluded strip left of the object"
    assert beside < 0.2, f"{beside:.0%} holes right of the object, where both imagers see the wall"


def test_a_dark_object_gets_more_holes_than_a_bright_one(rig):
    left, right = box_columns(rig)
    rows = slice(int(rig.intr.cy) - 20, int(rig.intr.cy) + 20)
    inner = (rows, slice(left + 6, right - 6))
    bright, dark = _holes(rig, 0.8)[inner].mean(), _holes(rig, 0.03)[inner].mean()
    assert dark > bright + 0.3, f"dark object holes {dark:.0%} vs bright {bright:.0%}"


def test_noise_on_a_flat_wall_grows_with_distance(rig):
    def spread_mm(z):
        d = rig.wall(z, seed=1).depth_mm[:, 200:].astype(float)  # right of the left band
        valid = d[d > 0]
        assert valid.size > 0.5 * d.size, f"wall at {z} m mostly holes"
        assert abs(np.median(valid) - 1000 * z) < 0.01 * 1000 * z, "wall depth off by more than 1 %"
        return np.percentile(valid, 84) - np.percentile(valid, 16)

    near, far = spread_mm(0.5), spread_mm(1.2)
    assert far > 2.5 * near, f"noise at 1.2 m ({far:.1f} mm) should be well above 0.5 m's ({near:.1f} mm)"


def test_left_band_width_follows_the_d4xx_formula(rig):
    """Left no-data band = the right imager's blind strip f B / z stream pixels plus a few for the matching
    window (real D4xx frames here: 1.03-1.14 x), not OpenCV's fixed numDisparities."""
    for z in (0.5, 1.0):
        depth = rig.wall(z, seed=2).depth_mm
        band = int(np.argmin((depth == 0).mean(axis=0) > 0.5))
        blind = 424.51 * rig.params.baseline_m / z
        assert blind <= band <= 1.3 * blind, f"band {band} px at {z} m, blind strip {blind:.0f} px"


def test_world_frames_are_deterministic_under_a_seed(world, sensor):
    world.reset("cube", 3)
    sensor.reset(world, 3)
    first = sensor.stream(world)
    sensor.reset(world, 3)
    again = sensor.stream(world)
    sensor.reset(world, 4)
    other = sensor.stream(world)
    assert first.shape == (480, 848) and first.dtype == np.uint16
    np.testing.assert_array_equal(first, again)
    assert np.any(first != other), "a different seed must draw different noise"


def test_an_episodes_material_is_known_from_its_seed_without_a_world(world, sensor):
    drawn = []
    for seed in range(12):
        sensor.reset(world, seed)
        assert sensor.material == episode_material(seed, sensor.params)
        drawn.append(sensor.material)
    assert len(set(drawn)) == 3, f"12 episodes should draw every material, drew {sorted(set(drawn))}"


def test_world_depth_matches_the_exact_depth_where_valid(world, sensor):
    world.reset("cube", 5)
    sensor.reset(world, 5)
    stereo, exact = sensor.stream(world).astype(float), world.render_depth().astype(float)
    both = (stereo > 0) & (exact > 0) & (exact < 1500)
    assert both.mean() > 0.3
    assert np.median(np.abs(stereo[both] - exact[both])) < 10, "stereo depth should sit on the true surfaces"
    assert ((stereo == 0) & (exact > 0)).mean() > 0.01, "a stereo frame without holes is not a D4xx frame"


def test_frame_before_reset_is_a_clear_error(world, sensor):
    with pytest.raises(RuntimeError, match="reset"):
        sensor.stream(world)


def test_passive_surface_texture_keeps_depth_where_the_dots_fade():
    """At 3 m the projector's dots are too dim to match on a uniform wall; the same wall with a surface
    texture under ambient light keeps its depth, as real surfaces do."""
    params = StereoParams.load().replace(ambient=0.2, texture_threshold=2.0)
    holes = {}
    for texture in (0.0, 0.6):
        rig = Rig(params.replace(surface_texture=texture), d455_intrinsics())
        depth = rig.wall(3.0, seed=1).depth_mm[:, 300:]  # right of the left band
        holes[texture] = float((depth == 0).mean())
        valid = depth[depth > 0]
        if valid.size:
            assert abs(np.median(valid) - 3000) < 60, "textured wall depth off by more than 2 %"
    assert holes[0.0] > 0.5 and holes[0.6] < 0.1, holes


def test_value_noise_is_a_fixed_function_of_the_surface_point():
    pts = np.random.default_rng(0).uniform(-2, 2, (500, 3)).astype(np.float32)
    a, b = value_noise(pts, 0.015), value_noise(pts.copy(), 0.015)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a).max() <= 1.0 and a.std() > 0.1
    near = value_noise(pts + 1e-4, 0.015)  # 0.1 mm away: almost the same value (smooth, not per-pixel)
    assert np.abs(near - a).max() < 0.1
