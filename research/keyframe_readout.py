"""Look before you reach (issue 42): the readout given, besides its last frames, the last frame in which the
hand was still high over the table.

On its own episodes the shipped readout reads the object's offset along the camera's line of sight well
while the hand is 6-15 cm above the object (0.46 cm off along it, median) and is blind once the fingers are
down beside it (0.87 cm off): at grasp height hand and object overlap in the image. The object does not move
before the fingers touch it and the camera does not move at all, so the frame taken when the hand was last
high still shows where the object lies, in the same pixels and depths as the current frame shows the hand.

Here the stack's oldest frame is replaced by that *keyframe*: the last frame of the episode so far with the
hand (forward kinematics of the stored joints) at least ``--high-cm`` above the table (the episode's first
frame when there is none). The depth student's fit is continued from a recipe round's weights with a fourth
input channel (its first-convolution weights zero at the start, so the net begins as the round's) on that
round's stores; ``score`` reads a labelled store as ``trainer student readout`` does, near the object and by
the hand's height.

    python research/keyframe_readout.py fit RECIPE --round 6 --steps 3000 --out runs/keyframe
    python research/keyframe_readout.py score runs/keyframe/ckpt.pt --store probe.zarr
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import torch

from research import readout_probes
from research.own_frame_readout import ACROSS, SIGHT
from trainer.dataset import DemoStore
from trainer.sim.labels import OFFSET, READOUT
from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint
from trainer.student.distill import distill
from trainer.student.model import hand_pose
from trainer.student.readout import errors
from trainer.student.recipe import Recipe, RecipeConfig, stored_settings
from trainer.student.steps import LabelledSteps

STEM = "perception.resnet.stem.0.weight"


def hand_height(state: np.ndarray) -> np.ndarray:
    """The hand's height over the table (m): forward kinematics in the robot base frame, which sits on it."""
    return hand_pose(torch.from_numpy(np.asarray(state, np.float32))).numpy()[:, 2]


def keyframes(state: np.ndarray, start: np.ndarray, high_m: float) -> np.ndarray:
    """Each step's keyframe: the last step of its episode so far with the hand ``high_m`` over the table, else
    the episode's first step."""
    step = np.arange(len(state))
    last_high = np.maximum.accumulate(np.where(hand_height(state) >= high_m, step, -1))
    return np.where(last_high >= start, last_high, start)


def keyed_steps(paths: list[Path], cfg, high_m: float | None) -> LabelledSteps:
    """The stores' steps stacked with ``cfg``'s frames; with ``high_m``, the oldest is the keyframe."""
    steps = LabelledSteps(paths, cfg.obs_horizon, cfg.action_horizon, depth=True)
    if high_m is not None:
        step = np.arange(len(steps))
        opens = steps.stack_index[:, -2].numpy() == step  # a first step's previous frame is clamped to itself
        start = np.maximum.accumulate(np.where(opens, step, 0))
        steps.stack_index[:, 0] = torch.from_numpy(keyframes(steps.state_np, start, high_m))
    return steps


def widened(ckpt: Checkpoint) -> Checkpoint:
    """``ckpt`` with one more input frame, first in the stack, whose stem weights are zero."""
    cfg = dataclasses.replace(ckpt.config, obs_horizon=ckpt.config.obs_horizon + 1)

    def grow(weights: dict) -> dict:
        out = {k: v.clone() for k, v in weights.items()}
        stem = out[STEM]
        out[STEM] = torch.cat([torch.zeros_like(stem[:, :1]), stem], dim=1)
        return out

    return Checkpoint(cfg, ckpt.info, ema=grow(ckpt.ema), model=grow(ckpt.ema))


def fit(args: argparse.Namespace) -> None:
    torch.set_num_threads(2)
    settings = stored_settings(args.recipe / "recipe.json")
    recipe = Recipe(args.recipe, RecipeConfig(**settings))
    source = checkpoint.load(recipe.run_dir(args.round) / "ckpt.pt")
    args.out.mkdir(parents=True, exist_ok=True)
    init = args.out / "init.pt"
    start = widened(source)
    checkpoint.save(init, start)
    data = keyed_steps(recipe.stores(args.round), start.config, args.high_cm / 100)
    (args.out / "keyframe.json").write_text(json.dumps({"high_cm": args.high_cm}))
    summary = distill(data, args.out, start.config, recipe.cfg.distill(args.steps), source.info, init)
    print(json.dumps(summary))


def high_m(ckpt_path: Path) -> float | None:
    """The keyframe height (m) a checkpoint was fitted with; None without one (e.g. a recipe round)."""
    marker = ckpt_path.parent / "keyframe.json"
    high = json.loads(marker.read_text())["high_cm"] if marker.is_file() else None
    return None if high is None else high / 100


def score(args: argparse.Namespace) -> None:
    net = checkpoint.load(args.checkpoint).policy()
    steps = keyed_steps([args.store], net.config, high_m(args.checkpoint))
    estimate, labels = readout_probes.read(net, steps), steps.labels_np[:, :READOUT]
    result = errors(estimate, labels, DemoStore.open(args.store).episode_ends)
    print(json.dumps({k: result[k] for k in ("near", "off_target")}))
    true, read = labels[:, OFFSET], estimate[:, OFFSET]
    apart = np.linalg.norm(true[:, :2], axis=1)
    above = -true[:, 2] * 100
    for lo, hi in ((-5, 6), (6, 15), (15, 40)):
        m = (apart >= 0.007) & (apart < 0.02) & (above >= lo) & (above < hi)
        along, across = (np.abs((read[m, :2] - true[m, :2]) @ axis) * 100 for axis in (SIGHT, ACROSS))
        print(f"hand {lo}-{hi} cm above, 0.7-2 cm beside: {m.sum()} frames, off along the sight "
              f"{np.median(along):.2f} cm, across {np.median(across):.2f} cm")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit")
    f.add_argument("recipe", type=Path)
    f.add_argument("--round", type=int, required=True)
    f.add_argument("--steps", type=int, default=3000)
    f.add_argument("--high-cm", type=float, default=12.0)
    f.add_argument("--out", type=Path, required=True)
    s = sub.add_parser("score")
    s.add_argument("checkpoint", type=Path)
    s.add_argument("--store", type=Path, required=True)
    args = p.parse_args()
    {"fit": fit, "score": score}[args.command](args)


if __name__ == "__main__":
    main()
