"""Where a student's grasps go wrong (docs/student.md "Where the closing error comes from"); seen kinds, seeds
10000.., randomised episodes, one process:

    python models/student/diagnose.py tolerance --episodes 30   # the scripted expert aiming off on purpose
    python models/student/diagnose.py spread student:S.onnx --episodes 90   # what the closing offset follows
    python models/student/diagnose.py dart --sigma 0 0.3 --episodes 24       # the expert under DART noise

``tolerance`` says how precise a grasp must be; ``dart`` what the demos of ``trainer collect --action-noise``
look like; ``spread`` regresses a policy's closing offset (object minus grasp site when it first closes the
gripper) on each group of the episode's randomisation and prints the adjusted R^2 per group: which of them the
error follows.
"""

from __future__ import annotations

import argparse

import numpy as np

from hil_sim.objects import GROUPS
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, rollouts, run_episode
from trainer.teacher.scripted import ScriptedExpert

KINDS = GROUPS["seen"]
OFFSETS_CM = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (-2, 0, 0), (-4, 0, 0), (0, 1, 0),
              (0, 2, 0), (0, 3, 0), (0, 4, 0), (0, -2, 0), (0, -4, 0), (0, 0, 1), (0, 0, 2), (0, 0, 3)]
"""World x, y, z (z up: a grasp too high)."""
GROUPS_OF_EPISODE = ("object_xy", "object_yaw", "crop_window", "camera_pos", "q0", "link_mass_scale",
                     "joint_friction", "joint_damping_scale", "joint_stiffness", "kind")


def jobs(episodes: int) -> list[Job]:
    """The evaluation episodes every measurement here shares (as ``trainer evaluate``'s defaults)."""
    return [Job(10_000 + i, KINDS[i % len(KINDS)]) for i in range(episodes)]


class OffsetExpert(ScriptedExpert):
    """The scripted expert aiming its grasp ``offset_cm`` away from where it should."""

    def __init__(self, offset_cm: tuple[float, float, float]) -> None:
        super().__init__()
        self.offset = np.asarray(offset_cm, float) / 100

    def _grasp_pose(self, priv: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos, frame = super()._grasp_pose(priv, rot)
        return pos + self.offset, frame


def tolerance(episodes: int) -> None:
    env = GraspEnv(EnvConfig(objects=KINDS, render_depth=False))
    for offset in OFFSETS_CM:
        wins = [run_episode(env, OffsetExpert(offset), job).success for job in jobs(episodes)]
        print(f"grasp aimed {offset} cm off: success {np.mean(wins):.2f} ({episodes} episodes)", flush=True)


def dart(episodes: int, sigmas: list[float]) -> None:
    env = GraspEnv(EnvConfig(objects=KINDS, render_depth=False))
    for sigma in sigmas:
        runs = [run_episode(env, ScriptedExpert(), job, action_noise=sigma) for job in jobs(episodes)]
        closes = np.array([r.closed_at[1] for r in runs if r.closed_at is not None]) * 100
        print(f"action noise {sigma}: success {np.mean([r.success for r in runs]):.2f}, "
              f"{np.mean([r.steps for r in runs]):.0f} steps, object - hand at the first close "
              f"mean {closes.mean(0).round(2)} std {closes.std(0).round(2)} cm ({episodes} episodes)",
              flush=True)


def features(episode: dict, group: str) -> list[float]:
    if group == "kind":
        return [float(episode["kind"] == k) for k in KINDS[1:]]
    if group == "object_yaw":  # grasps are symmetric under a half turn
        return [np.cos(2 * episode[group]), np.sin(2 * episode[group])]
    return list(np.atleast_1d(episode[group]))


def adjusted_r2(x: np.ndarray, y: np.ndarray) -> float:
    a = np.column_stack([x - x.mean(0), np.ones(len(y))])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r2 = 1 - ((y - a @ coef) ** 2).sum() / ((y - y.mean()) ** 2).sum()
    return 1 - (1 - r2) * (len(y) - 1) / (len(y) - x.shape[1] - 1)


def spread(policy: str, episodes: int) -> None:
    runs = rollouts(EnvConfig(objects=KINDS), policy, jobs(episodes))
    closed = [r for r in runs if r.closed_at is not None]
    offsets = np.array([r.closed_at[1] for r in closed]) * 100
    print(f"{len(closed)} of {episodes} episodes closed the gripper; object - hand at the first close, cm:")
    for axis, name in enumerate("xyz"):
        y = offsets[:, axis]
        fits = {g: adjusted_r2(np.array([features(r.episode, g) for r in closed]), y)
                for g in GROUPS_OF_EPISODE}
        print(f"  {name}: mean {y.mean():+.2f}, std {y.std():.2f}; adjusted R^2 of "
              + ", ".join(f"{g} {v:+.2f}" for g, v in fits.items()))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["tolerance", "spread", "dart"])
    p.add_argument("policy", nargs="?", default="scripted", help="spread: a trainer policy spec")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--sigma", type=float, nargs="+", default=[0.0, 0.3], help="dart: action noise levels")
    args = p.parse_args()
    if args.what == "tolerance":
        tolerance(args.episodes)
    elif args.what == "dart":
        dart(args.episodes, args.sigma)
    else:
        spread(args.policy, args.episodes)


if __name__ == "__main__":
    main()
