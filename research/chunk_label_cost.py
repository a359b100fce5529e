"""What the expert's chunk labels cost a learner episode: the same episodes collected with the expert's
16-action chunk from every state (``RoundSpec.horizon`` 16: its lookahead in the physics) and with the frames'
perception labels alone (horizon 0, what ``trainer student readout --no-chunks`` stores for a perception-only
refit), one after the other in one process, so both see the same machine load.

    PYTHONPATH=. python research/chunk_label_cost.py --learner student:models/student.onnx --episodes 12

Prints seconds per episode for each, their ratio, and whether the two drove the same states.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hil_sim.objects import select_kinds
from runtime.policy import Policy
from trainer.policies import make_policy
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import schedule
from trainer.student.dagger import RoundSpec, labelled_episode
from trainer.teacher.scripted import ReactiveExpert


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--learner", required=True, help="a policy spec, e.g. student:models/student.onnx")
    p.add_argument("--episodes", type=int, default=12)
    p.add_argument("--objects", default="seen")
    p.add_argument("--seed", type=int, default=500_000)
    args = p.parse_args()
    depth = Policy(args.learner.partition(":")[2]).metadata.preprocess
    env, expert = GraspEnv(EnvConfig(objects=select_kinds(args.objects), depth=depth)), ReactiveExpert()
    learner = make_policy(args.learner)
    seconds = {16: [], 0: []}
    same = 0
    for job in schedule(select_kinds(args.objects), args.seed, args.episodes):
        states = {}
        for horizon in (16, 0):
            began = time.perf_counter()
            record, _ = labelled_episode(env, expert, learner, job, RoundSpec(learner=args.learner,
                                                                            horizon=horizon))
            seconds[horizon].append(time.perf_counter() - began)
            states[horizon] = record.state
        same += states[16].shape == states[0].shape and np.array_equal(states[16], states[0])
    chunks, frames = np.mean(seconds[16]), np.mean(seconds[0])
    print(f"{args.episodes} episodes: with chunks {chunks:.2f} s each, frames alone {frames:.2f} s each, "
          f"{chunks / frames:.2f}x; the same states in {same} of {args.episodes}")


if __name__ == "__main__":
    main()
