"""Smoothness of a policy's motion, paper eq. 7: mean squared joint acceleration over its episodes.

The env's reward already computes ``p_accel = |ddq|^2`` (7 arm joints, ddq from velocities one control
step apart) and logs it weighted as ``terms["accel"] = -w4 * p_accel``; this reads it back, so the figure
is exactly the quantity the teacher is penalised on. Reported per joint: p_accel / 7, in (rad/s^2)^2.
"""

from __future__ import annotations

import multiprocessing as mp
from functools import partial

import numpy as np
from tqdm import tqdm

from trainer.eval.stats import wilson_interval
from trainer.policies import Observation, make_policy
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, schedule

_CACHE: dict = {}


def _episode(config: EnvConfig, spec: str, job: Job) -> tuple[str, bool, list[float]]:
    if _CACHE.get("key") != (config, spec):
        _CACHE.update(key=(config, spec), env=GraspEnv(config), policy=make_policy(spec))
    env, policy = _CACHE["env"], _CACHE["policy"]
    obs, info = env.reset(seed=job.seed, options={"kind": job.kind})
    policy.reset(info)
    accel = []
    while True:
        action = policy.act(Observation(obs, None, info["state"]))
        obs, _, terminated, truncated, info = env.step(np.asarray(action, np.float32))
        accel.append(-info["terms"]["accel"] / config.weights.w4 / 7)
        if terminated or truncated:
            return job.kind, bool(info["success"]), accel


def measure(spec: str, kinds: tuple[str, ...], episodes: int, *, seed: int = 10_000,
            workers: int = 2) -> dict:
    """Success per kind and mean squared joint acceleration of ``spec`` over ``episodes`` (kinds cycled,
    seeds seed, seed+1, ...: ``trainer.sim.rollout.schedule``)."""
    config = EnvConfig(objects=kinds, render_depth=False)
    jobs = schedule(kinds, seed, episodes)
    work = partial(_episode, config, spec)
    bar = partial(tqdm, total=episodes, desc=f"smoothness {spec}", unit="ep")
    if workers <= 1:
        results = list(bar(map(work, jobs)))
    else:
        with mp.get_context("spawn").Pool(workers) as pool:
            results = list(bar(pool.imap(work, jobs)))
    accel = np.concatenate([r[2] for r in results])
    per = {k: float(np.mean([ok for kind, ok, _ in results if kind == k]))
           for k in dict.fromkeys(r[0] for r in results)}
    wins = sum(r[1] for r in results)
    return {"policy": spec, "episodes": episodes, "success_rate": wins / episodes,
            "ci95": wilson_interval(wins, episodes),
            "per_object": per, "mean_sq_joint_accel": float(accel.mean()),
            "p99_sq_joint_accel": float(np.percentile(accel, 99)), "mean_steps": len(accel) / episodes}
