import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from runtime.preprocess import DepthSpec
from trainer.ddg.graft import HOLE_THRESHOLD, GraftError, decode, graft

SPEC = DepthSpec()
frames = arrays(np.uint16, (12, 16), elements=st.integers(0, 3000))


@settings(max_examples=60, deadline=None)
@given(sim=frames, pred=frames)
def test_grafting_keeps_every_non_hole_pixel_of_sim_bit_exact(sim, pred):
    out = graft(sim, pred, SPEC)
    keep = (pred != 0) & (sim >= 300)
    assert out.dtype == np.uint16
    assert np.array_equal(out[keep], sim[keep])
    assert np.all(out[~keep] == 0)


def test_holes_come_from_prediction_and_sensor_near_limit():
    sim = np.full((4, 4), 900, np.uint16)
    sim[0, 0] = 250  # closer than near_m = 0.3 m: a D4xx returns nothing there
    pred = np.full((4, 4), 1200, np.uint16)
    pred[3, 3] = 0
    out = graft(sim, pred, SPEC)
    assert out[0, 0] == 0 and out[3, 3] == 0
    assert (out == 900).sum() == 14


def test_decode_threshold_is_on_the_normalised_scale():
    pred = np.array([[-1.0, HOLE_THRESHOLD - 1e-3, HOLE_THRESHOLD + 1e-3, 0.0, 0.5, 1.0, 1.7]], np.float32)
    mm = decode(pred, SPEC)
    assert mm.tolist() == [[0, 0, 300, 300, 900, 1500, 1500]]


def test_graft_rejects_mismatched_inputs():
    with pytest.raises(GraftError, match="shapes differ"):
        graft(np.zeros((4, 4), np.uint16), np.zeros((4, 5), np.uint16), SPEC)
    with pytest.raises(GraftError, match="uint16"):
        graft(np.zeros((4, 4), np.float32), np.zeros((4, 4), np.uint16), SPEC)
