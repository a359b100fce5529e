"""Where a policy's failed episodes closed the gripper, beside its successful ones (issue 42, lever 3).

Runs the policy over the same seeds as ``trainer evaluate`` (10000..) on the given kinds and prints, for
the successes and the failures apart, the median horizontal distance between the object's centre and the grasp
site at the first close, the median height offset and the median episode length; then each failure's offset.

    python research/m0_failures.py oracle:CKPT [--kinds banana pear] [--episodes 40]
"""

from __future__ import annotations

import argparse

import numpy as np

from trainer.policies import depth_spec
from trainer.sim.env import EnvConfig
from trainer.sim.rollout import Job, rollouts


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("policy")
    p.add_argument("--kinds", nargs="+", default=["banana", "pear"])
    p.add_argument("--episodes", type=int, default=40)
    args = p.parse_args()
    kinds = tuple(args.kinds)
    config = EnvConfig(objects=kinds, randomise=True, depth=depth_spec(args.policy), render_depth=False)
    jobs = [Job(10_000 + i, kinds[i % len(kinds)]) for i in range(args.episodes)]
    rows = []
    for r in rollouts(config, args.policy, jobs, workers=1, sensor_spec="clean", restore="none"):
        offset = r.closed_at[1] * 100 if r.closed_at else np.full(3, np.nan)
        rows.append((r.kind, r.success, r.steps, offset))
    for success in (True, False):
        chosen = [row for row in rows if row[1] == success]
        if not chosen:
            continue
        offsets = np.array([row[3] for row in chosen])
        apart = np.nanmedian(np.linalg.norm(offsets[:, :2], axis=1))
        height, steps = np.nanmedian(offsets[:, 2]), np.median([row[2] for row in chosen])
        print(f"{'successes' if success else 'failures'} {len(chosen)}: closes {apart:.2f} cm apart "
              f"horizontally, height offset {height:.2f} cm, {steps:.0f} steps (medians)")
    for kind, success, steps, offset in rows:
        if not success:
            print(f"  failed {kind}: {steps} steps, closed at object - hand {np.round(offset, 2)} cm")


if __name__ == "__main__":
    main()
