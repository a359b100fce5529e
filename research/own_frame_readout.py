"""Where a depth student's readout loses the object's offset on its own frames (issue 42, M1).

On labelled stores, e.g. 30 episodes driven by the expert and 30 by the student on the same seeds
(``trainer student readout CKPT --store S --episodes 30 --objects seen --seed 777000 [--learner ONNX]``):

- ``bins``: the two supervised fine keypoints (object centre, grasp site) against their labelled pixels,
  binned by the true object-to-hand distance in pixels: each keypoint's median error (px) and the share of
  the true object-minus-hand pixel vector they report along it (a softmax mixing the two maps reports less);
- ``sight``: of the frames with the hand 0.7-2 cm off the object, how many lie mostly along the camera's line
  of sight (on the table plane), and the median share of the offset the readout reports along it there and
  across it elsewhere;
- with ``--fit STORE``, ``offset``: a quadratic map from the two *true* pixels to the horizontal offset,
  fitted on that store's labels and read from the true pixels and from the keypoints, beside the learned
  readout, each scored as ``trainer student readout`` scores it (horizontally: z is taken from the label).

    python research/own_frame_readout.py CKPT STORE [STORE ...] [--fit TRAIN_STORE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hil_sim.world import CAMERA_POS, CAMERA_TARGET
from trainer.dataset import DemoStore
from trainer.sim.labels import HAND_PX, OBJECT_PX, OFFSET, READOUT
from trainer.student.perception import SUPERVISED_KEYPOINTS
from trainer.student.readout import OFF_TARGET_M, errors, perceive_store
from trainer.student.steps import LabelledSteps

BINS_PX = (0, 2, 4, 8, 16, 1000)
_LOOK = np.subtract(CAMERA_TARGET, CAMERA_POS)[:2]
SIGHT = _LOOK / np.linalg.norm(_LOOK)
"""The nominal camera's line of sight on the table plane (unit, base frame)."""
ACROSS = np.array([-SIGHT[1], SIGHT[0]])


def keypoints(fine: np.ndarray, steps: LabelledSteps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The supervised keypoints ``fine[:, :2]`` and their labels (object, hand) [N, 2, 2] in [-1, 1] image
    coordinates, and the pixels per unit of those coordinates (x, y)."""
    truth = label_pixels(steps.labels_np)
    px_per_unit = (np.array([steps.spec.out_width, steps.spec.out_height], float) - 1) / 2
    return fine[:, :SUPERVISED_KEYPOINTS], truth, px_per_unit


def label_pixels(labels: np.ndarray) -> np.ndarray:
    """The labelled object and hand pixels [N, 2, 2] in [-1, 1] image coordinates."""
    return np.stack([labels[:, OBJECT_PX], labels[:, HAND_PX]], axis=1)


def in_view(pixels: np.ndarray) -> np.ndarray:
    """Frames [N] whose two pixels [N, 2, 2] both lie inside the image."""
    return (np.abs(pixels) <= 1).all(axis=(1, 2))


def _median_px(a: np.ndarray, b: np.ndarray) -> float:
    return round(float(np.median(np.linalg.norm(a - b, axis=1))), 2)


def bins(pred: np.ndarray, truth: np.ndarray, px_per_unit: np.ndarray) -> list[dict]:
    both_seen = in_view(truth)
    pred, truth = pred * px_per_unit, truth * px_per_unit
    true_vec, pred_vec = truth[:, 0] - truth[:, 1], pred[:, 0] - pred[:, 1]
    dist = np.linalg.norm(true_vec, axis=1)
    rows = []
    for lo, hi in zip(BINS_PX[:-1], BINS_PX[1:], strict=True):
        m = both_seen & (dist >= lo) & (dist < hi)
        if not m.any():
            continue
        share = (pred_vec[m] * true_vec[m]).sum(1) / np.maximum(dist[m], 1e-6) ** 2
        rows.append({"px": f"{lo}-{hi}", "frames": int(m.sum()),
                     "object_err_px": _median_px(pred[m, 0], truth[m, 0]),
                     "hand_err_px": _median_px(pred[m, 1], truth[m, 1]),
                     "share_median": round(float(np.median(share)), 2) if lo > 0 else None})
    return rows


def sight(estimate: np.ndarray, labels: np.ndarray) -> dict:
    true, read = labels[:, OFFSET][:, :2], estimate[:, OFFSET][:, :2]
    length = np.linalg.norm(true, axis=1)
    m = (length >= OFF_TARGET_M[0]) & (length < OFF_TARGET_M[1])
    along, across = true[m] @ SIGHT, true[m] @ ACROSS
    mostly = np.abs(along) > np.abs(across)
    return {"frames": int(m.sum()), "mostly_along_sight": int(mostly.sum()),
            "share_along": round(float(np.median((read[m] @ SIGHT)[mostly] / along[mostly])), 2),
            "share_across": round(float(np.median((read[m] @ ACROSS)[~mostly] / across[~mostly])), 2)}


def quadratic(pixels: np.ndarray) -> np.ndarray:
    """[N, 2, 2] object and hand pixels -> [N, 28]: 1, (object, hand, difference) and their products."""
    x = np.concatenate([pixels.reshape(len(pixels), 4), pixels[:, 0] - pixels[:, 1]], axis=1)
    pairs = [x[:, i] * x[:, j] for i in range(6) for j in range(i, 6)]
    return np.column_stack([np.ones(len(x)), x, *pairs])


def fit_map(store: Path) -> np.ndarray:
    """Least-squares weights [28, 2], true pixels -> horizontal offset, on frames with both in view."""
    labels = LabelledSteps([store], 1, 1, depth=False).labels_np
    pixels = label_pixels(labels)
    m = in_view(pixels)
    return np.linalg.lstsq(quadratic(pixels[m]), labels[m, OFFSET][:, :2], rcond=None)[0]


def horizontal(offset_xy: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """An estimate [N, READOUT] with ``offset_xy`` and every other fact from the labels."""
    estimate = labels[:, :READOUT].copy()
    estimate[:, :2] = offset_xy
    return estimate


def offsets(pred: np.ndarray, true_px: np.ndarray, learned: np.ndarray, labels: np.ndarray,
            ends: np.ndarray, weights: np.ndarray) -> dict:
    estimates = {"true pixels": quadratic(true_px) @ weights, "keypoints": quadratic(pred) @ weights,
                 "learned readout": learned[:, :2]}
    scored = {name: errors(horizontal(xy, labels), labels, ends) for name, xy in estimates.items()}
    return {name: {k: r[k] for k in ("near", "off_target")} for name, r in scored.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("stores", type=Path, nargs="+")
    p.add_argument("--fit", type=Path, help="labelled store to fit the pixels -> offset map on")
    a = p.parse_args()
    weights = fit_map(a.fit) if a.fit else None
    for store in a.stores:
        learned, fine, steps = perceive_store(a.checkpoint, store)
        pred, true_px, px_per_unit = keypoints(fine, steps)
        labels = steps.labels_np[:, :READOUT]
        row = {"store": str(store), "bins": bins(pred, true_px, px_per_unit), "sight": sight(learned, labels)}
        if weights is not None:
            ends = DemoStore.open(store).episode_ends
            row["offset"] = offsets(pred, true_px, learned, labels, ends, weights)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
