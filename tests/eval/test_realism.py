import numpy as np
import pytest

from runtime.preprocess import DepthSpec
from tests.ddg.conftest import scene
from trainer.eval.holes import hole_stats
from trainer.eval.judge import RandomEncoder, encoder_input, features, fid, kid
from trainer.eval.realism import bootstrap_ci, off_sim_mm
from trainer.eval.sim_frames import (
    MATCHED_DISTANCE_M,
    MATCHED_ELEVATION_DEG,
    MAX_VOID_FRACTION,
    matched_view,
    rendered,
    void_as_far,
)


def test_fid_and_kid_separate_distributions():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((300, 16)), rng.standard_normal((300, 16))
    shifted = rng.standard_normal((300, 16)) + 1.0
    assert fid(a, b) < 0.5 < fid(a, shifted)
    assert abs(kid(a, b)) < 0.02 < kid(a, shifted)


def test_fid_matches_the_matrix_square_root_formula():
    from scipy import linalg

    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((60, 5)), rng.standard_normal((80, 5)) @ rng.standard_normal((5, 5)) + 0.3
    ca, cb = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    ref = np.sum((a.mean(0) - b.mean(0)) ** 2) + np.trace(ca + cb - 2 * linalg.sqrtm(ca @ cb).real)
    assert abs(fid(a, b) - ref) < 1e-6 * max(1.0, ref)


def test_bootstrap_interval_covers_the_spread():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((120, 8)), rng.standard_normal((90, 8)) + 0.5
    groups_b = np.repeat(np.arange(30), 3)  # 3 rows per "frame"
    ci = bootstrap_ci(a, np.arange(120), b, groups_b, replicates=40)
    (flo, fhi), (klo, khi) = ci["fid_ci95"], ci["kid_ci95"]
    assert flo < fid(a, b) < fhi and klo < khi and fhi - flo > 0.05
    assert bootstrap_ci(a, np.arange(120), b, groups_b, replicates=0) == {}


def test_encoder_is_fixed_and_sees_holes():
    rng = np.random.default_rng(1)
    clean = np.stack([scene(rng) for _ in range(4)])
    holed = clean.copy()
    holed[:, 30:50, 30:60] = 0
    e1, e2 = features(clean, RandomEncoder()), features(clean, RandomEncoder())
    assert np.array_equal(e1, e2) and e1.shape == (4, 288)
    assert np.abs(features(holed) - e1).mean() > 1e-3
    x = encoder_input(holed)
    assert x[0, 1, 40, 40] == 1 and x[0, 0, 40, 40] == 0


def test_hole_stats_on_a_known_frame():
    f = np.full((1, 96, 128), 900, np.uint16)
    f[0, 10:13, 10:13] = 0  # one 3x3 hole in a flat region
    f[0, 50:, :] = 1100  # a depth edge at row 50
    f[0, 50, 60] = 0  # one single-pixel hole on the edge
    s = hole_stats(f)
    assert s["hole_fraction"] == 10 / (96 * 128)
    assert s["holes_per_frame"] == 2
    assert s["hole_size_px_p50_p90"][0] == 5.0  # sizes 1 and 9
    assert s["hole_rate_near_edges"] > s["hole_rate_flat"] > 0
    assert s["grad_jump_fraction"] > 0


def test_void_as_far_fills_only_the_no_data_pixels():
    sim = np.array([[[0, 900], [1200, 0]]], np.uint16)
    out = void_as_far(sim, DepthSpec())
    assert out.dtype == np.uint16 and out.tolist() == [[[1500, 900], [1200, 1500]]]


def test_the_judge_sees_one_channel_when_asked():
    """``--judge holes`` hides the depth: frames with the same holes on other scenes look the same to it, and
    ``--judge depth`` hides the mask (a hole still reads as 0 in the depth channel)."""
    rng = np.random.default_rng(2)
    a, b = np.stack([scene(rng) for _ in range(3)]), np.stack([scene(rng) for _ in range(3)])
    a[:, 20:30, 40:70] = b[:, 20:30, 40:70] = 0
    assert np.array_equal(features(a, channels="holes"), features(b, channels="holes"))
    assert not np.array_equal(features(a, channels="both"), features(b, channels="both"))
    x = encoder_input(a, "depth")
    assert not x[:, 1].any() and x[0, 0, 50, 50] > 0 and x[0, 0, 25, 50] == 0
    assert not encoder_input(a, "holes")[:, 0].any()
    with pytest.raises(ValueError, match="channels must be one of"):
        encoder_input(a, "colour")


@pytest.mark.parametrize("seed", range(20))
def test_matched_views_look_down_at_the_object_from_the_far_side(seed):
    rng = np.random.default_rng(seed)
    obj = np.array([0.5, 0.1, 0.78])
    pos, target = matched_view(obj, rng)
    offset = pos - target
    dist, elev = np.linalg.norm(offset), np.rad2deg(np.arcsin(offset[2] / np.linalg.norm(offset)))
    assert MATCHED_DISTANCE_M[0] <= dist <= MATCHED_DISTANCE_M[1]
    assert MATCHED_ELEVATION_DEG[0] <= elev <= MATCHED_ELEVATION_DEG[1]
    assert offset[0] >= 0 and np.all(np.abs(target[:2] - obj[:2]) <= 0.05) and target[2] == obj[2]


def test_matched_frames_are_close_views_without_void_and_reproducible():
    frames = rendered(6, seed=3, views="matched")
    assert frames.shape == (6, 96, 128) and frames.dtype == np.uint16
    assert all(np.mean(f == 0) <= MAX_VOID_FRACTION for f in frames)
    medians = [np.median(f[f > 0]) for f in frames]
    assert 400 <= min(medians) and max(medians) <= 1300  # the real captures' range, not the robot's 0.9-1.5 m
    assert np.array_equal(rendered(6, seed=3, views="matched"), frames)
    with pytest.raises(ValueError, match="views must be one of policy, matched"):
        rendered(1, views="wrist")


def test_off_sim_counts_only_pixels_both_measure():
    sim = np.array([[[1000, 1000, 0, 1000]]], np.uint16)
    moved = np.array([[[1010, 0, 500, 1100]]], np.uint16)  # 10 and 100 mm off where both measure
    assert off_sim_mm(moved, sim) == [55.0, 91.0]
    assert off_sim_mm(sim, sim) == [0.0, 0.0]
    assert all(np.isnan(off_sim_mm(np.zeros_like(sim), sim)))
