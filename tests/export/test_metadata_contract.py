"""The exported file carries the metadata contract; the runtime refuses it when that metadata is wrong."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from export.graph import read_metadata
from runtime.metadata import METADATA_KEY, PolicyMetadata
from runtime.policy import Policy, PolicyError


def rewrite_metadata(src, dst, edit) -> None:
    model = onnx.load(str(src))
    prop = next(p for p in model.metadata_props if p.key == METADATA_KEY)
    prop.value = json.dumps(edit(json.loads(prop.value)))
    onnx.save(model, str(dst))


def test_runtime_loads_and_runs_the_export(untrained_student_onnx):
    policy = Policy(untrained_student_onnx)
    meta = policy.metadata
    actions = policy(np.zeros(meta.input_shapes()["depth"][1:], np.float32), np.zeros(8, np.float32))
    assert actions.shape == (meta.action_horizon, 8) and np.isfinite(actions).all()


def test_metadata_describes_the_checkpoint(untrained_student_onnx, untrained_student_checkpoint):
    meta = read_metadata(onnx.load(str(untrained_student_onnx)))
    assert meta == PolicyMetadata.from_json(meta.to_json())
    assert meta.training_data["checkpoint"] == str(untrained_student_checkpoint.resolve())
    assert len(meta.training_data["checkpoint_sha256"]) == 64
    assert meta.normalisation["action"]["low"] == [-1.0] * 8  # identity statistics of an untrained student


@pytest.mark.parametrize("edit, match", [
    (lambda d: d | {"schema": "diffudepgrasp.policy/0"}, "schema"),
    (lambda d: {k: v for k, v in d.items() if k != "schema"}, "schema"),
    (lambda d: d | {"action_horizon": 8, "exec_horizon": 8}, "noise"),
    (lambda d: d | {"state_dim": 7}, "state_dim"),
])
def test_runtime_refuses_wrong_metadata(untrained_student_onnx, tmp_path, edit, match):
    bad = tmp_path / "bad.onnx"
    rewrite_metadata(untrained_student_onnx, bad, edit)
    with pytest.raises(PolicyError, match=match):
        Policy(bad)


def test_exec_horizon_is_chosen_at_export(untrained_student_checkpoint, tmp_path, capsys):
    from export.__main__ import main as export_main

    out = tmp_path / "exec4.onnx"
    assert export_main([str(untrained_student_checkpoint), "--exec-horizon", "4", "--out", str(out)]) == 0
    assert Policy(out).metadata.exec_horizon == 4
    assert export_main([str(untrained_student_checkpoint), "--exec-horizon", "17", "--out", str(out)]) == 2
    assert "exec_horizon 17" in capsys.readouterr().err
