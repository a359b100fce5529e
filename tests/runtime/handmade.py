"""A tiny contract-conforming student.onnx built with onnx.helper, for the runtime's own tests.

It tests loading, validation and the loop's plumbing only, never a policy: every action is the same joint
delta and gripper value, plus ``noise_gain`` times the DDIM start noise (so the seed shows in the output).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from runtime.metadata import METADATA_KEY, PolicyMetadata
from runtime.preprocess import DepthSpec

DELTA = 0.01
"""Joint delta (rad) every action of the handmade student carries."""


def metadata(**over) -> PolicyMetadata:
    return PolicyMetadata(preprocess=DepthSpec(), **over)


def build(path: Path, *, meta: PolicyMetadata | None = None, meta_json: str | None = None,
          gripper: float = 1.0, noise_gain: float = 0.0, nan: bool = False,
          horizon: int | None = None) -> Path:
    """Write the model to ``path``. ``meta_json`` overrides the metadata text verbatim (None: from ``meta``);
    ``horizon`` overrides the graph's action horizon to disagree with the metadata."""
    meta = meta or metadata()
    ha = horizon or meta.action_horizon
    shapes = {**meta.input_shapes(), "noise": [1, ha, meta.action_dim]}
    bias = np.full((1, ha, meta.action_dim), DELTA, np.float32)
    bias[..., -1] = np.nan if nan else gripper
    nodes = [
        helper.make_node("ReduceMean", ["depth"], ["depth_mean"], keepdims=0),
        helper.make_node("ReduceSum", ["state"], ["state_sum"], keepdims=0),
        helper.make_node("Add", ["depth_mean", "state_sum"], ["obs"]),
        helper.make_node("Mul", ["obs", "zero"], ["obs_zero"]),  # ties the observations into the graph
        helper.make_node("Mul", ["noise", "gain"], ["scaled_noise"]),
        helper.make_node("Add", ["scaled_noise", "bias"], ["chunk"]),
        helper.make_node("Add", ["chunk", "obs_zero"], ["actions"]),
    ]
    graph = helper.make_graph(
        nodes, "handmade_student",
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in shapes.items()],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, ha, meta.action_dim])],
        [numpy_helper.from_array(np.float32(0.0), "zero"),
         numpy_helper.from_array(np.float32(noise_gain), "gain"), numpy_helper.from_array(bias, "bias")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 9
    text = meta.to_json() if meta_json is None else meta_json
    if text:
        helper.set_model_props(model, {METADATA_KEY: text})
    onnx.checker.check_model(model)
    path.write_bytes(model.SerializeToString())
    return path


def meta_dict(**over) -> str:
    """Metadata JSON with fields replaced or (value None) removed."""
    d = json.loads(metadata().to_json())
    for k, v in over.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    return json.dumps(d)
