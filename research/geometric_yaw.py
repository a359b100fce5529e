"""Can geometry read an elongated object's grasp direction where the readout cannot? (issue 42: the lemon)

The shipped pair given the true grasp direction grasps 45 of 60 lemons against 36 as read
(``research/composed_policy.py ... --objects lemon --true yaw``). This is the ceiling of a geometric reading:
each frame's depth pixels back-projected to the world through the episode's own camera (intrinsics of its crop
window, extrinsics as recorded), the points within ``--radius-cm`` of the true object centre and between the
table and the object's top taken, and the narrow axis of their horizontal spread (the eigenvector of the
smaller eigenvalue) compared with the label. Frames are those with the hand at least ``--above-cm`` over the
object (the fingers out of the points); beside it the readout of ``--student`` (a depth student or a composed
pair's checkpoint) on the same frames.

    PYTHONPATH=. python research/geometric_yaw.py STORE.zarr [--student CKPT] [--kinds lemon bread starfruit]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from hil_sim.camera import Intrinsics
from hil_sim.world import TABLE_Z
from trainer.dataset import DEPTH_SCALE, DemoStore
from trainer.sim.labels import GRASP_YAW, OFFSET, SIZE
from trainer.student.model import hand_pose
from trainer.student.readout import perceive_store, yaw_errors


def narrow_axis(points_xy: np.ndarray) -> np.ndarray:
    """(cos 2p, sin 2p) of the direction p of the smaller principal axis of a horizontal point spread, as the
    grasp-direction label gives it."""
    centred = points_xy - points_xy.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    p = np.arctan2(vectors[1, 0], vectors[0, 0])
    return np.array([np.cos(2 * p), np.sin(2 * p)])


def world_points(depth_mm: np.ndarray, intr: Intrinsics, extrinsics: np.ndarray) -> np.ndarray:
    """Valid pixels of a policy-resolution frame as world points [N, 3]."""
    v, u = np.nonzero(depth_mm)
    z = depth_mm[v, u] * DEPTH_SCALE
    cam = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
    return cam @ extrinsics[:3, :3].T + extrinsics[:3, 3]


def episode_errors(ep: dict, spec, radius: float, above: float) -> list[tuple[int, float]]:
    """(frame index, geometric direction error in degrees) of the episode's frames with the hand high."""
    intr = Intrinsics().window(*ep["crop_window"], spec)
    hands = hand_pose(torch.from_numpy(ep["state"].astype(np.float32)))[:, :3].numpy()
    out = []
    for t, labels in enumerate(ep["labels"]):
        if -labels[OFFSET][2] < above or not labels[GRASP_YAW].any():
            continue
        centre = hands[t] + labels[OFFSET] + np.array([0.0, 0.0, TABLE_Z])  # base frame -> world
        half_height = labels[SIZE][2]
        points = world_points(ep["depth"][t], intr, ep["camera_extrinsics"])
        near = np.hypot(*(points[:, :2] - centre[:2]).T) < radius
        low, high = centre[2] - half_height + 0.008, centre[2] + half_height + 0.005
        mine = points[near & (points[:, 2] > low) & (points[:, 2] < high)]
        if len(mine) >= 8:
            estimate = labels.copy()
            estimate[GRASP_YAW] = narrow_axis(mine[:, :2])
            out.append((t, float(yaw_errors(estimate[None], labels[None])[0])))
    return out


def readout_errors(student: Path, store: Path) -> np.ndarray:
    """The student's grasp-direction error (degrees) on every frame of ``store``."""
    facts, _, steps = perceive_store(student, store)
    return yaw_errors(facts, steps.labels_np[:, :facts.shape[1]])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("store", type=Path)
    p.add_argument("--student", type=Path, help="a depth student's checkpoint, read on the same frames")
    p.add_argument("--kinds", nargs="+", default=["lemon", "bread", "starfruit"])
    p.add_argument("--radius-cm", type=float, default=5.0)
    p.add_argument("--above-cm", type=float, default=6.0)
    args = p.parse_args()
    store = DemoStore.open(args.store)
    read = readout_errors(args.student, args.store) if args.student else None
    result = {}
    for kind in args.kinds:
        geo, ours, bias = [], [], []
        for i, k in enumerate(store.kinds):
            if k != kind:
                continue
            pairs = episode_errors(store.episode(i), store.depth_spec, args.radius_cm / 100,
                                   args.above_cm / 100)
            if not pairs:
                continue
            geo += [e for _, e in pairs]
            bias.append(float(np.median([e for _, e in pairs])))
            if read is not None:
                start = store.episode_slice(i).start
                ours += [float(read[start + t]) for t, _ in pairs]
        row = {"frames": len(geo), "episodes": len(bias), "geometric_median": np.median(geo),
               "geometric_p90": np.percentile(geo, 90),
               "geometric_episode_median_p90": np.percentile(bias, 90)}
        if ours:
            row |= {"readout_median": np.median(ours), "readout_p90": np.percentile(ours, 90)}
        result[kind] = {k: round(float(v), 2) for k, v in row.items()}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
