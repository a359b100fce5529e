"""``python -m trainer student probe``: an exported student's actions against the demos' own, offline.

A cheap check before a closed-loop evaluation: on every ``--every``-th demo step it runs the policy file
exactly as the evaluator does (runtime.policy over onnxruntime, on the same normalised frame stack the
trainer builds) and compares the first ``exec_horizon`` actions with the demo's, in env units. Two
references are reported beside it: the always-zero predictor (a student no better than zero has learned
nothing), and the same student fed another step's depth with its own joint state
(``shuffled_depth_err``): a student whose error does not grow when its depth is swapped does not use its
camera, only the arm's joint state. With ``--checkpoint`` (the run the file was exported from) it also
measures the training-only object head on these demos: how far, in cm, its object position is from the
true one (``object_err_cm``), beside always answering the training demos' mean position. Run it on demos
the student never saw: a head that memorised its training episodes is no better than the mean there.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from runtime.policy import PolicyError
from trainer.dataset import DatasetError, DemoStore
from trainer.student import checkpoint
from trainer.student.checkpoint import CheckpointError
from trainer.student.data import (
    DemoDataError,
    DemoDataset,
    column_scale,
    privileged_targets,
    training_targets,
)
from trainer.student.onnx_policy import StudentOnnxPolicy, to_env_actions


def probe(policy_path: str, demos: str, depth_source: str, every: int) -> dict:
    policy = StudentOnnxPolicy(policy_path)
    meta = policy.meta
    data = DemoDataset.stacked_as(demos, depth_source, meta, meta.preprocess)
    steps = np.arange(0, len(data), every)
    stacks = [data.depth_stack(int(i)) for i in steps]
    other = np.roll(np.arange(len(steps)), len(steps) // 2)  # each step paired with a distant one
    rng = np.random.default_rng(0)
    joint_err, shuffled_err, zero_err, gripper_ok = [], [], [], []
    for n, i in enumerate(steps):
        true = data.action[data.action_indices(int(i))][: meta.exec_horizon]
        noise = rng.standard_normal(policy.runtime.noise_shape, dtype=np.float32)  # same for both calls
        pred = env_chunk(policy, stacks[n], data.state[i], noise)
        joint_err.append(np.abs(pred[:, :7] - true[:, :7]).mean())
        shuffled = env_chunk(policy, stacks[other[n]], data.state[i], noise)
        shuffled_err.append(np.abs(shuffled[:, :7] - true[:, :7]).mean())
        zero_err.append(np.abs(true[:, :7]).mean())
        gripper_ok.append((np.sign(pred[:, 7]) == np.sign(true[:, 7])).mean())
    return {"policy": policy_path, "demos": demos, "depth_source": depth_source, "steps": len(steps),
            "joint_abs_err": float(np.mean(joint_err)), "shuffled_depth_err": float(np.mean(shuffled_err)),
            "zero_predictor_err": float(np.mean(zero_err)),
            "gripper_sign_agreement": float(np.mean(gripper_ok))}


def locate(ckpt_path: str, demos: str, depth_source: str, every: int) -> dict:
    """The object head's error on ``demos`` (cm), against predicting the training demos' mean position; for
    a head with the hand target also the error of the hand's offset from the object."""
    ckpt = checkpoint.load(Path(ckpt_path))
    if "demos" not in ckpt.info.data:
        raise DemoDataError(f"{ckpt_path} records no training demos (an untrained checkpoint?)")
    hand = ckpt.config.hand_target
    trained_on = training_targets(ckpt.info.data, hand)
    probed = privileged_targets(DemoStore.open(demos), hand)
    if trained_on is None or probed is None:
        raise DemoDataError("object positions are not recorded in the training or the probed demos")
    data = DemoDataset.stacked_as(demos, depth_source, ckpt.config, ckpt.info.depth_spec)
    steps = np.arange(0, len(data), every)
    net = ckpt.policy()
    with torch.no_grad():
        predicted = net.object_head(net.encoder(data.batch(steps).depth)).numpy()
    mean, std = column_scale(trained_on)
    predicted = predicted * std + mean
    err, mean_err = (np.linalg.norm(x[..., :2] - probed[steps, :2], axis=1) * 100 for x in (predicted, mean))
    result = {"object_err_cm": {"median": float(np.median(err)), "mean": float(err.mean())},
              "mean_position_err_cm": float(mean_err.mean())}
    if hand:
        hand_err = np.linalg.norm(predicted[:, 2:5] - probed[steps, 2:5], axis=1) * 100
        result["hand_offset_err_cm"] = {"median": float(np.median(hand_err)), "mean": float(hand_err.mean())}
    return result


def env_chunk(policy: StudentOnnxPolicy, stack: np.ndarray, state: np.ndarray,
              noise: np.ndarray) -> np.ndarray:
    chunk = policy.runtime(stack, state, noise)
    return to_env_actions(chunk[: policy.meta.exec_horizon], policy.meta.action_scale)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student probe", description=__doc__.split("\n\n")[0])
    p.add_argument("--policy", required=True, help="student.onnx written by `python -m export`")
    p.add_argument("--demos", required=True, help="demo store (zarr) to compare with")
    p.add_argument("--depth-source", default="gt",
                   help="gt | randnoise | ddg | ddg_nograft | sensor (default gt)")
    p.add_argument("--every", type=int, default=97, help="probe every N-th demo step (default 97)")
    p.add_argument("--checkpoint", help="the run's ckpt.pt: also report the object head's error (cm)")
    args = p.parse_args(argv)
    if args.every < 1:
        p.error(f"--every must be >= 1, got {args.every}")
    try:
        result = probe(args.policy, args.demos, args.depth_source, args.every)
        if args.checkpoint:
            result.update(locate(args.checkpoint, args.demos, args.depth_source, args.every))
    except (PolicyError, DemoDataError, CheckpointError, DatasetError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result))
    return 0
