"""``--int8``: the encoder is quantised with static QDQ, and the result is kept only when it pays off."""

from __future__ import annotations

from pathlib import Path

import onnx
import pytest

from export.graph import build_model, read_metadata
from export.quantize import MAX_ACTION_ERR, MIN_SPEEDUP, quantize_if_worth_it
from tests.conftest import TINY_STUDENT
from trainer.student import checkpoint
from trainer.student.cli import main as student_main


@pytest.fixture(params=["", "depth"], ids=["plain", "perception"])
def student(request, untrained_student_checkpoint, tmp_path_factory) -> Path:
    """The tiny untrained student, plain and as a perception student (whose encoder is named otherwise)."""
    if not request.param:
        return untrained_student_checkpoint
    path = tmp_path_factory.mktemp("int8") / "perception.pt"
    assert student_main(["init", "--out", str(path), *TINY_STUDENT, "--perception", request.param]) == 0
    return path


@pytest.mark.slow
def test_int8_decision_follows_the_measurement(student):
    ckpt = checkpoint.load(student)
    model, meta = build_model(ckpt, student, 4)
    out, report = quantize_if_worth_it(model, ckpt, threads=1)
    convs = [n.name for n in model.graph.node if n.op_type == "Conv"]
    encoder = [name for name in convs if "/head/" not in name]
    assert encoder and len(encoder) < len(convs) and report["quantised_convs"] == len(encoder)
    assert {"max_action_err", "fp32_ms", "int8_ms", "speedup", "kept"} <= set(report)
    assert report["kept"] == (report["speedup"] >= MIN_SPEEDUP and report["max_action_err"] <= MAX_ACTION_ERR)
    qdq = [n for n in out.graph.node if n.op_type == "QuantizeLinear"]
    assert bool(qdq) == report["kept"]
    assert not any("/head/" in n.name for n in qdq if n.name)  # only the encoder is quantised
    onnx.checker.check_model(out)
    assert read_metadata(out) == meta
