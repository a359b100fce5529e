"""Does a depth readout see the hand beside the object once it is low (issue 45)? On a labelled store's
frames (a learner's own states, as a DAgger round stores them): by the hand's height over the object, how much
of the true horizontal offset the readout reads (the slope of read on true: 1 sees it, 0 reads "on target"
whatever it is); at each episode's first close, how far off the hand closed against what the readout read just
before; whether the object's place averaged while the hand was high (a latch) would read the close better; and
how much of each episode's error where the aim is set the camera's pose, drawn per episode, explains.

    PYTHONPATH=. python research/low_hand_readout.py CKPT STORE [--also CKPT ...] [--versus CKPT] [--out J]

CKPT: a depth student or composed checkpoint (``student.pt``); STORE: a store with its frames' labels
(``trainer student readout --store``). Frames are read as ``trainer student readout`` reads them. With
``--also``, the readings of every checkpoint are averaged, as an exported pair of readouts averages them; with
``--versus``, another checkpoint's error is compared with theirs episode by episode.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from research import readout_probes
from trainer.dataset import DemoStore
from trainer.sim.labels import OFFSET, READOUT
from trainer.student import checkpoint
from trainer.student.model import hand_pose
from trainer.student.steps import STORED, LabelledSteps

OPEN_M = 0.075
"""A gripper opening below this (fully open: 0.08 m) is a close."""
BANDS_CM = ((-3, 1), (1, 3), (3, 5), (5, 8), (8, 12), (12, 18), (18, 30))
"""Heights of the grasp site over the object's centre whose frames are judged together."""
BESIDE_CM = 4.0
"""Only frames with the hand this near the object (horizontally) count for the slopes."""
LATCH_CM = (6.0, 20.0)
"""The hand heights over the table whose readings of the object's place a latch averages."""


def slopes(read: np.ndarray, true: np.ndarray, opened: np.ndarray, ends: np.ndarray) -> list[dict]:
    """Per height band: the read offset's slope on the true one in x and y, the horizontal error (cm), and the
    share of the error's variance that is one constant per episode (1: averaging an episode's frames cannot
    help; 0: every frame errs afresh)."""
    apart = np.linalg.norm(true[:, :2], axis=1) * 100
    episode = np.searchsorted(ends, np.arange(len(read)), side="right")
    rows = []
    for lo, hi in BANDS_CM:
        m = in_band(true, opened, lo, hi)
        if m.sum() < 20:
            continue
        error = np.linalg.norm((read - true)[m, :2], axis=1) * 100
        rows.append({"above_cm": [lo, hi], "frames": int(m.sum()),
                     "true_xy_cm_median": _r(np.median(apart[m])),
                     "slope_x": _r(np.polyfit(true[m, 0], read[m, 0], 1)[0]),
                     "slope_y": _r(np.polyfit(true[m, 1], read[m, 1], 1)[0]),
                     "error_xy_cm_median": _r(np.median(error)),
                     "error_xy_cm_p90": _r(np.percentile(error, 90)),
                     "episode_share": _r(episode_share((read - true)[m, :2], episode[m]))})
    return rows


