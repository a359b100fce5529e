import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from runtime.preprocess import DepthSpec
from trainer.ddg.graft import HOLE_THRESHOLD, GraftError, decode, edge_band, encode, graft, graft_edges

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


def test_decode_threshold_is_on_the_relative_scale():
    pred = np.array([[-1.0, HOLE_THRESHOLD - 1e-3, HOLE_THRESHOLD + 1e-3, 0.0, 0.5, 1.0, 1.7]], np.float32)
    mm = decode(pred[None], np.array([[0.25, 0.5]]), SPEC)  # 0..1 -> 0.6..1.2 m
    assert mm.tolist() == [[[0, 0, 600, 600, 900, 1200, 1200]]]


@settings(max_examples=40, deadline=None)
@given(depth=arrays(np.uint16, (6, 8), elements=st.integers(0, 2000)), lo=st.floats(0.0, 0.5),
       span=st.floats(0.05, 0.5))
def test_decode_inverts_encode_within_a_millimetre(depth, lo, span):
    back = decode(encode(depth, (lo, span), SPEC)[None], np.array([[lo, span]]), SPEC)[0]
    lo_mm, hi_mm = (round(1000 * (SPEC.near_m + v * (SPEC.far_m - SPEC.near_m))) for v in (lo, lo + span))
    inside = (depth >= lo_mm + 1) & (depth <= hi_mm - 1)
    assert np.all(back[depth == 0] == 0)
    assert np.abs(back[inside].astype(int) - depth[inside]).max(initial=0) <= 1


def test_graft_rejects_mismatched_inputs():
    with pytest.raises(GraftError, match="shapes differ"):
        graft(np.zeros((4, 4), np.uint16), np.zeros((4, 5), np.uint16), SPEC)
    with pytest.raises(GraftError, match="uint16"):
        graft(np.zeros((4, 4), np.float32), np.zeros((4, 4), np.uint16), SPEC)


def test_edge_grafting_keeps_the_generated_depth_near_edges_only_and_its_holes_everywhere():
    sim = np.full((1, 10, 16), 800, np.uint16)
    sim[:, :, 8:] = 1200  # one vertical depth edge between columns 7 and 8
    made = sim + np.uint16(37)
    made[0, 5, 2] = made[0, 5, 8] = 0  # a hole on the flat, one at the edge
    out = graft_edges(sim, made)
    near = edge_band(sim[0])
    assert near[:, 6:10].all() and not near[:, :5].any() and not near[:, 11:].any()
    keep = (made != 0) & near[None]
    assert np.array_equal(out[keep], made[keep])
    flat = (made != 0) & ~near[None]
    assert np.array_equal(out[flat], sim[flat])
    assert out[0, 5, 2] == 0 and out[0, 5, 8] == 0 and out.dtype == np.uint16
    with pytest.raises(GraftError, match="equal"):
        graft_edges(sim, made[:, :, :8])
