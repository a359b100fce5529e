"""How precisely can the object's offset from the hand be read, given perfect keypoints? (issue 42, lever 4)

A small MLP regresses the offset (object centre minus grasp site, m) from the true pixels of the object and
the grasp site (the labels the fine keypoints are supervised to) and the hand's pose by forward kinematics,
with and without the depth under those two pixels, trained on one labelled store and measured on others
(the expert's held-out frames and a student's own). The grasp site floats between the finger pads, so
the depth under its pixel is whatever lies behind it; the ``fingers`` variants read the nearest depth around
the two finger pads instead (their pixels found by forward kinematics of the stored joint state and the
episode's stored camera), where the image shows how far the hand is along the camera's line of sight.
Keypoint noise of a few pixels is then added at test to see how precise the keypoints must be. Errors near
the object are also split along the camera's line of sight and across it. Prints one JSON object.

    python research/readout_ceiling.py --train STORE[@A:B] ... --test NAME=STORE[@A:B] ... [--steps 3000]
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np
import torch
import zarr
from torch import nn

from hil_sim.world import World
from trainer.sim.labels import HAND_PX, OBJECT_PX, OFFSET, project
from trainer.student.model import hand_pose


def depth_at(depth_mm: np.ndarray, px: np.ndarray, reach: int = 0) -> np.ndarray:
    """Depth (m) at spatial-softmax coordinates ``px`` [N, 2] (nearest pixel, clamped to the image); with
    ``reach`` r, the nearest surface within r pixels of it (a finger is ~2 px wide at 128 x 96)."""
    n, h, w = depth_mm.shape
    u = np.clip(np.rint((px[:, 0] + 1) / 2 * (w - 1)), 0, w - 1).astype(int)
    v = np.clip(np.rint((px[:, 1] + 1) / 2 * (h - 1)), 0, h - 1).astype(int)
    if reach == 0:  # the pixel itself, no data (0) included, as the first variants always read it
        return depth_mm[np.arange(n), v, u].astype(np.float32) / 1000.0
    near = np.full(n, np.iinfo(np.uint16).max, np.int64)
    for dv in range(-reach, reach + 1):
        for du in range(-reach, reach + 1):
            z = depth_mm[np.arange(n), np.clip(v + dv, 0, h - 1), np.clip(u + du, 0, w - 1)].astype(np.int64)
            near = np.minimum(near, np.where(z > 0, z, near))  # 0 = no data
    return near.astype(np.float32) / 1000.0


PAD_REACH = 1
"""Pixels around a finger pad's pixel searched for its depth (the nearest surface there)."""
VARIANTS = ("pixels", "pixels+depth", "relative+depth", "fingers+depth", "relative+fingers")
"""What the MLP reads: both pixels and the hand's pose by forward kinematics; the same with the depth under
the two pixels; or only image-space quantities (the pixels' difference, the hand's pixel, both depths and
their difference), where an error of the camera's pose shifts both points alike and cancels; the last two
as the second and third with the two finger pads' pixels and depths in place of the grasp site's."""


def inputs(store: dict, variant: str, pixel_noise: float, rng: np.random.Generator) -> np.ndarray:
    labels, h, w = store["labels"], *store["depth"].shape[1:]
    step = np.array([2 / (w - 1), 2 / (h - 1)], np.float32)  # one pixel in [-1, 1] units
    obj = labels[:, OBJECT_PX] + rng.normal(0, pixel_noise, (len(labels), 2)).astype(np.float32) * step
    hand = labels[:, HAND_PX] + rng.normal(0, pixel_noise, (len(labels), 2)).astype(np.float32) * step
    z_obj, z_hand = depth_at(store["depth"], obj)[:, None], depth_at(store["depth"], hand)[:, None]
    pads = [store["pads"][:, i] + rng.normal(0, pixel_noise, (len(labels), 2)).astype(np.float32) * step
            for i in range(2)]
    z_pads = [depth_at(store["depth"], pad, PAD_REACH)[:, None] for pad in pads]
    parts = {"pixels": [obj, hand, store["hand"]],
             "pixels+depth": [obj, hand, store["hand"], z_obj, z_hand],
             "relative+depth": [obj - hand, hand, z_obj, z_hand, z_obj - z_hand],
             "fingers+depth": [obj, *pads, store["hand"], z_obj, *z_pads],
             "relative+fingers": [obj - hand, hand, *(obj - pad for pad in pads), z_obj, *z_pads,
                                  *(z_obj - z for z in z_pads)]}[variant]
    return np.concatenate(parts, axis=1).astype(np.float32)


def load(spec: str) -> dict:
    """A labelled store, ``PATH`` or ``PATH@A:B`` for its episodes A to B-1."""
    path, _, episodes = spec.partition("@")
    z = zarr.open(path, mode="r")
    ends = np.asarray(z["meta/episode_ends"])
    a, b = (int(i) for i in episodes.split(":")) if episodes else (0, len(ends))
    rows = slice(ends[a - 1] if a else 0, ends[b - 1])
    state = torch.from_numpy(np.asarray(z["data/state"][rows], np.float32))
    with torch.no_grad():
        hand = hand_pose(state).numpy()
    lengths = np.diff(np.concatenate([[0], ends]))[a:b]
    episode = np.repeat(np.arange(b - a), lengths)
    labels = np.asarray(z["data/labels"][rows])
    pads, sight = pad_pixels(z, rows, episode + a, labels)
    return {"labels": labels, "depth": np.asarray(z["data/depth"][rows]),
            "hand": hand, "episode": episode, "pads": pads, "sight": sight}