def in_band(true: np.ndarray, opened: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The frames judged in the band ``lo``-``hi`` cm over the object: the hand open and near it."""
    above, apart = -true[:, 2] * 100, np.linalg.norm(true[:, :2], axis=1) * 100
    return (above >= lo) & (above < hi) & (apart < BESIDE_CM) & opened


def versus(read: np.ndarray, other: np.ndarray, true: np.ndarray, opened: np.ndarray, ends: np.ndarray,
           seed: int = 0) -> list[dict]:
    """Per height band, paired by episode: each episode's mean horizontal error (cm) read by ``other`` minus
    read by ``read``, the mean over episodes with a 95 % bootstrap interval, and the episodes each reads
    better.
    The error is mostly one constant per episode, so episodes, not frames, are the samples."""
    episode = np.searchsorted(ends, np.arange(len(read)), side="right")
    rng, rows = np.random.default_rng(seed), []
    for lo, hi in BANDS_CM:
        m = in_band(true, opened, lo, hi)
        eps = np.unique(episode[m])
        if len(eps) < 10:
            continue
        err = [np.linalg.norm((r - true)[m, :2], axis=1) * 100 for r in (read, other)]
        diff = np.array([err[1][episode[m] == e].mean() - err[0][episode[m] == e].mean() for e in eps])
        boot = rng.choice(diff, (2000, len(diff))).mean(axis=1)
        rows.append({"above_cm": [lo, hi], "episodes": len(eps), "diff_cm_mean": _r(diff.mean()),
                     "diff_cm_ci95": [_r(np.percentile(boot, 2.5)), _r(np.percentile(boot, 97.5))],
                     "other_better": int((diff < 0).sum()), "other_worse": int((diff > 0).sum())})
    return rows


def episode_share(error: np.ndarray, episode: np.ndarray) -> float:
    """The share of the error's variance (x and y summed) explained by each episode's mean error."""
    _, group = np.unique(episode, return_inverse=True)
    means = np.stack([np.bincount(group, error[:, i]) / np.bincount(group) for i in range(error.shape[1])], 1)
    return float(((means[group] - error.mean(0)) ** 2).sum() / ((error - error.mean(0)) ** 2).sum())


def at_close(read: np.ndarray, true: np.ndarray, opened: np.ndarray, ends: np.ndarray) -> dict:
    """At each episode's first close: the hand's horizontal miss, and the readout's error over the 4 frames
    before it."""
    miss, error = [], []
    for start, end in spans(ends):
        closed = np.nonzero(~opened[start:end])[0]
        if not len(closed) or closed[0] == 0:
            continue
        last = start + closed[0] - 1
        before = slice(max(start, last - 3), last + 1)
        miss.append(true[last, :2] * 100)
        error.append((read[before, :2] - true[before, :2]).mean(0) * 100)
    if not miss:  # e.g. drivers that never close
        return {"episodes_closed": 0}
    miss, error = np.array(miss), np.array(error)
    miss_cm, error_cm = np.linalg.norm(miss, axis=1), np.linalg.norm(error, axis=1)
    return {"episodes_closed": len(miss), "miss_cm_median": _r(np.median(miss_cm)),
            "miss_cm_p90": _r(np.percentile(miss_cm, 90)), "error_cm_median": _r(np.median(error_cm)),
            "error_cm_p90": _r(np.percentile(error_cm, 90)),
            "corr_miss_error_xy": [_r(np.corrcoef(miss[:, i], error[:, i])[0, 1]) for i in (0, 1)],
            "share_missed_over_cm": {str(t): _r(np.mean(miss_cm > t)) for t in (0.5, 1.0, 1.5)}}


def latch(read: np.ndarray, true: np.ndarray, hand: np.ndarray, opened: np.ndarray, ends: np.ndarray) -> dict:
    """Near the grasp (hand < 6 cm over the object, < 3 cm beside it, open): the horizontal error (cm, mean
    per episode) of each frame's reading of the object's place against the mean of the readings while the hand
    was ``LATCH_CM`` over the table and the readout put the object within 10 cm."""
    per_frame, latched = [], []
    place_read, place_true = hand + read, hand + true
    for start, end in spans(ends):
        ep = slice(start, end)
        height_cm = hand[ep, 2] * 100
        high = (opened[ep] & (height_cm >= LATCH_CM[0]) & (height_cm < LATCH_CM[1])
                & (np.linalg.norm(read[ep, :2], axis=1) < 0.10))
        near = opened[ep] & (-true[ep, 2] < 0.06) & (np.linalg.norm(true[ep, :2], axis=1) < 0.03)
        if not high.any() or not near.any():
            continue
        err = place_read[ep][near, :2] - place_true[ep][near, :2]
        per_frame.append(np.linalg.norm(err, axis=1).mean() * 100)
        err = place_read[ep][high, :2].mean(0) - place_true[ep][near, :2]
        latched.append(np.linalg.norm(err, axis=1).mean() * 100)
    if not per_frame:
        return {"episodes": 0}
    per_frame, latched = np.array(per_frame), np.array(latched)
    return {"episodes": len(per_frame), "per_frame_cm_median": _r(np.median(per_frame)),
            "per_frame_cm_p90": _r(np.percentile(per_frame, 90)), "latched_cm_median": _r(np.median(latched)),
            "latched_cm_p90": _r(np.percentile(latched, 90)),
            "latched_better_share": _r(np.mean(latched < per_frame))}


def camera_pose(read: np.ndarray, true: np.ndarray, opened: np.ndarray, ends: np.ndarray,
                extrinsics: np.ndarray, band: tuple[float, float] = (12, 30)) -> dict:
    """How much of each episode's mean horizontal error in ``band`` (cm over the object) a linear map of its
    camera's deviation (position, cm; rotation vector, degrees; from the store's mean pose) predicts for an
    episode left out: R^2 in x and y (0: none of it; the world draws the camera +-2 cm, +-2 degrees)."""
    episode = np.searchsorted(ends, np.arange(len(read)), side="right")
    m = in_band(true, opened, *band)
    eps = np.unique(episode[m])
    error = np.stack([(read - true)[m & (episode == e), :2].mean(0) for e in eps]) * 100
    u, _, vt = np.linalg.svd(extrinsics[:, :3, :3].mean(0))
    rot = Rotation.from_matrix(np.einsum("ji,ejk->eik", u @ vt, extrinsics[eps, :3, :3])).as_rotvec()
    pos = extrinsics[eps, :3, 3] - extrinsics[:, :3, 3].mean(0)
    x = np.c_[np.ones(len(eps)), pos * 100, np.degrees(rot)]
    predicted = np.stack([x[i] @ np.linalg.lstsq(np.delete(x, i, 0), np.delete(error, i, 0), rcond=None)[0]
                          for i in range(len(eps))])
    r2 = 1 - ((error - predicted) ** 2).sum(0) / ((error - error.mean(0)) ** 2).sum(0)
    return {"above_cm": list(band), "episodes": len(eps), "r2_left_out_x": _r(r2[0]),
            "r2_left_out_y": _r(r2[1])}


def spans(ends: np.ndarray) -> list[tuple[int, int]]:
    """Each episode's (first, past-last) frame from the store's episode ends."""
    starts = np.concatenate([[0], ends[:-1]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _r(x: float) -> float:
    return round(float(x), 3)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("store", type=Path)
    p.add_argument("--also", type=Path, nargs="+", default=[],
                   help="more checkpoints whose readings are averaged with CKPT's")
    p.add_argument("--versus", type=Path,
                   help="another checkpoint, compared with CKPT (and --also) episode by episode per band")
    p.add_argument("--depth-source", choices=sorted(STORED), default="sensor")
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    torch.set_num_threads(1)
    nets = [checkpoint.load(ckpt).policy() for ckpt in [args.checkpoint, *args.also]]
    steps = LabelledSteps([args.store], nets[0].config.obs_horizon, nets[0].config.action_horizon, depth=True,
                          chunks=False, depth_source=args.depth_source)
    read = np.mean([readout_probes.read(net, steps)[:, OFFSET] for net in nets], axis=0)
    true = steps.labels_np[:, :READOUT][:, OFFSET]
    state = steps.state_np
    hand = hand_pose(torch.from_numpy(state.astype(np.float32))).numpy()[:, :3]
    store = DemoStore.open(args.store)
    opened, ends = state[:, 7] >= OPEN_M, store.episode_ends
    result = {"checkpoint": str(args.checkpoint), "also": [str(c) for c in args.also],
              "store": str(args.store), "frames": len(read), "by_height": slopes(read, true, opened, ends),
              "at_close": at_close(read, true, opened, ends), "latch": latch(read, true, hand, opened, ends),
              "camera_pose": camera_pose(read, true, opened, ends,
                                         np.asarray(store.root["meta/camera_extrinsics"]))}
    if args.versus:
        other = readout_probes.read(checkpoint.load(args.versus).policy(), steps)[:, OFFSET]
        result["versus"] = {"checkpoint": str(args.versus),
                            "by_height": versus(read, other, true, opened, ends)}
    print(json.dumps(result, indent=1))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
