"""Would finer pixels where the object is read it better? (issue 42: the next lever's ceiling, offline)

The readout reads the object's offset from the hand worst along the camera's line of sight, where the policy
image (192 x 144, the 400 x 300 crop downsampled 2.08x) shows a 6 cm object about 14 pixels wide. This asks
whether the stream's native pixels would help before any policy is built on them: one small CNN reads the
offset (and the object's size) from a 96 x 96 patch of the 848 x 480 stream around the object (~21 cm), the
same CNN from the same patch as the policy image shows it (each native pixel replaced by the policy pixel
that ``crop_resize`` sampled for it: the information of 192 x 144, on the same grid). Both also read the
patch's place in the stream, its median depth and the hand's pose by forward kinematics. The patch centre is
the object's true pixel with 2 px of noise (a keypoint would place it at deploy time).

``collect`` runs a learner (the shipped student) on some kinds and writes one .npz per episode: both patches,
the policy frame, joint state, labels (``trainer.sim.labels``) and the camera-to-object direction; it resumes
where it stopped. ``fit`` trains the CNN on some folders and reports errors on others, near the object split
along the line of sight and across it, per kind.

    PYTHONPATH=. python research/patch_ceiling.py collect OUT --objects seen,squares,shapes --episodes 150 \
        --seed 600000 [--learner student:models/student.onnx] [--workers 2]
    PYTHONPATH=. python research/patch_ceiling.py fit --train DIR ... --test NAME=DIR ... --variant native|low
    PYTHONPATH=. python research/patch_ceiling.py fit --test NAME=DIR ... --variant readout --ckpt CKPT
        # a depth student's own readout on the same frames: the bar the CNN is read against

Under the stereo sensor (issue 45), where the aim is set: ``glimpse`` stores 3 frames of a scene with the hand
12-30 cm over the object (``trainer student readout --glimpse``'s episodes, driven by a policy that reads no
depth), each with both patches of the sensor's own stream; ``fit`` with several variants compares them on the
same held-out frames, paired by episode per height band (``research/low_hand_readout.py``'s ``versus``):

    PYTHONPATH=. python research/patch_ceiling.py glimpse OUT --driver reactive:1.0 --sensor stereo \
        --objects seen,squares,shapes --episodes 500 --seed 80000 [--workers 2]
        # --approach --driver student:ONNX --beta B: a learner's whole approaches (the gate's states)
    PYTHONPATH=. python research/patch_ceiling.py fit --train DIR ... --test NAME=DIR ... \
        --variant readout native low --ckpt CKPT
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from hil_sim.objects import select_kinds
from research.low_hand_readout import BANDS_CM, OPEN_M, in_band, versus
from runtime.preprocess import DepthSpec, crop_resize, normalise
from trainer.dataset import DEPTH_SCALE
from trainer.policies import Observation, depth_spec, make_policy
from trainer.sim.env import HAND_POSITION, EnvConfig, GraspEnv
from trainer.sim.labels import OFFSET, SIZE, frame_labels
from trainer.sim.rollout import in_workers, schedule, start_episode
from trainer.sim.sensors import make_sensor
from trainer.student import checkpoint
from trainer.student.dagger import RoundSpec, labelled_episode
from trainer.student.model import hand_pose
from trainer.teacher.scripted import ReactiveExpert

PATCH = 96
"""Native stream pixels on a side of the patch (~21 cm at the object's ~0.93 m)."""
CENTRE_NOISE_PX = 2.0
NEAR_M = 0.05
STALL = RoundSpec()
"""A learner episode ends once the hand stalls, as a DAgger round's does."""
GLIMPSE = RoundSpec(horizon=0, end_height_m=0.12, glimpse=3)
"""A scene's last 3 frames, the hand stopped 12-30 cm over the object (``trainer student readout
--glimpse``)."""
APPROACH = RoundSpec(horizon=0, end_height_m=0.12)
"""Every frame of an approach that ends 12 cm over the object (``trainer student readout
--end-height-cm 12``)."""


def window_indices(n_stream: int, start: int, crop: int, out: int) -> np.ndarray:
    """For each stream pixel along one axis, the policy pixel ``crop_resize`` sampled nearest to it."""
    scale = crop / out
    return np.clip(np.rint((np.arange(n_stream) - start + 0.5) / scale - 0.5), 0, out - 1).astype(int)


def patches(stream: np.ndarray, spec, window: tuple[int, int], centre: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """The native patch around ``centre`` (u, v stream pixels) and the same patch as the policy frame shows
    it; outside the stream 0 (no data)."""
    top, left = window
    policy = crop_resize(stream, spec, window)
    rows = window_indices(stream.shape[0], top, spec.crop_height, spec.out_height)
    cols = window_indices(stream.shape[1], left, spec.crop_width, spec.out_width)
    u0, v0 = int(round(centre[0])) - PATCH // 2, int(round(centre[1])) - PATCH // 2
    native, low = np.zeros((PATCH, PATCH), np.uint16), np.zeros((PATCH, PATCH), np.uint16)
    r = np.arange(v0, v0 + PATCH)
    c = np.arange(u0, u0 + PATCH)
    rin, cin = (r >= 0) & (r < stream.shape[0]), (c >= 0) & (c < stream.shape[1])
    native[np.ix_(rin, cin)] = stream[np.ix_(r[rin], c[cin])]
    low[np.ix_(rin, cin)] = policy[np.ix_(rows[r[rin]], cols[c[cin]])]
    return native, low


def stream_pixel(world, point: np.ndarray) -> np.ndarray:
    extr = world.camera_extrinsics()
    x, y, z = extr[:3, :3].T @ (point - extr[:3, 3])
    return np.array([world.intr.fx * x / z + world.intr.cx, world.intr.fy * y / z + world.intr.cy])


def episode(env: GraspEnv, learner, job) -> dict:
    info = start_episode(env, learner, job)
    world, rng = env.world, np.random.default_rng([job.seed, 0x9A7C])
    rows: dict[str, list] = {k: [] for k in ("native", "low", "centre", "depth", "state", "labels", "sight")}
    hands = []
    while True:
        obs = env.observation()
        obj, _ = world.object_pose()
        centre = stream_pixel(world, obj) + rng.normal(0, CENTRE_NOISE_PX, 2)
        native, low = patches(world.render_depth(), env.spec, world.episode.crop_window, centre)
        to_object = obj - world.camera_extrinsics()[:3, 3]
        for key, value in (("native", native), ("low", low), ("centre", centre), ("depth", info["depth"]),
                           ("state", info["state"]), ("labels", frame_labels(env)),
                           ("sight", to_object / np.linalg.norm(to_object))):
            rows[key].append(value)
        hands.append(obs[HAND_POSITION])
        action = np.asarray(learner.act(Observation(obs, info["depth"], info["state"])), np.float32)
        _, _, terminated, truncated, info = env.step(action)
        n = STALL.stall_steps
        stalled = len(hands) >= n and np.linalg.norm(hands[-1] - hands[-n]) < STALL.stall_m
        if terminated or truncated or stalled:
            out = {k: np.stack(v) for k, v in rows.items()}
            return out | {"kind": job.kind, "seed": job.seed, "success": bool(info.get("success", False))}


_WORKER: dict = {}


def _init(kinds: tuple[str, ...], learner: str) -> None:
    env = GraspEnv(EnvConfig(objects=kinds, depth=depth_spec(learner)))
    _WORKER.update(env=env, learner=make_policy(learner))


def _work(job) -> dict:
    return episode(_WORKER["env"], _WORKER["learner"], job)


def collect(out: Path, kinds: tuple[str, ...], episodes: int, seed: int, learner: str, workers: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    jobs = [j for j in schedule(kinds, seed, episodes) if not (out / f"{j.seed}.npz").exists()]
    wins = 0
    episodes_done = in_workers(_init, (kinds, learner), _work, jobs, workers, _WORKER)
    for ep in tqdm(episodes_done, total=len(jobs), desc=f"collect {out.name}", unit="ep"):
        np.savez_compressed(out / f"{ep['seed']}.npz", **ep)
        wins += ep["success"]
    print(f"{out}: {wins} of {len(jobs)} new episodes grasped")


class StreamTap:
    """A scene sensor that keeps, beside each stream it renders, the object's pixel and the camera's line of
    sight to it, so the patches are cut from the very frame the policy image was made of."""

    def __init__(self, sensor) -> None:
        self.sensor, self.kept = sensor, []

    def reset(self, world, seed: int) -> None:
        self.kept.clear()
        self.sensor.reset(world, seed)

    def stream(self, world) -> np.ndarray:
        frame = self.sensor.stream(world)
        obj, _ = world.object_pose()
        to_object = obj - world.camera_extrinsics()[:3, 3]
        self.kept.append((frame, stream_pixel(world, obj), to_object / np.linalg.norm(to_object)))
        return frame


def _init_glimpse(config: EnvConfig, spec: RoundSpec, sensor: str) -> None:
    _WORKER.update(env=GraspEnv(config), expert=ReactiveExpert(), spec=spec,
                   learner=make_policy(spec.learner), tap=StreamTap(make_sensor(sensor)))


def _glimpse(job) -> dict:
    w = _WORKER
    env, tap = w["env"], w["tap"]
    record, success = labelled_episode(env, w["expert"], w["learner"], job, w["spec"], tap)
    assert len(tap.kept) == len(record.state), "a stream rendered that the record does not keep"
    rng = np.random.default_rng([job.seed, 0x9A7C])
    centres = [pixel + rng.normal(0, CENTRE_NOISE_PX, 2) for _, pixel, _ in tap.kept]
    window = env.world.episode.crop_window
    cut = [patches(frame, env.spec, window, c) for (frame, _, _), c in zip(tap.kept, centres, strict=True)]
    return {"native": np.stack([n for n, _ in cut]), "low": np.stack([lo for _, lo in cut]),
            "centre": np.stack(centres), "depth": record.depth_sensor, "state": record.state,
            "labels": record.labels, "sight": np.stack([s for _, _, s in tap.kept]), "kind": job.kind,
            "seed": job.seed, "success": success}


def glimpse(out: Path, kinds: tuple[str, ...], episodes: int, seed: int, driver: str, sensor: str,
            workers: int, beta: float = 0.0, approach: bool = False) -> None:
    """Glimpses (or whole approaches) of ``episodes`` scenes under ``sensor``, one .npz each, resumed where it
    stopped."""
    try:
        spec = replace(APPROACH if approach else GLIMPSE, learner=driver, sensor=sensor, beta=beta)
    except ValueError as e:  # a glimpse's driver that reads depth
        raise SystemExit(str(e)) from None
    make_sensor(sensor)  # an unknown sensor fails here in one line, not in every worker
    out.mkdir(parents=True, exist_ok=True)
    jobs = [j for j in schedule(kinds, seed, episodes) if not (out / f"{j.seed}.npz").exists()]
    config = EnvConfig(objects=kinds, depth=depth_spec("student:models/student.onnx"), render_depth=False)
    for ep in tqdm(in_workers(_init_glimpse, (config, spec, sensor), _glimpse, jobs, workers, _WORKER),
                   total=len(jobs), desc=f"glimpse {out.name}", unit="scene"):
        np.savez_compressed(out / f"{ep['seed']}.npz", **ep)


def load(dirs: list[str]) -> dict:
    eps = [np.load(f) for d in dirs for f in sorted(Path(d).glob("*.npz"))]
    if not eps:
        raise SystemExit(f"no episodes in {dirs}")
    data = {k: np.concatenate([e[k] for e in eps]) for k in ("native", "low", "centre", "state", "labels",
                                                             "sight")}
    data["depth"] = np.concatenate([e["depth"] for e in eps])
    data["episode"] = np.repeat(np.arange(len(eps)), [len(e["state"]) for e in eps])
    data["kind"] = np.repeat([str(e["kind"]) for e in eps], [len(e["state"]) for e in eps])
    with torch.no_grad():
        data["hand"] = hand_pose(torch.from_numpy(data["state"].astype(np.float32))).numpy()
    return data


def tensors(data: dict, variant: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Patch (depth about its median, dm; no data 0), scalars (centre, median depth, hand pose), targets
    (offset, size; cm)."""
    mm = data[variant].astype(np.float32)
    valid = mm > 0
    ref = np.array([np.median(p[v]) if v.any() else 0.0 for p, v in zip(mm, valid, strict=True)], np.float32)
    img = np.where(valid, (mm - ref[:, None, None]) / 100.0, 0.0).astype(np.float32)
    scalars = np.concatenate([data["centre"] / 500.0, ref[:, None] / 1000.0, data["hand"]], 1)
    y = np.concatenate([data["labels"][:, OFFSET], data["labels"][:, SIZE]], 1) * 100
    return (torch.from_numpy(img[:, None]), torch.from_numpy(scalars.astype(np.float32)),
            torch.from_numpy(y.astype(np.float32)))


class PatchNet(nn.Module):
    """Four stride-2 convolutions (96 -> 6), flattened so that where a thing is stays, then an MLP."""

    def __init__(self, n_scalars: int, n_out: int) -> None:
        super().__init__()
        chans, layers = (1, 16, 32, 64, 64), []
        for i in range(4):
            k = 5 if i == 0 else 3
            layers += [nn.Conv2d(chans[i], chans[i + 1], k, 2, k // 2), nn.GroupNorm(8, chans[i + 1]),
                       nn.ReLU()]
        self.conv = nn.Sequential(*layers)
        self.mlp = nn.Sequential(nn.Linear(64 * 36 + n_scalars, 256), nn.ReLU(), nn.Linear(256, 256),
                                 nn.ReLU(), nn.Linear(256, n_out))

    def forward(self, img: torch.Tensor, scalars: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat([self.conv(img).flatten(1), scalars], 1))


def fit(train: dict, variant: str, steps: int, batch: int, seed: int
        ) -> tuple[nn.Module, torch.Tensor, torch.Tensor]:
    torch.manual_seed(seed)
    img, s, y = tensors(train, variant)
    s_mean, s_std = s.mean(0), s.std(0) + 1e-6
    net = PatchNet(s.shape[1], y.shape[1])
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, 1e-3, total_steps=steps)
    bar = tqdm(range(steps), desc=f"fit {variant}", mininterval=10)
    for _ in bar:
        idx = torch.randint(0, len(y), (batch,))
        loss = nn.functional.smooth_l1_loss(net(img[idx], (s[idx] - s_mean) / s_std), y[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        bar.set_postfix(loss=f"{loss.item():.3f}", refresh=False)
    return net, s_mean, s_std


def predict(net: nn.Module, s_mean: torch.Tensor, s_std: torch.Tensor, data: dict, variant: str
            ) -> np.ndarray:
    """The CNN's errors [N, 6] (offset, size; cm)."""
    img, s, y = tensors(data, variant)
    with torch.no_grad():
        pred = torch.cat([net(img[i:i + 512], (s[i:i + 512] - s_mean) / s_std)
                          for i in range(0, len(y), 512)])
    return (pred - y).numpy()


def readout_errors(net: nn.Module, data: dict) -> np.ndarray:
    """A depth student's own readout's errors [N, 6] on the same frames (its 3-frame stacks of the policy
    frames, as ``LabelledSteps`` stacks them)."""
    spec, horizon = DepthSpec(), net.config.obs_horizon  # normalise reads only its metric range
    start = np.searchsorted(data["episode"], data["episode"])  # each frame's episode's first row
    stacks = np.maximum(np.arange(len(start))[:, None] - np.arange(horizon - 1, -1, -1), start[:, None])
    facts = []
    with torch.no_grad():
        for i in range(0, len(start), 256):
            rows = stacks[i:i + 256]
            depth = torch.from_numpy(normalise(data["depth"][rows], DEPTH_SCALE, spec))
            _, read, _ = net.perceive(depth, torch.from_numpy(data["state"][i:i + 256].astype(np.float32)))
            facts.append(net.label_norm.unnormalise(read).numpy())
    facts = np.concatenate(facts)
    cols = np.r_[OFFSET, SIZE]
    return (facts[:, cols] - data["labels"][:, cols]) * 100


def summarise(diff: np.ndarray, data: dict) -> dict:
    """Error medians (cm): all frames; near the object (hand within 5 cm horizontally) the offset, its
    horizontal part, the parts along the camera's line of sight and across it, the median episode's mean
    horizontal error (the bias a closed loop acts on) and the mean error of the object's read width."""
    off, size, sight = diff[:, :3], diff[:, 3:], data["sight"]
    near = np.linalg.norm(data["labels"][:, OFFSET][:, :2], axis=1) < NEAR_M
    along = np.sum(off * sight, 1)
    across = np.linalg.norm(off - along[:, None] * sight, axis=1)

    def one(mask: np.ndarray) -> dict:
        m = mask & near
        episodes = np.unique(data["episode"][m])
        bias = [np.linalg.norm(off[m & (data["episode"] == e), :2].mean(0)) for e in episodes]
        return {"frames": int(mask.sum()), "near": int(m.sum()),
                "median": _r(np.median(np.linalg.norm(off[mask], axis=1))),
                "near_median": _r(np.median(np.linalg.norm(off[m], axis=1))),
                "near_xy_median": _r(np.median(np.linalg.norm(off[m, :2], axis=1))),
                "near_along_sight": _r(np.median(np.abs(along[m]))),
                "near_across_sight": _r(np.median(across[m])),
                "near_xy_bias_median": _r(np.median(bias)),
                "near_narrow_width_error": _r(np.mean(2 * size[m, 0]))}

    kinds = sorted(set(data["kind"]))
    return {"all": one(np.ones(len(diff), bool))} | {k: one(data["kind"] == k) for k in kinds}


def _judged(diff: np.ndarray, data: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The read and true offsets (m), whether the hand is open, and the episodes' ends, as
    ``research/low_hand_readout.py`` judges a store's frames."""
    true = data["labels"][:, OFFSET]
    ends = np.cumsum(np.bincount(data["episode"]))
    return true + diff[:, :3] / 100, true, data["state"][:, 7] >= OPEN_M, ends


def by_height(diff: np.ndarray, data: dict) -> list[dict]:
    """Per band of the hand's height over the object: the horizontal error median / p90 (cm)."""
    read, true, opened, _ = _judged(diff, data)
    rows = []
    for lo, hi in BANDS_CM:
        m = in_band(true, opened, lo, hi)
        if m.sum() >= 20:
            error = np.linalg.norm((read - true)[m, :2], axis=1) * 100
            rows.append({"above_cm": [lo, hi], "frames": int(m.sum()),
                         "error_xy_cm_median": _r(np.median(error)),
                         "error_xy_cm_p90": _r(np.percentile(error, 90))})
    return rows


def paired(first: np.ndarray, other: np.ndarray, data: dict) -> list[dict]:
    """``other``'s per-episode error against ``first``'s by height band (``low_hand_readout.versus``)."""
    read, true, opened, ends = _judged(first, data)
    return versus(read, _judged(other, data)[0], true, opened, ends)


def _r(x: float) -> float:
    return round(float(x), 3)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect", help="learner episodes with both patches, one .npz each")
    c.add_argument("out", type=Path)
    c.add_argument("--objects", default="seen")
    c.add_argument("--episodes", type=int, default=100)
    c.add_argument("--seed", type=int, default=600000)
    c.add_argument("--learner", default="student:models/student.onnx")
    c.add_argument("--workers", type=int, default=2)
    g = sub.add_parser("glimpse", help="stereo glimpses (3 frames, hand 12-30 cm up) with both patches, or "
                       "whole approaches")
    g.add_argument("out", type=Path)
    g.add_argument("--driver", default="reactive:1.0",
                   help="a policy that reads no depth (expert, reactive:B, oracle:CKPT@B)")
    g.add_argument("--sensor", default="stereo")
    g.add_argument("--objects", default="seen,squares,shapes")
    g.add_argument("--episodes", type=int, default=500)
    g.add_argument("--seed", type=int, default=80000)
    g.add_argument("--workers", type=int, default=2)
    g.add_argument("--beta", type=float, default=0.0, help="share of steps the expert drives")
    g.add_argument("--approach", action="store_true",
                   help="keep every frame of an approach ending 12 cm up instead (any driver: a learner too)")
    f = sub.add_parser("fit", help="the CNN on --train, its errors (cm) on each --test")
    f.add_argument("--train", nargs="+", help="folders to fit on (not for --variant readout)")
    f.add_argument("--test", nargs="+", required=True, help="NAME=DIR")
    f.add_argument("--variant", nargs="+", choices=("native", "low", "readout"), required=True,
                   help="the CNN on native or policy pixels; readout: --ckpt's own readout, no fit; several: "
                   "each compared with the first, paired by episode")
    f.add_argument("--ckpt", type=Path, help="a depth student checkpoint (--variant readout)")
    f.add_argument("--steps", type=int, default=4000)
    f.add_argument("--batch", type=int, default=64)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--out", type=Path, help="JSON report here too")
    args = p.parse_args()
    if args.cmd == "collect":
        collect(args.out, select_kinds(args.objects), args.episodes, args.seed, args.learner, args.workers)
        return
    if args.cmd == "glimpse":
        glimpse(args.out, select_kinds(args.objects), args.episodes, args.seed, args.driver, args.sensor,
                args.workers, args.beta, args.approach)
        return
    if "readout" in args.variant and not args.ckpt:
        p.error("--variant readout needs --ckpt")
    if set(args.variant) - {"readout"} and not args.train:
        p.error("--variant native / low need --train")
    torch.set_num_threads(1)
    tests = [(name, load([d])) for name, d in (t.split("=", 1) for t in args.test)]
    train = load(args.train) if args.train else None
    result: dict = {"variants": args.variant, "ckpt": str(args.ckpt), "steps": args.steps,
                    "batch": args.batch}
    errors = {}
    for variant in args.variant:
        if variant == "readout":
            net = checkpoint.load(args.ckpt).policy().eval()
            errors[variant] = [readout_errors(net, data) for _, data in tests]
            continue
        start = time.time()
        net, s_mean, s_std = fit(train, variant, args.steps, args.batch, args.seed)
        result[f"fit_s_{variant}"] = round(time.time() - start)
        errors[variant] = [predict(net, s_mean, s_std, data, variant) for _, data in tests]
    for i, (name, data) in enumerate(tests):
        result[name] = {v: summarise(errors[v][i], data) | {"by_height": by_height(errors[v][i], data)}
                        for v in args.variant}
        result[name]["versus"] = {v: paired(errors[args.variant[0]][i], errors[v][i], data)
                                  for v in args.variant[1:]}
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
