"""``--int8``: the encoder is quantised with static QDQ, and the result is kept only when it pays off."""

from __future__ import annotations

import onnx
import pytest

from export.graph import build_model, read_metadata
from export.quantize import MAX_ACTION_ERR, MIN_SPEEDUP, quantize_if_worth_it
from trainer.student import checkpoint


@pytest.mark.slow
def test_int8_decision_follows_the_measurement(untrained_student_checkpoint):
    ckpt = checkpoint.load(untrained_student_checkpoint)
    model, meta = build_model(ckpt, untrained_student_checkpoint, 4)
    out, report = quantize_if_worth_it(model, ckpt, threads=1)
    assert {"max_action_err", "fp32_ms", "int8_ms", "speedup", "kept"} <= set(report)
    assert report["kept"] == (report["speedup"] >= MIN_SPEEDUP and report["max_action_err"] <= MAX_ACTION_ERR)
    qdq = [n for n in out.graph.node if n.op_type == "QuantizeLinear"]
    assert bool(qdq) == report["kept"]
    assert all("/encoder/" in n.name for n in qdq if n.name)  # only the encoder is quantised
    onnx.checker.check_model(out)
    assert read_metadata(out) == meta
