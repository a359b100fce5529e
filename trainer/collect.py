"""``python -m trainer collect``: record successful teacher demos into a zarr demo store.

Episodes cycle through the object kinds; episode i uses seed ``--seed + i``, so a rerun on the same store
resumes where the last one stopped (attempts are counted in the store) until ``--episodes`` successful
episodes are stored. Failed episodes are counted, not stored. Layout: ``trainer.dataset``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hil_sim.objects import OBJECTS_HELP, ObjectError, select_kinds
from runtime.preprocess import DepthSpec
from trainer.dataset import DatasetError, DemoStore, EpisodeRecord, sizes
from trainer.policies import NEEDS_DEPTH, PolicyError, depth_spec, parse
from trainer.sim.env import EnvConfig
from trainer.sim.rollout import Rollout, rollouts, schedule
from trainer.sim.sensors import make_sensor


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m trainer collect", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--teacher", default="scripted",
                   help="scripted | reactive | ppo:CKPT, or another policy spec of trainer.policies")
    p.add_argument("--episodes", type=int, required=True, help="successful episodes wanted in the store")
    p.add_argument("--out", type=Path, required=True, help="zarr store (created, or resumed if it exists)")
    p.add_argument("--objects", default="seen", help=OBJECTS_HELP)
    p.add_argument("--rgb", action="store_true", help="also store RGB (about 7x slower to render)")
    p.add_argument("--no-depth", action="store_true",
                   help="skip depth rendering (throughput baseline; depth is then stored as zeros)")
    p.add_argument("--sensor", default="clean",
                   help="also store what this depth sensor shows the policy at each step (e.g. stereo: "
                        "hil_sim's active-stereo D455), as data/depth_sensor beside the clean depth; "
                        "students train on it with --depth-source sensor (clean: nothing more)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes")
    p.add_argument("--action-noise", type=float, default=0.0,
                   help="DART: std of Gaussian noise on the teacher's joint actions as executed (normalised "
                        "units; actions span [-1, 1]); the stored actions are the teacher's own, so a "
                        "student sees how to recover from the drift its own errors cause (0: off)")
    p.add_argument("--wrist-noise", type=float, default=EnvConfig.wrist_noise,
                   help="uniform +- noise on the wrist's (joint 7) start angle, rad: wider than the default, "
                        "the wrist's angle no longer tells a student which way the expert turns it "
                        "(docs/student.md \"The wrist's turn\")")
    p.add_argument("--resolution", type=resolution, default=f"{DepthSpec.out_width}x{DepthSpec.out_height}",
                   metavar="WxH", help="policy depth resolution stored, from the same crop window (default "
                   "%(default)s; finer pixels place the object more precisely, at more training cost)")
    p.add_argument("--max-attempts", type=int, default=0,
                   help="give up after this many attempts in the store (0: 2 x N + 20)")
    return p


def resolution(text: str) -> tuple[int, int]:
    """'192x144' -> (192, 144): the policy depth's width and height."""
    width, sep, height = text.partition("x")
    if not (sep and width.isdigit() and height.isdigit()):
        raise argparse.ArgumentTypeError(f"resolution must be WIDTHxHEIGHT, e.g. 192x144, got {text!r}")
    return int(width), int(height)


def _record(r: Rollout, spec_shape: tuple[int, int]) -> EpisodeRecord:
    f = r.frames
    depth = (np.stack(f["depth"]) if f["depth"] and f["depth"][0] is not None
             else np.zeros((len(f["action"]), *spec_shape), np.uint16))
    optional = {key: np.stack(f[key]) if key in f else None for key in ("rgb", "depth_sensor")}
    return EpisodeRecord(depth, np.stack(f["state"]), np.stack(f["action"]), r.kind, r.seed,
                         tuple(r.episode["crop_window"]), r.camera_K, r.camera_extrinsics, r.episode,
                         **optional)


def collect(args: argparse.Namespace) -> dict:
    teacher, _ = parse(args.teacher)
    make_sensor(args.sensor)  # an unknown sensor is refused before a store is made
    kinds = select_kinds(args.objects)
    spec = DepthSpec(out_width=args.resolution[0], out_height=args.resolution[1])
    read = depth_spec(args.teacher)  # opens a student file once
    if NEEDS_DEPTH[teacher] and read != spec:  # a student, which reads its own resolution
        raise ValueError(f"the teacher {args.teacher} reads {sizes(read)}: pass its resolution as "
                         "--resolution")
    config = EnvConfig(objects=kinds, render_depth=not args.no_depth, render_rgb=args.rgb,
                       wrist_noise=args.wrist_noise, depth=spec)
    store = DemoStore.create(args.out, spec=spec, action_scale=config.action_scale,
                             control_rate_hz=config.control_rate_hz, rgb=args.rgb,
                             sensor=None if args.sensor == "clean" else args.sensor,
                             attrs={"teacher": args.teacher, "seed": args.seed, "objects": list(kinds),
                                    "action_noise": args.action_noise, "wrist_noise": args.wrist_noise})
    start_attempt = int(store.attrs["attempted"])
    limit = args.max_attempts or 2 * args.episodes + 20
    jobs = schedule(kinds, args.seed, limit, start_attempt)
    bar = tqdm(total=args.episodes, initial=store.n_episodes, desc="collect", unit="ep")
    t0, new = time.perf_counter(), 0
    results = rollouts(config, args.teacher, jobs, workers=args.workers, record=True,
                       sensor_spec=args.sensor, action_noise=args.action_noise)
    try:
        for r in results if store.n_episodes < args.episodes else ():
            if r.success:
                store.append(_record(r, (spec.out_height, spec.out_width)))
                bar.update(1)
                new += 1
            store.count(success=r.success)
            bar.set_postfix(failed=store.attrs["failed"])
            if store.n_episodes >= args.episodes:
                break
    finally:
        results.close()
        bar.close()
    minutes = (time.perf_counter() - t0) / 60
    return {**{k: store.attrs[k] for k in ("attempted", "succeeded", "failed")},
            "new_episodes": new, "episodes_per_min": round(new / max(minutes, 1e-9), 2)}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        if args.action_noise < 0:
            raise ValueError(f"--action-noise must be >= 0, got {args.action_noise}")
        if args.wrist_noise < 0:
            raise ValueError(f"--wrist-noise must be >= 0, got {args.wrist_noise}")
        summary = collect(args)
    except (DatasetError, PolicyError, ObjectError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(" ".join(f"{k}={v}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
