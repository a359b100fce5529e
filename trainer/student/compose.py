"""``python -m trainer student compose``: one depth student from a depth student's perception and a privileged
student's action head (milestone M0: the head trained, with DAgger, on the true facts).

The two were fitted apart, each with its own normalisers. The composed student keeps the head's (state,
action, hand pose, facts) and re-expresses perception in them exactly: the readout's first layer takes the
hand pose in the head's scaling and its last layer gives the facts in the head's standardisation (both affine,
folded into the weights). The result has ``head_features=False`` (the head reads what it was trained on:
facts, joint state, hand pose) and exports like any depth student. ``--also`` adds more depth students of the
same network as partners (``StudentConfig.perceptions``), each re-expressed the same way: the head reads the
mean of all their facts.

    python -m trainer student compose --perception DEPTH/ckpt.pt --head PRIVILEGED/ckpt.pt --out C/ckpt.pt
    python -m trainer student compose --perception A.pt --also B.pt --head PRIVILEGED/ckpt.pt --out C/ckpt.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint
from trainer.student.model import PerceptionStudent
from trainer.student.perception import HAND_FEATURES

HEAD_FIELDS = ("action_horizon", "exec_horizon", "state_features", "head_dims", "step_features",
               "train_timesteps", "prediction", "state_dim", "action_dim")
"""Settings of the head's network that the composed student takes from the privileged student."""
ENCODER_FIELDS = ("width", "keypoints", "fine_keypoints", "obs_horizon")
"""Settings of the perception's network, which every partner must share with the first perception."""


def compose(perception: Checkpoint, head: Checkpoint, partners: tuple[Checkpoint, ...] = ()) -> Checkpoint:
    eyes = (perception, *partners)
    for eye in eyes:
        _check_perception(eye, perception)
    if head.config.perception != "privileged":
        raise ValueError(f"--head must be a privileged student, got perception={head.config.perception!r}")
    config = dataclasses.replace(perception.config, head_features=False, perceptions=len(eyes),
                                 **{name: getattr(head.config, name) for name in HEAD_FIELDS})
    net = PerceptionStudent(config)
    weights = {k: v.clone() for k, v in head.ema.items()}
    for prefix, eye in zip(perception_prefixes(len(eyes)), eyes, strict=True):
        weights.update({prefix + k.removeprefix("perception."): v.clone() for k, v in eye.ema.items()
                        if k.startswith("perception.")})
        _fold_hand_scaling(weights, prefix, net.perception.out_features, eye.ema, head.ema)
        _fold_facts_scaling(weights, prefix, eye.ema, head.ema)
    net.load_state_dict(weights)  # every tensor named, none left over
    state = net.state_dict()
    record = {"perception": perception.info.data, "head": head.info.data}
    if partners:
        record["partners"] = [eye.info.data for eye in partners]
    info = dataclasses.replace(perception.info, data={"composed": record})
    return Checkpoint(config, info, ema=state, model={k: v.clone() for k, v in state.items()},
                      step=perception.step)


def _check_perception(eye: Checkpoint, first: Checkpoint) -> None:
    if eye.config.perception != "depth" or eye.config.perceptions != 1:
        raise ValueError(f"--perception and --also must be depth students of one perception, got "
                         f"perception={eye.config.perception!r}, perceptions={eye.config.perceptions}")
    differ = [name for name in ENCODER_FIELDS if getattr(eye.config, name) != getattr(first.config, name)]
    if eye.info.depth_spec != first.info.depth_spec:
        differ.append("depth crop or resolution")
    if differ:
        raise ValueError(f"--also students must see depth as --perception does: {', '.join(differ)} differ")


def perception_prefixes(perceptions: int) -> list[str]:
    """Where each perception's weights live in a composed network (their state-dict key prefixes): the first,
    then its partners."""
    return ["perception.", *(f"partners.{i}." for i in range(perceptions - 1))]


def _fold_hand_scaling(weights: dict, prefix: str, features: int, perception: dict, head: dict) -> None:
    """The readout read the hand pose (its inputs after the ``features``) as (h - c_p) / r_p; it will get
    (h - c_h) / r_h."""
    first = f"{prefix}readout.0"
    hand = slice(features, features + HAND_FEATURES)
    c_p, r_p = perception["hand_norm.centre"], perception["hand_norm.half_range"]
    c_h, r_h = head["hand_norm.centre"], head["hand_norm.half_range"]
    w = weights[f"{first}.weight"]
    columns = w[:, hand]
    weights[f"{first}.bias"] = weights[f"{first}.bias"] + columns @ ((c_h - c_p) / r_p)
    w[:, hand] = columns * (r_h / r_p)


def _fold_facts_scaling(weights: dict, prefix: str, perception: dict, head: dict) -> None:
    """The readout gave facts as (f - c_p) / r_p; the head reads (f - c_h) / r_h."""
    last = f"{prefix}readout.4"
    c_p, r_p = perception["label_norm.centre"], perception["label_norm.half_range"]
    c_h, r_h = head["label_norm.centre"], head["label_norm.half_range"]
    weights[f"{last}.weight"] = weights[f"{last}.weight"] * (r_p / r_h)[:, None]
    weights[f"{last}.bias"] = weights[f"{last}.bias"] * (r_p / r_h) + (c_p - c_h) / r_h


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student compose",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--perception", type=Path, required=True, help="a depth student's checkpoint")
    p.add_argument("--also", type=Path, nargs="+", default=[], help="more depth students: the head reads "
                   "their facts averaged with --perception's")
    p.add_argument("--head", type=Path, required=True, help="a privileged student's checkpoint (M0)")
    p.add_argument("--out", type=Path, required=True, help="the composed checkpoint to write")
    args = p.parse_args(argv)
    try:
        ckpt = compose(checkpoint.load(args.perception), checkpoint.load(args.head),
                       tuple(checkpoint.load(path) for path in args.also))
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    checkpoint.save(args.out, ckpt)
    print(json.dumps({"out": str(args.out), "config": json.loads(ckpt.config.to_json())}))
    return 0
