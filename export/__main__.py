"""``python -m export CHECKPOINT --ddim-steps K --out student.onnx [--ddim-spacing S] [--exec-horizon N]
[--int8]``."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import onnx

from export.graph import build_model
from runtime.metadata import DDIM_SPACINGS
from trainer.student import checkpoint
from trainer.student.config import StudentConfigError


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m export", description="Freeze a student checkpoint into one "
                                "self-describing ONNX policy file (DDIM unrolled, metadata inside).")
    p.add_argument("checkpoint", type=Path, help="student checkpoint (.pt) from `trainer student fit|init`")
    p.add_argument("--ddim-steps", type=int, default=4, help="DDIM updates unrolled in the graph (default 4)")
    p.add_argument("--ddim-spacing", choices=DDIM_SPACINGS, default="leading",
                   help="where the DDIM steps sit among the 100 training steps: leading starts at "
                   "100 - 100/K (75 at K=4), trailing at 99, where the start noise is pure noise "
                   "(default leading)")
    p.add_argument("--out", type=Path, default=Path("student.onnx"), help="output ONNX file")
    p.add_argument("--exec-horizon", type=int, default=None,
                   help="actions the runtime executes from each chunk before re-planning (default: the "
                   "checkpoint's, 8 of 16); fewer re-plans more often")
    p.add_argument("--int8", action="store_true",
                   help="static QDQ int8 quantisation of the encoder; kept only if faster and accurate")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        ckpt = checkpoint.load(args.checkpoint)
        if args.exec_horizon is not None:
            ckpt = replace(ckpt, config=replace(ckpt.config, exec_horizon=args.exec_horizon))
    except (checkpoint.CheckpointError, StudentConfigError) as exc:
        print(f"export: {exc}", file=sys.stderr)
        return 2
    model, meta = build_model(ckpt, args.checkpoint, args.ddim_steps, args.ddim_spacing)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report = {"out": str(args.out), "ddim_steps": meta.ddim_steps, "ddim_spacing": meta.ddim_spacing,
              "trained": meta.trained}
    if args.int8:
        from export.quantize import quantize_if_worth_it
        model, report["int8"] = quantize_if_worth_it(model, ckpt)
    onnx.save(model, args.out)
    report["bytes"] = args.out.stat().st_size
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
