"""A policy file's encoder in int8, calibrated on frames a learner saw (issue 42): is the readout pair within
the inference budget this way, and does it still grasp?

``export.quantize`` calibrates on a checkpoint's demos, which a recipe student or a composed pair does not
name; this calibrates on ``patch_ceiling.py collect`` episodes (their policy frames stacked as the runtime
stacks them, their joint states) and writes the int8 file when ``export.quantize`` keeps it (>= 1.1x faster
here, actions within 2 mrad of the float graph's), else says why not.

    PYTHONPATH=. python research/int8_policy.py pair.onnx --frames DIR --out pair_int8.onnx [--count 64]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import onnx

from export.quantize import quantize_if_worth_it
from runtime.preprocess import DepthSpec, normalise
from trainer.dataset import DEPTH_SCALE


def feeds(folder: Path, count: int, noise_shape: tuple[int, ...], seed: int = 0
          ) -> list[dict[str, np.ndarray]]:
    """``count`` (depth stack, state, noise) inputs at random steps of the folder's episodes."""
    rng = np.random.default_rng(seed)
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise SystemExit(f"{folder}: no patch_ceiling.py episodes")
    out = []
    for path in rng.choice(files, count):
        ep = np.load(path)
        t = int(rng.integers(0, len(ep["state"])))
        rows = np.maximum(np.arange(t - 2, t + 1), 0)  # oldest first, the first frame repeated at the start
        out.append({"depth": normalise(ep["depth"][rows], DEPTH_SCALE, DepthSpec())[None],
                    "state": ep["state"][t:t + 1].astype(np.float32),
                    "noise": rng.standard_normal(noise_shape).astype(np.float32)})
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", type=Path)
    p.add_argument("--frames", type=Path, required=True, help="a patch_ceiling.py collect folder")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--count", type=int, default=64)
    p.add_argument("--threads", type=int, default=1, help="as the runtime runs it")
    args = p.parse_args()
    model = onnx.load(args.model)
    noise = next(i for i in model.graph.input if i.name == "noise")
    horizon, dim = (d.dim_value for d in noise.type.tensor_type.shape.dim[1:])
    calibration = feeds(args.frames, args.count, (1, horizon, dim))
    out, report = quantize_if_worth_it(model, None, args.threads, calibration)
    print(json.dumps(report))
    if report["kept"]:
        onnx.save(out, args.out)
        print(f"{args.out}: int8 encoder")


if __name__ == "__main__":
    main()
