"""Can the depth image measure what the readout guesses? The readout places an unseen round kind's centre at
its visible front plus the half width it reads, and it reads the can's width as the training boxes' (0.85 cm
narrow, 0.74 cm too near the camera; docs/student.md). The image row through the object's pixel shows the
object's width across the line of sight: measured here at the true or the read object pixel, frame by frame,
with the object's radius solved from that angular width and the front's depth.

    PYTHONPATH=. python research/width_probe.py CKPT --store S [--jump-cm 1.5] [--rows 0]

Reports per kind, near the object and by the hand's height over it: the readout's half-narrow error, the
measured one, and the along-sight offset error before and after moving the read centre by the difference.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from hil_sim.camera import d455_intrinsics
from hil_sim.world import CAMERA_POS
from runtime.preprocess import DepthSpec
from trainer.dataset import DemoStore
from trainer.sim.labels import OBJECT_PX, OFFSET, SIZE
from trainer.student.model import hand_pose
from trainer.student.readout import NEAR_M, perceive_store


def half_width(depth_mm: np.ndarray, point: np.ndarray, spec: DepthSpec, jump_mm: float,
               rows: float = 0) -> float:
    """Half the object's width across the sight (m) on the policy image's row through ``point`` (spatial-
    softmax coordinates, [-1, 1]), ``rows`` pixels lower: the run of pixels without a depth step over
    ``jump_mm`` between neighbours, its angular width and front depth -> radius."""
    fx = d455_intrinsics(spec).window(0, 0, spec).fx  # wherever the crop sits
    u, v = (np.asarray(point) + 1) / 2 * np.array([spec.out_width - 1, spec.out_height - 1])
    return _row_half_width(depth_mm, u, v + rows, jump_mm, fx)


def sight(object_xy: np.ndarray) -> np.ndarray:
    """Unit horizontal direction from the nominal camera to objects at ``object_xy`` [..., 2]: the policy
    knows no other camera pose."""
    ray = object_xy - np.asarray(CAMERA_POS[:2])
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def _row_half_width(depth_mm: np.ndarray, u: float, v: float, jump_mm: float, fx: float) -> float:
    h, w = depth_mm.shape
    row = depth_mm[int(np.clip(round(v), 0, h - 1))].astype(np.float64)
    c = int(np.clip(round(u), 0, w - 1))
    left = c
    while left > 0 and row[left - 1] > 0 and abs(row[left - 1] - row[left]) < jump_mm:
        left -= 1
    right = c
    while right < w - 1 and row[right + 1] > 0 and abs(row[right + 1] - row[right]) < jump_mm:
        right += 1
    front = row[left:right + 1].min() / 1000
    sin_half = np.sin(np.arctan((right - left + 1) / 2 / fx))
    return front * sin_half / (1 - sin_half)  # a circle of radius r at front depth z: sin = r / (z + r)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--store", type=Path, required=True)
    p.add_argument("--jump-cm", type=float, default=1.5)
    p.add_argument("--above-cm", type=float, nargs=2, default=(-100, 100),
                   help="only frames with the hand between these heights over the object's centre")
    p.add_argument("--pixel", choices=("true", "read"), default="true")
    args = p.parse_args()
    facts, fine, steps = perceive_store(args.checkpoint, args.store)
    labels = steps.labels_np
    store = DemoStore.open(args.store)
    depth = store.depth("gt", store.n_steps)
    px = labels[:, OBJECT_PX] if args.pixel == "true" else fine[:, 0]
    jump_mm = args.jump_cm * 10
    measured = np.array([half_width(d, point, store.depth_spec, jump_mm)
                         for d, point in zip(depth, px, strict=True)])
    kinds = np.repeat(np.asarray(store.kinds), np.diff(store.episode_ends, prepend=0))
    near = np.linalg.norm(labels[:, OFFSET][:, :2], axis=1) < NEAR_M
    above = -labels[:, OFFSET][:, 2] * 100  # the hand's height over the object's centre, cm
    near &= (above >= args.above_cm[0]) & (above < args.above_cm[1])
    with torch.no_grad():  # the grasp site by the Panda's forward kinematics, as the student's graph has it
        site = hand_pose(torch.from_numpy(steps.state_np.astype(np.float32))).numpy()[:, :3]
    err = facts[:, OFFSET][:, :2] - labels[:, OFFSET][:, :2]
    along = (err * sight(site[:, :2] + labels[:, OFFSET][:, :2])).sum(1) * 100
    shift = measured - facts[:, SIZE][:, 0]
    corrected = along + shift * 100
    report = {}
    for kind in dict.fromkeys(kinds):
        m = near & (kinds == kind)
        if m.any():
            true_r = labels[m, SIZE][:, 0] * 100
            report[kind] = {"frames": int(m.sum()), "half_narrow_cm": _cm(true_r.mean()),
                            "read_err_cm": _cm((facts[m, SIZE][:, 0] * 100 - true_r).mean()),
                            "measured_err_cm": _cm((measured[m] * 100 - true_r).mean()),
                            "measured_err_p90": _cm(np.percentile(abs(measured[m] * 100 - true_r), 90)),
                            "along_err_cm": _cm(along[m].mean()),
                            "along_abs_median": _cm(np.median(abs(along[m]))),
                            "corrected_along_cm": _cm(corrected[m].mean()),
                            "corrected_abs_median": _cm(np.median(abs(corrected[m])))}
    print(json.dumps(report, indent=1))


def _cm(x: float) -> float:
    return round(float(x), 2)


if __name__ == "__main__":
    main()