_WORLD: World | None = None


def pad_pixels(z, rows: slice, episode: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the two finger pads' pixels [N, 2, 2] (spatial-softmax coordinates) and the unit direction
    from the camera to the object [N, 3]. The pads sit on their fingers at the grasp site's height along them;
    the grasp site's own pixel, recomputed the same way, must match its label (checked)."""
    global _WORLD
    _WORLD = _WORLD or World(kinds=("cube",))
    w, ids = _WORLD, _WORLD._ids
    state = np.asarray(z["data/state"][rows], np.float64)
    extr, crops = np.asarray(z["meta/camera_extrinsics"]), np.asarray(z["meta/crop_window"])
    pads, sight, hand_px = np.zeros((len(state), 2, 2), np.float32), np.zeros((len(state), 3)), []
    for i, (s, e) in enumerate(zip(state, episode, strict=True)):
        w.data.qpos[ids.arm_qpos] = s[:7]
        w.data.qpos[ids.finger_qpos] = s[7] / 2
        mujoco.mj_kinematics(w.model, w.data)
        site, fingers = w.data.site_xpos[ids.ee_site], w.data.xpos[list(ids.fingers)]
        level = site - fingers.mean(0)  # from the fingers' bases to the pads' height
        pads[i] = [project(f + level, extr[e], crops[e], w) for f in fingers]
        hand_px.append(project(site, extr[e], crops[e], w))
        to_object = site + labels[i, OFFSET] - extr[e][:3, 3]
        sight[i] = to_object / np.linalg.norm(to_object)
    err = np.abs(np.array(hand_px) - labels[:, HAND_PX]).max()
    assert err < 5e-3, f"recomputed grasp-site pixels are {err:.4f} off their labels"  # 0.3 px: float32 state
    return pads, sight


def merged(stores: list[dict]) -> dict:
    """One store of several; episode numbers kept apart."""
    first = 0
    for store in stores:
        store["episode"] = store["episode"] + first
        first = store["episode"].max() + 1
    return {k: np.concatenate([s[k] for s in stores]) for k in stores[0]}


def fit(x: np.ndarray, y: np.ndarray, steps: int, seed: int) -> nn.Module:
    torch.manual_seed(seed)
    mean, std = x.mean(0), x.std(0) + 1e-6
    net = nn.Sequential(nn.Linear(x.shape[1], 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(),
                        nn.Linear(256, 3))
    xt, yt = torch.from_numpy((x - mean) / std), torch.from_numpy(y * 100)  # cm
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        idx = torch.randint(0, len(xt), (512,))
        loss = nn.functional.mse_loss(net(xt[idx]), yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    net.mean, net.std = mean, std
    return net


def errors_cm(net: nn.Module, x: np.ndarray, store: dict) -> dict:
    """Error medians (all frames, near the object; there also the part along the camera's line of sight and
    the part across it) and the per-episode bias: the norm of an episode's mean error over its near frames,
    the part of the error a closed loop cannot average away."""
    y, episode, sight = store["labels"][:, OFFSET], store["episode"], store["sight"]
    with torch.no_grad():
        pred = net(torch.from_numpy((x - net.mean) / net.std)).numpy()
    diff = pred - y * 100
    err = np.linalg.norm(diff, axis=1)
    near = np.linalg.norm(y, axis=1) < 0.05
    bias = [np.linalg.norm(diff[near & (episode == e)].mean(0)) for e in np.unique(episode[near])]
    along = np.abs(np.sum(diff * sight, axis=1))
    across = np.linalg.norm(diff - (diff * sight).sum(1, keepdims=True) * sight, axis=1)
    return {"median": round(float(np.median(err)), 3), "p90": round(float(np.percentile(err, 90)), 3),
            "near_median": round(float(np.median(err[near])), 3) if near.any() else None,
            "near_along_sight": round(float(np.median(along[near])), 3) if near.any() else None,
            "near_across_sight": round(float(np.median(across[near])), 3) if near.any() else None,
            "near_bias_median": round(float(np.median(bias)), 3) if bias else None}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--train", nargs="+", required=True, help="PATH[@A:B] stores to fit on")
    p.add_argument("--test", nargs="+", required=True, help="NAME=STORE")
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0], help="keypoint noise, px")
    args = p.parse_args()
    torch.set_num_threads(1)
    train = merged([load(spec) for spec in args.train])
    tests = {name: load(path) for name, path in (t.split("=", 1) for t in args.test)}
    report = {}
    for variant in VARIANTS:
        rng = np.random.default_rng(0)
        net = fit(inputs(train, variant, 0.0, rng), train["labels"][:, OFFSET], args.steps, 0)
        report[variant] = {f"{name} noise {noise}px": errors_cm(net, inputs(s, variant, noise, rng), s)
                           for name, s in tests.items() for noise in args.noise}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
