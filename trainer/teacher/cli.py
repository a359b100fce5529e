"""``python -m trainer teacher fit|bench|plot|smoothness``: train the PPO teacher, measure vectorised env
throughput, draw learning curves, compare policies' smoothness.

  fit    DAgger warm start from the reactive scripted expert (unless --dagger-episodes 0), then PPO within
         --steps / --budget-minutes; checkpoint, progress.csv and learning_curve.png in --out; --resume
         continues.
  bench  env steps/s of the state-only env, SubprocVecEnv vs DummyVecEnv, random actions.
  plot   learning-curve PNG from one or more progress.csv files (LABEL=PATH).
  smoothness  success per kind and mean squared joint acceleration (eq. 7) of policies, side by side.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hil_sim.objects import OBJECTS_HELP, ObjectError, select_kinds
from trainer.argspec import add_dataclass_args, from_args
from trainer.menu import Menu
from trainer.teacher.normaliser import NormaliserError
from trainer.teacher.ppo import VEC_KINDS, TeacherConfig, TeacherError, make_vec_env, train
from trainer.teacher.progress import plot_curves
from trainer.teacher.smoothness import measure

PROG = "python -m trainer teacher"


def fit(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"{PROG} fit")
    p.add_argument("--out", type=Path, required=True, help="checkpoint folder (created or resumed)")
    p.add_argument("--objects", default="seen", help=OBJECTS_HELP)
    p.add_argument("--resume", action="store_true", help="continue the checkpoint in --out")
    add_dataclass_args(p, TeacherConfig, skip=("objects",))  # --objects: a group name or a list
    args = p.parse_args(argv)
    config = from_args(TeacherConfig, args, objects=select_kinds(args.objects))
    summary = train(config, args.out, resume=args.resume)
    plot_curves({args.out.name: args.out / "progress.csv"}, args.out / "learning_curve.png")
    print(json.dumps({k: v for k, v in summary.items() if k != "config"}, indent=2))
    return 0


def bench_vec(vec: str, n_envs: int, steps: int) -> float:
    """Env steps/s (summed over envs) of random actions after one warm-up step."""
    venv = make_vec_env(TeacherConfig(n_envs=n_envs, vec=vec, batch_size=1))
    try:
        venv.reset()
        rng = np.random.default_rng(0)
        actions = lambda: rng.uniform(-1, 1, (n_envs, 8)).astype(np.float32)  # noqa: E731
        venv.step(actions())
        t0 = time.perf_counter()
        for _ in range(steps):
            venv.step(actions())
        return steps * n_envs / (time.perf_counter() - t0)
    finally:
        venv.close()


def bench(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"{PROG} bench")
    p.add_argument("--steps", type=int, default=400, help="vectorised steps per setting")
    p.add_argument("--n-envs", type=int, default=2)
    p.add_argument("--json", type=Path, help="write the figures here")
    args = p.parse_args(argv)
    result = {f"{vec}_steps_per_s": round(bench_vec(vec, args.n_envs, args.steps), 1) for vec in VEC_KINDS}
    result.update(n_envs=args.n_envs, steps=args.steps)
    print(json.dumps(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


def plot(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"{PROG} plot")
    p.add_argument("curves", nargs="+", help="LABEL=PATH/progress.csv")
    p.add_argument("--png", type=Path, required=True)
    args = p.parse_args(argv)
    curves = {}
    for item in args.curves:
        label, sep, path = item.partition("=")
        if not sep:
            raise TeacherError(f"curve {item!r}: expected LABEL=PATH")
        curves[label] = Path(path)
    plot_curves(curves, args.png)
    return 0


def smoothness(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"{PROG} smoothness")
    p.add_argument("--policy", action="append", required=True, help="scripted | ppo:CKPT (repeatable)")
    p.add_argument("--objects", default="seen", help=OBJECTS_HELP)
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--seed", type=int, default=10_000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", type=Path, help="write the figures here")
    args = p.parse_args(argv)
    kinds = select_kinds(args.objects)
    results = [measure(spec, kinds, args.episodes, seed=args.seed, workers=args.workers)
               for spec in args.policy]
    for r in results:
        lo, hi = r["ci95"]
        print(f"{r['policy']:<40} success {r['success_rate']:6.1%} [{lo:.1%}, {hi:.1%}]  mean sq joint accel "
              f"{r['mean_sq_joint_accel']:9.2f} (rad/s^2)^2  p99 {r['p99_sq_joint_accel']:9.2f}  "
              f"steps/ep {r['mean_steps']:.0f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


MENU = Menu(PROG, {
    "fit": ("train the PPO teacher", "trainer.teacher.cli:fit"),
    "bench": ("vectorised env steps/s, subproc vs dummy", "trainer.teacher.cli:bench"),
    "plot": ("learning-curve PNG from progress.csv files", "trainer.teacher.cli:plot"),
    "smoothness": ("eq. 7 smoothness and success of policies", "trainer.teacher.cli:smoothness"),
}, errors=(TeacherError, NormaliserError, ObjectError, OSError))
main = MENU.main

if __name__ == "__main__":
    sys.exit(main())
