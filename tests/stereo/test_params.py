"""Bad parameters and files fail early, naming the problem."""

from __future__ import annotations

import json

import pytest

from hil_sim.stereo import DEFAULT_PARAMS, StereoParams, StereoParamsError
from hil_sim.stereo.ir import Materials


@pytest.mark.parametrize(("change", "message"), [
    ({"block_size": 4}, "block_size"), ({"num_disparities": 50}, "num_disparities"),
    ({"render_scale": 0.3}, "render_scale"), ({"baseline_m": 0.0}, "baseline_m"),
    ({"read_noise": -1.0}, "read_noise"), ({"material_probs": (0.5, 0.5, 0.5)}, "material_probs"),
    ({"min_correlation": 2.0}, "min_correlation"), ({"scene_albedo": 0.0}, "scene_albedo")])
def test_out_of_range_parameters_are_refused(change, message):
    with pytest.raises(StereoParamsError, match=message):
        StereoParams(**change)


def test_the_shipped_parameters_load_and_round_trip(tmp_path):
    params = StereoParams.load()
    assert params == StereoParams.load(DEFAULT_PARAMS)
    params.save(tmp_path / "p.json", command="test")
    assert StereoParams.load(tmp_path / "p.json") == params


@pytest.mark.parametrize(("content", "message"), [
    (None, "does not exist"), ("not json", "not JSON"), ("[1, 2]", "no 'params'"),
    (json.dumps({"params": {"warp_factor": 9}}), "unknown stereo parameters")])
def test_bad_parameter_files_are_refused(tmp_path, content, message):
    path = tmp_path / "params.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(StereoParamsError, match=message):
        StereoParams.load(path)


def test_unknown_material_is_refused():
    with pytest.raises(ValueError, match="unknown IR material 'velvet'"):
        Materials.uniform(1, 0.5).with_body([0], "velvet", None)
