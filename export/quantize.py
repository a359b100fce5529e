"""``--int8``: static QDQ quantisation of the depth encoder's convolutions (onnxruntime.quantization),
calibrated on real training frames when the demos are at hand. The DDIM head stays float: its inputs swing
over the whole noise schedule and it is run K times, so its error would compound.

The quantised graph is kept only when it is measurably faster here AND its actions stay close to the
float graph's; otherwise the float graph is returned and the report says why.
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

from export.check import session, timed_side_by_side
from export.graph import read_metadata
from export.reference import example_feeds
from runtime.metadata import PolicyMetadata
from trainer.student.checkpoint import Checkpoint

MAX_ACTION_ERR = 2e-3
"""Largest tolerated |int8 - float| over calibration inputs, robot units (rad; 2 mrad is ~0.2 mm at 10 cm)."""
MIN_SPEEDUP = 1.1
"""Required float/int8 median latency ratio on this machine."""


class _Frames(CalibrationDataReader):
    def __init__(self, feeds: list[dict[str, np.ndarray]]) -> None:
        self._it = iter(feeds)

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._it, None)


def calibration_feeds(meta: PolicyMetadata, ckpt: Checkpoint, count: int = 32) -> list[dict[str, np.ndarray]]:
    """Observation stacks from the checkpoint's demos if the store is here, else random inputs."""
    rng = np.random.default_rng(0)
    demos = ckpt.info.data.get("demos")
    if demos and Path(demos).exists():
        from trainer.student.data import DemoDataset
        source = ckpt.info.data.get("depth_source", "gt")
        data = DemoDataset.stacked_as(demos, source, meta, meta.preprocess)
        batch = data.batch(rng.integers(0, len(data), count), rng)
        pairs = [(batch.depth[i:i + 1].numpy(), batch.state[i:i + 1].numpy()) for i in range(count)]
    else:
        pairs = [(f["depth"], f["state"]) for f in (example_feeds(meta, seed) for seed in range(count))]
    noise_shape = meta.input_shapes()["noise"]
    return [{"depth": d, "state": s, "noise": rng.standard_normal(noise_shape).astype(np.float32)}
            for d, s in pairs]


def encoder_convs(model: onnx.ModelProto) -> list[str]:
    """Names of the depth encoder's convolutions: every Conv outside the diffusion head (a plain student's sit
    under ``/encoder/``, a perception student's under ``/perception/``)."""
    return [n.name for n in model.graph.node if n.op_type == "Conv" and "/head/" not in n.name]


def quantize_if_worth_it(model: onnx.ModelProto, ckpt: Checkpoint | None, threads: int = 2,
                         feeds: list[dict[str, np.ndarray]] | None = None) -> tuple[onnx.ModelProto, dict]:
    """``model`` with its encoder in int8 if that pays off (else as it was) and the report; calibrated on
    ``feeds`` when given (e.g. frames of a recipe's stores), else on ``ckpt``'s demos."""
    feeds = feeds or calibration_feeds(read_metadata(model), ckpt)
    convs = encoder_convs(model)
    with tempfile.TemporaryDirectory() as tmp:
        fp32, int8 = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
        onnx.save(model, fp32)
        quantize_static(fp32, int8, _Frames(feeds), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QInt8, weight_type=QuantType.QInt8,
                        nodes_to_quantize=convs)
        report = compare(fp32, int8, feeds, threads) | {"quantised_convs": len(convs)}
        quantised = onnx.load(str(int8))
    keep = report["speedup"] >= MIN_SPEEDUP and report["max_action_err"] <= MAX_ACTION_ERR
    report["kept"] = keep
    if not keep:
        return model, report
    del quantised.metadata_props[:]
    quantised.metadata_props.extend(model.metadata_props)
    onnx.checker.check_model(quantised)
    return quantised, report


def compare(fp32: Path, int8: Path, feeds: list[dict[str, np.ndarray]], threads: int) -> dict:
    a, b = session(fp32, threads), session(int8, threads)
    err = max(float(np.abs(a.run(None, f)[0] - b.run(None, f)[0]).max()) for f in feeds)
    times = timed_side_by_side([lambda: a.run(None, feeds[0]), lambda: b.run(None, feeds[0])], 30)
    fp32_ms, int8_ms = (statistics.median(t) for t in times)
    return {"max_action_err": err, "fp32_ms": fp32_ms, "int8_ms": int8_ms,
            "speedup": fp32_ms / int8_ms}
