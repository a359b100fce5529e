"""A policy file whose DDIM start noise is scaled by a temperature (issue 42): does a colder draw grasp more?

The runtime draws the start noise from a standard normal and the graph denoises it in 4 DDIM steps; at
temperature 0 every chunk is the one denoised from zero noise, a deterministic policy. This writes a copy of
a policy file with one Mul on its ``noise`` input, metadata kept, so ``trainer evaluate`` and ``hil_sim`` run
it as they run the original.

    PYTHONPATH=. python research/noise_temperature.py models/student.onnx --scale 0 --out cold.onnx
    python -m trainer evaluate --policy student:cold.onnx --sensor clean --objects unseen --episodes 180 \
        --workers 2 --seed 10000
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper


def scaled(model: onnx.ModelProto, scale: float) -> onnx.ModelProto:
    """``model`` reading ``noise * scale`` wherever it read ``noise``."""
    graph = model.graph
    if "noise" not in {i.name for i in graph.input}:
        raise SystemExit("the graph has no 'noise' input: not a student policy file")
    graph.initializer.append(numpy_helper.from_array(np.array(scale, np.float32), "noise_temperature"))
    for node in graph.node:
        node.input[:] = ["noise_scaled" if name == "noise" else name for name in node.input]
    graph.node.insert(0, helper.make_node("Mul", ["noise", "noise_temperature"], ["noise_scaled"]))
    onnx.checker.check_model(model)
    return model


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", type=Path)
    p.add_argument("--scale", type=float, required=True, help="the start noise's standard deviation")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    onnx.save(scaled(onnx.load(args.model), args.scale), args.out)
    print(f"{args.out}: start noise x {args.scale}")


if __name__ == "__main__":
    main()
