"""What a depth student's readout uses and what averaging it would buy, on a labelled store (issue 42, M1).

- ``invariance``: every depth value moved by +-2 cm (the camera moved along its axis, roughly), and the hand
  pose the readout is told (forward kinematics) moved 1 cm along the line of sight, across it and up while
  the image stays: how far the offset readout moves near the object. 0 = it reads the offset from the image,
  relative; the whole shift = it reads absolute depth or trusts the told hand (shortcuts the camera's
  randomised pose breaks).
- ``average``: the readouts of several checkpoints averaged, and one readout averaged over whole-pixel
  shifts of its input (edge repeated, as the fit's ``shift_px``), scored as ``trainer student readout``
  scores them.
- ``latch``: offline, the object's place in the robot base frame (hand by forward kinematics + offset read)
  averaged over the frames before the first close with the hand 12-30 cm over the table and the object read
  within 10 cm, against the readout's own offset on the frames at grasp height (the hand < 6 cm above the
  object centre, < 5 cm beside it): ``research/latched_readout.py`` drives with it.

    python research/readout_probes.py invariance CKPT --store STORE
    python research/readout_probes.py average CKPT [CKPT ...] --store STORE
    python research/readout_probes.py latch CKPT --store STORE
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from research.latched_readout import HIGH_M, NEAR_M, OPEN_M
from research.own_frame_readout import ACROSS, SIGHT
from trainer.dataset import DemoStore
from trainer.sim.labels import OFFSET, READOUT
from trainer.student import checkpoint
from trainer.student.model import hand_pose
from trainer.student.readout import NEAR_M as READOUT_NEAR_M
from trainer.student.readout import errors
from trainer.student.steps import LabelledSteps

SHIFTS_PX = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))


def read(net, steps: LabelledSteps, depth_cm: float = 0.0, hand_m=(0.0, 0.0, 0.0),
         shifts=((0, 0),)) -> np.ndarray:
    """The readout [N, READOUT] (m) of every step, its depth moved by ``depth_cm``, the told hand by
    ``hand_m``, averaged over the input's whole-pixel ``shifts``."""
    out = []
    with torch.no_grad():
        for s in range(0, len(steps), 512):
            b = steps.batch(torch.arange(s, min(s + 512, len(steps))))
            moved = b.depth + depth_cm / 100 / (steps.spec.far_m - steps.spec.near_m)  # normalised units
            depth = torch.where(b.depth >= 0, moved, b.depth)
            pose = hand_pose(b.state)
            pose[:, :3] += torch.tensor(hand_m, dtype=pose.dtype)
            total = 0
            for dx, dy in shifts:
                _, facts, _ = net.perception(shifted(depth, dx, dy), net.hand_norm.normalise(pose))
                total = total + net.label_norm.unnormalise(facts).float().numpy()
            out.append(total / len(shifts))
    return np.concatenate(out)


def shifted(depth: torch.Tensor, dx: int, dy: int) -> torch.Tensor:
    """``depth`` [B, T, H, W] moved by whole pixels, the edge repeated."""
    h, w = depth.shape[-2:]
    rows = (torch.arange(h) - dy).clamp(0, h - 1)
    cols = (torch.arange(w) - dx).clamp(0, w - 1)
    return depth[..., rows, :][..., cols]


def loaded(ckpt: Path, store: Path):
    net = checkpoint.load(ckpt).policy()
    return net, LabelledSteps([store], net.config.obs_horizon, net.config.action_horizon, depth=True)


def invariance(args: argparse.Namespace) -> None:
    net, steps = loaded(args.checkpoints[0], args.store)
    near = np.linalg.norm(steps.labels_np[:, OFFSET][:, :2], axis=1) < READOUT_NEAR_M
    base = read(net, steps)[near][:, OFFSET] * 100
    moves = {"depth -2 cm": {"depth_cm": -2.0}, "depth +2 cm": {"depth_cm": 2.0},
             "hand +1 cm along the sight": {"hand_m": (*(SIGHT * 0.01), 0.0)},
             "hand +1 cm across": {"hand_m": (*(ACROSS * 0.01), 0.0)},
             "hand +1 cm up": {"hand_m": (0.0, 0.0, 0.01)}}
    for name, move in moves.items():
        d = read(net, steps, **move)[near][:, OFFSET] * 100 - base
        print(f"{name}: the offset read moves along the sight {np.median(d[:, :2] @ SIGHT):+.2f}, across "
              f"{np.median(d[:, :2] @ ACROSS):+.2f}, up {np.median(d[:, 2]):+.2f} cm (near the object)")


def score(name: str, estimate: np.ndarray, labels: np.ndarray, ends: np.ndarray) -> None:
    e = errors(estimate, labels, ends)
    near = e["near"]
    print(f"{name}: near the object {near['offset_cm_median']:.2f} cm, bias p90 {near['bias_cm_p90']:.2f}, "
          f"off-target share {e['off_target'].get('read_share_median')}")


def average(args: argparse.Namespace) -> None:
    ends = DemoStore.open(args.store).episode_ends
    estimates = []
    for ckpt in args.checkpoints:
        net, steps = loaded(ckpt, args.store)
        estimates.append(read(net, steps))
        score(str(ckpt), estimates[-1], steps.labels_np[:, :READOUT], ends)
    labels = steps.labels_np[:, :READOUT]
    if len(estimates) > 1:
        score("their mean", np.mean(estimates, axis=0), labels, ends)
    score(f"the last averaged over shifts {SHIFTS_PX}", read(net, steps, shifts=SHIFTS_PX), labels, ends)


def latch(args: argparse.Namespace) -> None:
    net, steps = loaded(args.checkpoints[0], args.store)
    estimate, labels = read(net, steps)[:, OFFSET], steps.labels_np[:, OFFSET]
    hand = hand_pose(torch.from_numpy(steps.state_np)).numpy()[:, :3]
    own, latched, start = [], [], 0
    for end in DemoStore.open(args.store).episode_ends:
        episode = np.arange(start, end)
        start = end
        shut = np.flatnonzero(steps.state_np[episode, 7] < OPEN_M)
        before = episode[: shut[0]] if len(shut) else episode
        high = before[(hand[before, 2] >= HIGH_M[0]) & (hand[before, 2] < HIGH_M[1])
                      & (np.linalg.norm(estimate[before, :2], axis=1) < NEAR_M)]
        low = before[(-labels[before, 2] < 0.06) & (np.linalg.norm(labels[before, :2], axis=1) < 0.05)]
        for i in low:  # causal: the high frames seen so far
            seen = high[high <= i]
            place = (hand[seen] + estimate[seen]).mean(0) if len(seen) else hand[i] + estimate[i]
            own.append((estimate[i] - labels[i]) * 100)
            latched.append((place - hand[i] - labels[i]) * 100)
    for name, e in (("the readout", np.array(own)), ("latched", np.array(latched))):
        apart = np.median(np.linalg.norm(e[:, :2], axis=1))
        along, across = (np.median(np.abs(e[:, :2] @ axis)) for axis in (SIGHT, ACROSS))
        print(f"{name} at grasp height ({len(e)} frames): {apart:.2f} cm off horizontally (along the sight "
              f"{along:.2f}, across {across:.2f}), up {np.median(np.abs(e[:, 2])):.2f} (medians)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("probe", choices=("invariance", "average", "latch"))
    p.add_argument("checkpoints", type=Path, nargs="+")
    p.add_argument("--store", type=Path, required=True)
    args = p.parse_args()
    torch.set_num_threads(2)
    {"invariance": invariance, "average": average, "latch": latch}[args.probe](args)


if __name__ == "__main__":
    main()
