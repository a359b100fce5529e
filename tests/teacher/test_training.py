"""A tiny-budget training run (CLI, warm start + a few PPO updates) earns more eq. 2-7 return than a
random policy on the same episodes."""

from __future__ import annotations

import numpy as np

from trainer.sim.env import GraspEnv
from trainer.teacher.ppo import TeacherConfig, load

SEEDS = (101, 102, 103)


def _mean_return(act, seeds=SEEDS) -> float:
    env = GraspEnv(TeacherConfig(objects=("cube", "can"), max_steps=40).env_config())
    totals = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            obs, r, terminated, truncated, _ = env.step(act(obs))
            total, done = total + r, terminated or truncated
        totals.append(total)
    env.close()
    return float(np.mean(totals))


def test_tiny_training_beats_random_policy(tiny_teacher):
    rng = np.random.default_rng(0)
    random_return = _mean_return(lambda _: rng.uniform(-1, 1, 8).astype(np.float32))
    teacher_return = _mean_return(load(tiny_teacher).act)
    assert teacher_return > random_return + 0.5, (teacher_return, random_return)
