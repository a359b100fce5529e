"""Perception variants refitted side by side from one depth student (issue 42, M1: the readout's error).

Each arm starts from the same recipe checkpoint (tensors whose names and shapes match are copied; the
readout's first layer keeps its trained columns and starts the new inputs at zero, so an arm that only adds
inputs begins as the source's function) and is refitted with ``trainer.student.distill`` on the same stores
for the same steps. Then each arm's readout is measured (``trainer.student.readout``) on held-out stores, and,
exported, it is evaluated closed loop as ``trainer evaluate`` does. Prints and writes one JSON per arm.

    python research/perception_arms.py --init CKPT --stores S0 S1 ... --test NAME=STORE ... --out DIR \\
        [--arms base=8 s4g=4g near=8:1] [--steps 2000] [--lr 1e-4] [--shift-px 0] [--episodes 60] \\
        [--head M0] [--precision bf16] [--seen-share 0.5]

An arm is NAME=STRIDE[LETTERS][:NEAR]: the fine keypoints' stride (8 or 4), letters for the readout's inputs
(g: the geometric ones, n: no global average, v: 4 values under each fine keypoint; ``ARM_FLAGS``), and the
weight of the near-weighted offset loss (``DistillConfig.near_loss``, default 0). With ``--head`` each arm is
composed with that privileged head before export (as ``trainer student recipe --head``), so the closed loop
measures its perception under the same head.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from hil_sim.objects import GROUPS
from trainer.dataset import DemoStore
from trainer.eval.success import evaluate
from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint
from trainer.student.config import StudentConfig
from trainer.student.distill import DistillConfig, distill
from trainer.student.model import PerceptionStudent
from trainer.student.perception import readout_layout
from trainer.student.readout import errors, readouts
from trainer.student.recipe import export
from trainer.student.steps import LabelledSteps
from trainer.student.train import CKPT_NAME

ARM_FLAGS = {"g": {"geometric": True}, "n": {"readout_global": False}, "v": {"keypoint_values": 4}}
"""The letters after an arm's stride: the readout inputs it changes (``StudentConfig``)."""


def arm_config(base: StudentConfig, spec: str) -> StudentConfig:
    network = spec.partition(":")[0]
    stride, flags = network[0], network[1:]
    if unknown := set(flags) - set(ARM_FLAGS):
        raise SystemExit(f"error: arm {spec!r}: unknown letters {sorted(unknown)} (know {sorted(ARM_FLAGS)})")
    changes = {"fine_stride": int(stride), "geometric": False, "readout_global": True, "keypoint_values": 0}
    for letter in flags:
        changes |= ARM_FLAGS[letter]
    return dataclasses.replace(base, **changes)


def arm_distill(spec: str, args: argparse.Namespace) -> DistillConfig:
    near = spec.partition(":")[2]
    return DistillConfig(steps=args.steps, batch=args.batch, lr=args.lr, warmup=min(200, args.steps // 10),
                         shift_px=args.shift_px, near_loss=float(near or 0), precision=args.precision,
                         seen_share=args.seen_share)


READOUT_INPUT = "perception.readout.0.weight"


def transplant(source: Checkpoint, config: StudentConfig) -> Checkpoint:
    """``source``'s weights in a network of ``config``: matching tensors copied, the readout's first layer
    column block by column block (``readout_layout``: a block the source lacks starts at zero, one the arm
    drops is left out), the rest fresh."""
    net = PerceptionStudent(config)
    state = net.state_dict()
    for name, tensor in source.ema.items():
        if name in state and state[name].shape == tensor.shape and name != READOUT_INPUT:
            state[name] = tensor.clone()
    blocks = _columns(readout_layout(source.config), source.ema[READOUT_INPUT])
    rows = len(state[READOUT_INPUT])
    state[READOUT_INPUT] = torch.cat([blocks.get(block, state[READOUT_INPUT].new_zeros(rows, n))
                                      for block, n in readout_layout(config)], dim=1)
    return Checkpoint(config, source.info, ema=state, model={k: v.clone() for k, v in state.items()})


def _columns(layout: list[tuple[str, int]], weight: torch.Tensor) -> dict[str, torch.Tensor]:
    return dict(zip([block for block, _ in layout], weight.split([n for _, n in layout], dim=1), strict=True))


def run_arm(name: str, spec: str, source: Checkpoint, data: LabelledSteps, tests: dict[str, Path],
            args: argparse.Namespace) -> dict:
    out = args.out / name
    out.mkdir(parents=True, exist_ok=True)
    init = out / "init.pt"
    if not init.is_file():
        checkpoint.save(init, transplant(source, arm_config(source.config, spec)))
    fit = distill(data, out, arm_config(source.config, spec), arm_distill(spec, args), source.info, init)
    result = {"arm": name, "spec": spec, "fit": fit}
    for test, store in tests.items():
        estimate, labels = readouts(out / CKPT_NAME, store)
        result[test] = errors(estimate, labels, DemoStore.open(store).episode_ends)
    onnx = out / "student.onnx"
    if not onnx.is_file():
        export(out / CKPT_NAME, onnx, ddim_steps=4, head=args.head)
    if args.episodes:
        run = evaluate(f"student:{onnx}", GROUPS["seen"], args.episodes, workers=1)
        result["seen"] = {k: run[k] for k in ("success_rate", "ci95", "per_object", "first_close")}
    (out / "result.json").write_text(json.dumps(result, indent=1))
    return result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--init", type=Path, required=True)
    p.add_argument("--stores", type=Path, nargs="+", required=True)
    p.add_argument("--test", nargs="*", default=[], help="NAME=STORE: readout measured on these")
    p.add_argument("--arms", nargs="+", default=["base=8", "s4g=4g"])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--shift-px", type=int, default=0)
    p.add_argument("--precision", default="fp32", help="fp32 | bf16, as the recipe's --precision")
    p.add_argument("--seen-share", type=float, help="as the recipe's --seen-share")
    p.add_argument("--head", type=Path, help="a privileged head (M0) each arm is composed with before export")
    p.add_argument("--episodes", type=int, default=60)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    source = checkpoint.load(args.init)
    cfg = source.config
    data = LabelledSteps(args.stores, cfg.obs_horizon, cfg.action_horizon, depth=True)
    tests = {k: Path(v) for k, v in (t.split("=", 1) for t in args.test)}
    for arm in args.arms:
        name, _, spec = arm.partition("=")
        print(json.dumps(run_arm(name, spec, source, data, tests, args)), flush=True)


if __name__ == "__main__":
    main()
