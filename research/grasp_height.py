"""The expert's grasp-height window on thin kinds (issue 42): ``ReactiveExpert`` with its grasp site held at
each given height over the table (``ExpertConfig.tip_clearance_m``), the same seeds (10000..) at every height.

Thin kinds (banana, wheel) are grasped at that lowest height, so the sweep shows where the fingers hold them:
a learned head must close inside the window, and the expert's own height should sit in its middle.

    python research/grasp_height.py [--kinds banana wheel] [--heights-cm 4.6 5.0 5.4 5.8 6.2] [--episodes 30]
"""

from __future__ import annotations

import argparse

from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import run_episode, schedule
from trainer.teacher.scripted import ExpertConfig, ReactiveExpert


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kinds", nargs="+", default=["banana", "wheel"])
    p.add_argument("--heights-cm", nargs="+", type=float, default=[4.6, 5.0, 5.4, 5.8, 6.2])
    p.add_argument("--episodes", type=int, default=30)
    args = p.parse_args()
    print("grasp site over the table, cm: " + "  ".join(f"{h:5.1f}" for h in args.heights_cm))
    for kind in args.kinds:
        env = GraspEnv(EnvConfig(objects=(kind,), randomise=True))
        counts = []
        for height in args.heights_cm:
            expert = ReactiveExpert(ExpertConfig(tip_clearance_m=height / 100))
            counts.append(sum(run_episode(env, expert, job).success
                              for job in schedule((kind,), 10_000, args.episodes)))
        env.close()
        print(f"{kind:>10} of {args.episodes}: " + "  ".join(f"{c:5d}" for c in counts))


if __name__ == "__main__":
    main()
