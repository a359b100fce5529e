"""``python -m trainer ddg vs-sensor``: wrong depth and holes split near depth edges and on flat regions."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.preprocess import DepthSpec
from trainer.eval.sensor_realism import edge_regions, wrong_depth_by_region

SPEC = DepthSpec()


def _box() -> np.ndarray:
    """A 1 m floor with a box top at 0.8 m: its outline is the frame's only depth edge."""
    clean = np.full((1, 40, 40), 1000, np.uint16)
    clean[0, 15:25, 15:25] = 800
    return clean


def test_errors_and_holes_are_counted_in_the_region_they_fall_in():
    clean = _box()
    assert wrong_depth_by_region(clean, clean, edge_regions(clean, SPEC)) == {
        f"{r}_{k}": 0.0 for r in ("edge", "flat") for k in ("holes_pct", "off_20mm_pct", "off_50mm_pct")}
    fattened = clean.copy()
    fattened[0, 13:15, 18:22] = 800  # the box's top pulled 2 px out over the floor: edge pixels 200 mm off
    s = wrong_depth_by_region(fattened, clean, edge_regions(clean, SPEC))
    assert s["edge_off_50mm_pct"] > 0 and s["flat_off_20mm_pct"] == 0.0
    noisy = clean.copy()
    noisy[0, 30:, :] += 30  # far from the box: flat pixels 30 mm off, more than 2 cm, less than 5
    noisy[0, :5, :] = 0  # and a flat strip lost
    s = wrong_depth_by_region(noisy, clean, edge_regions(clean, SPEC))
    assert s["flat_off_20mm_pct"] > 0 and s["flat_off_50mm_pct"] == 0.0 and s["flat_holes_pct"] > 0
    assert s["edge_off_20mm_pct"] == 0.0 and s["edge_holes_pct"] == 0.0


def test_pixels_beyond_the_policy_range_are_not_judged():
    clean = _box()
    clean[0, :, 35:] = 3000  # past far_m: whatever a source says there is not counted
    source = clean.copy()
    source[0, :, 35:] = 0
    assert wrong_depth_by_region(source, clean, edge_regions(clean, SPEC))["flat_holes_pct"] == 0.0
    with pytest.raises(ValueError, match="differ in shape"):
        wrong_depth_by_region(source[:, :10], clean, edge_regions(clean, SPEC))
