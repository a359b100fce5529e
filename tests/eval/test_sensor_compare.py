"""``trainer.eval.sensor_compare``: the statistics that explain what a sensor takes from the student."""

from __future__ import annotations

import numpy as np
import pytest

from trainer.eval.sensor_compare import main, statistics


def test_statistics_separate_lost_pixels_in_and_beyond_the_policy_range():
    clean = np.zeros((4, 4), np.uint16)
    clean[:, :2] = 800  # in range
    clean[:, 2] = 2000  # beyond far_m = 1.5 m
    lossy = clean.copy()
    lossy[:2, 0] = 0  # 2 of 8 in-range pixels lost
    lossy[:, 2] = 0  # every far pixel lost
    lossy[0, 3] = 900  # a no-data pixel given a value, 1 of 4
    lossy[1, 1] = 810
    stats = statistics([{"clean": clean, "lossy": lossy}])["lossy"]
    assert stats["in_range_lost"] == pytest.approx(2 / 8)
    assert stats["measurable_lost"] == pytest.approx(6 / 12)
    assert stats["no_data_filled"] == pytest.approx(1 / 4)
    assert stats["holes"] == pytest.approx(9 / 16)
    assert stats["median_abs_err_mm"] == 0.0  # 5 exact pixels, 1 off by 10 mm


def test_the_reference_must_be_clean(capsys):
    assert main(["--sensors", "stereo", "clean", "--episodes", "1"]) == 2
    assert "first sensor must be clean" in capsys.readouterr().err
