"""``python -m trainer ddg paired``: each source's depth against the exact depth of the same view."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trainer.ddg.data import RealDataError, RealFrame
from trainer.eval.paired_depth import PairedConfig, hole_agreement, paired, policy_views, wrong_depth
from trainer.sim.capture import capture


def test_wrong_depth_counts_holes_and_errors_in_the_policy_range_only():
    exact = np.full((1, 10, 20), 1000, np.uint16)
    exact[0, :, 15:] = 2000  # beyond the policy's 1.5 m: not judged, whatever the source says there
    depth = exact.copy()
    depth[0, :, 15:] = 0
    depth[0, :5, :5] = 0  # 25 of the 150 judged pixels lost
    depth[0, 5:, :5] += 100  # 25 of the 125 kept ones 100 mm off
    depth[0, 5:, 5:10] += 20  # 25 more 20 mm off
    s = wrong_depth(depth, exact)
    assert s["holes_pct"] == pytest.approx(100 * 25 / 150, abs=0.01)
    assert s["off_over_50mm_pct"] == pytest.approx(20.0) and s["off_median_mm"] == 0.0
    assert s["off_p90_mm"] == pytest.approx(100.0) and s["off_p99_mm"] == pytest.approx(100.0)
    with pytest.raises(ValueError, match="differ in shape"):
        wrong_depth(depth, exact[:, :5])


def test_hole_agreement_counts_holes_where_the_sensor_has_them():
    exact = np.full((1, 10, 10), 1000, np.uint16)
    exact[0, 9] = 3000  # beyond the policy's range: its holes are not counted
    sensor, source = exact.copy(), exact.copy()
    sensor[0, :4], source[0, 2:4], source[0, 5] = 0, 0, 0  # sensor: 40 holes; source: 20 of them + 10 more
    sensor[0, 9], source[0, 9] = 0, 0
    assert hole_agreement(source, sensor, exact) == {"sensor_holes_shared_pct": 50.0,
                                                     "holes_the_sensors_pct": pytest.approx(66.7)}
    assert hole_agreement(sensor, sensor, exact)["holes_the_sensors_pct"] == 100.0


def test_the_sensor_is_judged_against_its_own_scene_and_grafting_keeps_it_exact(tmp_path, tiny_model):
    capture("stereo", ("cube",), 1, (0, 10), 70_000, tmp_path / "cap")
    out = tmp_path / "paired.json"
    result = paired(PairedConfig(real=str(tmp_path / "cap"), model=(str(tiny_model),), threads=1,
                                 json=str(out)))
    sensor, grafted = result["sources"]["sensor"], result["sources"][f"{tiny_model} grafted"]
    assert result["frames"] == 2 and json.loads(out.read_text())["sources"]["sensor"] == sensor
    assert 0 < sensor["holes_pct"] < 50 and sensor["off_median_mm"] < 15 and sensor["off_p99_mm"] > 50
    assert grafted["off_p99_mm"] == 0.0  # every pixel grafting keeps is the exact depth


def test_frames_without_exact_depth_are_refused_by_name():
    frame = RealFrame("real_one", np.full((480, 848), 900, np.uint16), "d4xx", "s", 0, window=(90, 224))
    with pytest.raises(RealDataError, match="1 frames lack the exact depth .* e.g. real_one"):
        policy_views([frame])
