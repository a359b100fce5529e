import numpy as np
import pytest
from scipy import ndimage

from trainer.ddg.prior import DepthPrior, OnnxPrior, PriorError, fill_holes, relative_depth, temporal_fuse

from .conftest import scene


def _nearest_filled(depth):
    idx = ndimage.distance_transform_edt(depth == 0, return_distances=False, return_indices=True)
    return depth[tuple(idx)]


def test_prior_normalisation_is_identical_on_real_and_sim_inputs():
    rng = np.random.default_rng(1)
    sim = scene(rng)
    real = sim.copy()
    real[rng.random(real.shape) < 0.1] = 0  # the "sensor" loses 10% of pixels
    real[30:40, 50:70] = 0
    sim_like = _nearest_filled(real)  # what the real frame's geometry is, hole-free, as sim would render it
    prior = DepthPrior()
    c_real, c_sim = prior(real), prior(sim_like)
    assert np.array_equal(c_real, c_sim)
    assert c_real.dtype == np.float32 and c_real.min() >= -1 and c_real.max() <= 1
    assert np.isfinite(c_real).all()


def test_hole_pattern_does_not_leak_into_the_prior():
    yy, xx = np.mgrid[0:96, 0:128]
    geometry = np.rint(900 + 0.8 * yy + 0.3 * xx).astype(np.uint16)  # a flat, tilted table
    a, b = geometry.copy(), geometry.copy()
    a[10:20, 10:30] = 0
    b[60:75, 90:120] = 0
    b[np.random.default_rng(0).random(b.shape) < 0.05] = 0
    ca, cb = DepthPrior()(a), DepthPrior()(b)
    # two hole patterns, one geometry: the same condition, up to a few mm inside the biggest filled hole
    # (0.15 of c's [-1, 1] range is ~8 mm on this 114 mm deep view)
    assert np.abs(ca - cb).mean() < 0.005 and np.abs(ca - cb).max() < 0.15


def test_relative_depth_is_affine_invariant():
    d = scene(np.random.default_rng(3)).astype(np.float32)
    assert np.allclose(relative_depth(d), relative_depth(3 * d + 100), atol=1e-5)


def test_fill_holes_rejects_empty_frame():
    with pytest.raises(PriorError, match="no valid depth"):
        fill_holes(np.zeros((8, 8), np.uint16))


def test_temporal_fusion_fills_only_agreeing_holes():
    frames = np.full((3, 4, 4), 800, np.uint16)
    frames[1, 0, 0] = 0  # neighbours agree -> filled
    frames[1, 1, 1] = 0
    frames[0, 1, 1], frames[2, 1, 1] = 700, 900  # neighbours disagree (moving camera) -> stays a hole
    fused = temporal_fuse(frames)
    assert fused[1, 0, 0] == 800 and fused[1, 1, 1] == 0
    assert np.array_equal(fused[0], frames[0])


def _standin_depth_anything(path, size=28):
    """Same I/O as a Depth Anything V2 export: [1, 3, S, S] image -> [1, S, S] inverse depth (here: mean)."""
    import onnx
    from onnx import TensorProto, helper

    node = helper.make_node("ReduceMean", ["pixel_values"], ["predicted_depth"], axes=[1], keepdims=0)
    inp = helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [1, 3, size, size])
    out = helper.make_tensor_value_info("predicted_depth", TensorProto.FLOAT, [1, size, size])
    graph = helper.make_graph([node], "standin", [inp], [out])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)


def test_onnx_prior_runs_a_local_depth_anything_standin(tmp_path):
    path = tmp_path / "depth_anything_v2.onnx"
    _standin_depth_anything(str(path))
    prior = OnnxPrior(path)
    rgb = np.zeros((96, 128, 3), np.uint8)
    rgb[:, 64:] = 255  # bright half = large "inverse depth" = near
    c = prior(None, rgb)
    assert c.shape == (96, 128) and c.dtype == np.float32
    assert c[:, :60].mean() > c[:, 70:].mean()  # near maps to low c, as for depth input
    with pytest.raises(PriorError, match="needs an RGB"):
        prior(None, None)
    with pytest.raises(PriorError, match="no ONNX depth model"):
        OnnxPrior(tmp_path / "missing.onnx")
