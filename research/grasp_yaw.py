"""The expert's tolerance to a turned grasp (issue 42): ``ReactiveExpert`` closing with its fingers turned a
fixed angle off the object's narrow horizontal axis, the same seeds (10000..) at every angle.

The depth student closes on lemons 17-66 degrees off that axis (``research/m0_failures.py``); the sweep says
how much of that the lemon forgives, so whether its grasp direction is what loses it.

    python research/grasp_yaw.py [--kinds lemon] [--degrees 0 15 30 45 60 90] [--episodes 30]
"""

from __future__ import annotations

import argparse

import numpy as np

from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import run_episode, schedule
from trainer.teacher.scripted import ReactiveExpert


class TurnedExpert(ReactiveExpert):
    """Closes ``degrees`` off the object's narrow axis (round kinds keep the wrist as it is)."""

    def __init__(self, degrees: float) -> None:
        super().__init__()
        self.turn = np.radians(degrees)

    def _grasp_yaw(self, obj_quat: np.ndarray, rot: np.ndarray) -> float:
        return super()._grasp_yaw(obj_quat, rot) + self.turn


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kinds", nargs="+", default=["lemon"])
    p.add_argument("--degrees", nargs="+", type=float, default=[0, 15, 30, 45, 60, 90])
    p.add_argument("--episodes", type=int, default=30)
    args = p.parse_args()
    print("fingers off the narrow axis, deg: " + "  ".join(f"{d:5.0f}" for d in args.degrees))
    for kind in args.kinds:
        env = GraspEnv(EnvConfig(objects=(kind,), randomise=True))
        counts = [sum(run_episode(env, TurnedExpert(d), job).success
                      for job in schedule((kind,), 10_000, args.episodes)) for d in args.degrees]
        env.close()
        print(f"{kind:>10} of {args.episodes}: " + "  ".join(f"{c:5d}" for c in counts))


if __name__ == "__main__":
    main()
