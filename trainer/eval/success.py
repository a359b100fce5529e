"""``python -m trainer evaluate``: closed-loop grasp success of a policy in the simulated world.

Episodes cycle through the chosen object kinds (equal counts per kind) with seeds seed, seed+1, ...; an
episode's randomness (scene, sensor draws, a student's start noise) comes from its seed alone, so the same
command gives the same result on any number of ``--workers``. Prints a per-object table and writes
{"success_rate", "ci95", "episodes", "per_object": {kind: rate}, ...} as JSON; ``ci95`` is the Wilson score
interval of the success rate. ``first_close`` says where the hand was when the policy first closed the gripper
(object minus grasp site, cm, world frame): a policy that fails by closing beside or above its objects shows
it there. ``failed_seeds`` lists the episodes that failed, so two policies run on the same seeds can be
compared episode by episode.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hil_sim.objects import OBJECTS_HELP, ObjectError, select_kinds
from runtime.preprocess import RESTORE_METHODS
from trainer.eval.stats import median_interval, wilson_interval
from trainer.policies import NEEDS_DEPTH, PolicyError, depth_spec, parse
from trainer.sim.env import EnvConfig
from trainer.sim.rollout import rollouts, schedule
from trainer.sim.sensors import SensorError, make_sensor, reads_clean_depth


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m trainer evaluate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default="scripted", help="scripted | reactive | ppo:CKPT | student:ONNX")
    p.add_argument("--objects", default="seen", help=OBJECTS_HELP)
    p.add_argument("--sensor", default="clean",
                   help="depth sensor model seen by the policy: clean | stereo[:PARAMS] | randnoise | "
                        "inpaint | ddg[:model=DIR,steps=K] | ddg_nograft[:...] "
                        "(DDG default: models/ddg, 10 DDIM steps)")
    p.add_argument("--restore", choices=RESTORE_METHODS, default="none",
                   help="the runtime's hole restoration applied to what the sensor gives (runtime --restore)")
    p.add_argument("--episodes", type=int, default=60, help="total episodes, spread evenly over the kinds")
    p.add_argument("--seed", type=int, default=10_000, help="seed of the first episode")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes")
    p.add_argument("--no-randomise", action="store_true", help="nominal dynamics, camera and crop")
    p.add_argument("--json", type=Path, help="write the result here")
    return p


def evaluate(policy: str, kinds: tuple[str, ...], episodes: int, *, seed: int = 10_000, workers: int = 1,
             sensor: str = "clean", restore: str = "none", randomise: bool = True) -> dict:
    kind, _ = parse(policy)
    config = EnvConfig(objects=kinds, randomise=randomise, depth=depth_spec(policy),
                       render_depth=NEEDS_DEPTH[kind] and reads_clean_depth(sensor))
    jobs = schedule(kinds, seed, episodes)
    per: dict[str, list[bool]] = {k: [] for k in kinds}
    steps, closes, failed, start = [], [], [], time.perf_counter()
    runs = rollouts(config, policy, jobs, workers=workers, sensor_spec=sensor, restore=restore)
    for r in tqdm(runs, total=episodes, desc=f"evaluate {policy}", unit="ep"):
        per[r.kind].append(r.success)
        steps.append(r.steps)
        if not r.success:
            failed.append(r.seed)
        if r.closed_at is not None:
            closes.append(r.closed_at)
    total = sum(map(sum, per.values()))
    return {"success_rate": total / episodes, "ci95": [round(b, 4) for b in wilson_interval(total, episodes)],
            "episodes": episodes, "per_object": {k: sum(v) / len(v) for k, v in per.items() if v},
            "policy": policy, "sensor": sensor, "restore": restore, "objects": list(kinds), "seed": seed,
            "mean_steps": sum(steps) / max(1, len(steps)), "first_close": first_close(closes),
            "failed_seeds": sorted(failed), "seconds": round(time.perf_counter() - start, 1)}


def first_close(closes: list[tuple[int, np.ndarray]]) -> dict:
    """Episodes whose policy closed the gripper, the median step it first did, and the object's offset from
    the grasp site then: mean and std per axis, and the median horizontal distance (cm) with its interval."""
    if not closes:
        return {"episodes": 0}
    # float64 before rounding: a float32 rounded to 2 decimals prints as -3.2799999713897705
    offsets = np.array([offset for _, offset in closes], dtype=np.float64) * 100
    horizontal = np.linalg.norm(offsets[:, :2], axis=1)
    return {"episodes": len(closes), "median_step": float(np.median([step for step, _ in closes])),
            "offset_cm_mean": offsets.mean(0).round(2).tolist(),
            "offset_cm_std": offsets.std(0).round(2).tolist(),
            "horizontal_cm_median": round(float(np.median(horizontal)), 2),
            "horizontal_cm_median_ci95": median_interval(horizontal)}


def table(result: dict) -> str:
    width = max([12, *map(len, result["per_object"])])  # a user object is named by its path
    rows = [f"{'object':<{width}} {'success':>8}"]
    rows += [f"{k:<{width}} {v:>8.1%}" for k, v in result["per_object"].items()]
    lo, hi = result["ci95"]
    closes = result["first_close"]
    if closes["episodes"]:
        interval = closes["horizontal_cm_median_ci95"]
        rows.append(f"first close in {closes['episodes']} episodes, median step {closes['median_step']:.0f}: "
                    f"object - hand {closes['offset_cm_mean']} cm (std {closes['offset_cm_std']}), "
                    f"{closes['horizontal_cm_median']} cm apart horizontally (median"
                    + (f"; 95 % CI {interval})" if interval else ")"))
    rows.append(f"{'ALL':<{width}} {result['success_rate']:>8.1%}  (95 % CI {lo:.1%}-{hi:.1%}; "
                f"{result['episodes']} episodes, {result['policy']}, sensor {result['sensor']}, "
                f"restore {result['restore']})")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        parse(args.policy)
        make_sensor(args.sensor)
        kinds = select_kinds(args.objects)
        result = evaluate(args.policy, kinds, args.episodes, seed=args.seed, workers=args.workers,
                          sensor=args.sensor, restore=args.restore, randomise=not args.no_randomise)
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(result, indent=2))
    except (PolicyError, SensorError, ObjectError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
