"""Warm start of the PPO teacher: DAgger from the reactive scripted expert, then a critic fitted to the
cloned actor's own returns, so PPO starts from a policy that already grasps.

Why DAgger and not plain behaviour cloning: ``ScriptedExpert`` decides "descend now" and "lift now" from
its phase memory, which the 40-d observation does not show, and a clone of 40 of its episodes hovered at
the pre-grasp point (0 % success). ``ReactiveExpert`` reads the phase off the observation, so its actions
are a function a memoryless actor can fit; and it labels any state, so each round rolls out the learner,
labels the states it visits (its mistakes included) and refits on everything gathered so far.

Two things make the rounds count on a loaded 2-core machine: learner steps follow the expert with
probability ``beta`` (halved each round), so early learners still reach the grasp and lift states and get
them labelled; and a learner episode stops once the hand has stalled, whose repeats teach nothing new.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3 import PPO
from tqdm import tqdm

from trainer.sim.env import HAND_POSITION, OBS_DIM, EnvConfig, GraspEnv
from trainer.teacher.normaliser import ARM_VELOCITIES, ObsNormaliser
from trainer.teacher.observation import TeacherObservation
from trainer.teacher.scripted import ReactiveExpert

Actor = Callable[[np.ndarray], np.ndarray]
EVAL_SEED = 20_000
"""First seed of the held-out episodes of the learning curve: apart from the rounds' (1,000,000+) and from the
evaluation sets of the docs (10,000+)."""
RoundLog = Callable[[dict], None]


@dataclass(frozen=True)
class DaggerConfig:
    rounds: int = 14
    """Learner rounds after the expert's own episodes (0: plain behaviour cloning)."""
    episodes: int = 60
    """Episodes per learner round."""
    epochs: int = 60
    """Passes over the aggregated data after each round (20 underfit: 58 % against 79 % success after
    8 rounds, docs/teacher.md)."""
    expert_episodes: int = 200
    """Episodes of the expert's own round (cheap, and the initial states need many to cover)."""
    beta: float = 0.5
    """Probability that a step of learner round 1 executes the expert's action; halved each round."""
    stall_steps: int = 10
    """A learner episode ends when the hand moved less than ``stall_m`` over this many steps."""
    stall_m: float = 0.002
    eval_episodes: int = 30
    """Held-out episodes (seeds 20000+) the actor runs alone, deterministic, after each round: the learning
    curve's success rate (0 skips it)."""
    batch_size: int = 256
    lr: float = 1e-3
    seed: int = 0


@dataclass(frozen=True)
class Episode:
    obs: np.ndarray
    """float32 [T, 55] teacher observations (``trainer.teacher.observation``) the driver saw."""
    labels: np.ndarray
    """float32 [T, 8] the expert's actions at them, clipped to the action box."""
    returns: np.ndarray
    """float32 [T] discounted eq. 2-7 return from each step on, under the driver."""
    total: float
    """Undiscounted episode return (what PPO's episode log reports)."""
    success: bool


def labelled_episode(env: TeacherObservation, expert: ReactiveExpert, seed: int, gamma: float,
                     driver: Actor | None = None, beta: float = 0.0,
                     stall: tuple[int, float] | None = None) -> Episode:
    """One episode, every state labelled by the expert, driven by ``driver`` except for a ``beta`` share of
    steps (all of them when ``driver`` is None) that execute the label; ``stall`` = (steps, metres) ends it
    once the grasp site moved less than that over that many steps."""
    obs, info = env.reset(seed=seed)
    expert.reset(info)
    rng = np.random.default_rng(seed)
    observations, labels, rewards = [], [], []
    while True:
        label = np.clip(expert.act(obs[:OBS_DIM]), -1.0, 1.0).astype(np.float32)
        observations.append(obs)
        labels.append(label)
        use_label = driver is None or rng.random() < beta
        obs, r, terminated, truncated, info = env.step(label if use_label else driver(obs))
        rewards.append(r)
        if terminated or truncated or (stall and _stalled(observations, obs, *stall)):
            break
    returns = np.zeros(len(rewards), np.float32)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running
        returns[t] = running
    return Episode(np.array(observations, np.float32), np.array(labels), returns, float(sum(rewards)),
                   bool(info["success"]))


def _stalled(history: list[np.ndarray], obs: np.ndarray, steps: int, metres: float) -> bool:
    moved = obs[HAND_POSITION] - history[-steps][HAND_POSITION] if len(history) >= steps else np.inf
    return float(np.linalg.norm(moved)) < metres


def actor_success(env: TeacherObservation, actor: Actor, seeds: range) -> float:
    """Share of the episodes with these seeds that ``actor`` alone grasps and lifts."""
    wins = 0
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, info = env.step(actor(obs))
            if terminated or truncated:
                break
        wins += bool(info["success"])
    return wins / max(len(seeds), 1)


def mean_actor(model: PPO, normaliser: ObsNormaliser) -> Actor:
    """The actor's deterministic action, exactly as ``PPOTeacher.act`` computes it."""
    return lambda obs: model.predict(normaliser(obs), deterministic=True)[0]


def dagger(model: PPO, env_config: EnvConfig, config: DaggerConfig, *, gamma: float,
           log: RoundLog) -> tuple[ObsNormaliser, dict]:
    """DAgger on ``model``'s actor, then its critic on the last round's returns; ``log`` gets one summary
    per round (env steps so far, wall s, episodes, mean return, success rate, mean length). Returns the
    normaliser (fitted on the expert's round, then frozen) and a summary."""
    t0, steps, seed = time.perf_counter(), 0, 1_000_000 + config.seed * 10_000
    env, expert = TeacherObservation(GraspEnv(env_config)), ReactiveExpert()
    data: list[Episode] = []
    normaliser = None
    try:
        for rnd in tqdm(range(config.rounds + 1), desc="DAgger", unit="round"):
            if rnd == 0:
                batch = [labelled_episode(env, expert, seed + i, gamma)
                         for i in range(config.expert_episodes)]
                stage = "expert"
            else:
                driver, beta = mean_actor(model, normaliser), config.beta * 0.5 ** (rnd - 1)
                stall = (config.stall_steps, config.stall_m)
                batch = [labelled_episode(env, expert, seed + i, gamma, driver, beta, stall)
                         for i in range(config.episodes)]
                stage = f"dagger{rnd}_beta{beta:g}"
            seed += len(batch)
            steps += sum(len(e.obs) for e in batch)
            if normaliser is None:
                normaliser = ObsNormaliser.fit(np.concatenate([e.obs for e in batch]), masked=ARM_VELOCITIES)
            data += batch
            obs, labels = _stack(data, "obs"), _stack(data, "labels")
            actor_mse = fit_head(model, "actor", normaliser(obs), labels, config)
            held_out = range(EVAL_SEED, EVAL_SEED + config.eval_episodes)
            log({"stage": stage, "env_steps": steps,
                 "wall_s": time.perf_counter() - t0, "episodes": len(batch),
                 "mean_return": float(np.mean([e.total for e in batch])),
                 "success_rate": float(np.mean([e.success for e in batch])),
                 "mean_length": float(np.mean([len(e.obs) for e in batch])), "actor_mse": actor_mse,
                 "eval_success": actor_success(env, mean_actor(model, normaliser), held_out)})
        value_mse = fit_head(model, "critic", normaliser(_stack(batch, "obs")), _stack(batch, "returns"),
                             config)
    finally:
        env.close()
    last_success = float(np.mean([e.success for e in batch]))
    return normaliser, {"env_steps": steps, "samples": len(obs), "rounds": config.rounds,
                        "episodes_per_round": config.episodes, "last_round_success": last_success,
                        "actor_mse": actor_mse, "value_mse": value_mse,
                        "seconds": round(time.perf_counter() - t0, 1)}


def _stack(episodes: list[Episode], key: str) -> np.ndarray:
    return np.concatenate([getattr(e, key) for e in episodes])


def fit_head(model: PPO, head: str, x: np.ndarray, y: np.ndarray, config: DaggerConfig) -> float:
    """Regress the actor's mean (``head="actor"``) or the critic's value (``"critic"``) onto ``y`` by MSE,
    in place; the log std is left alone. Returns the last epoch's mean loss."""
    policy = model.policy
    if head == "actor":
        params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
        forward = lambda f: policy.action_net(policy.mlp_extractor.forward_actor(f))  # noqa: E731
    elif head == "critic":
        params = [*policy.mlp_extractor.value_net.parameters(), *policy.value_net.parameters()]
        forward = lambda f: policy.value_net(policy.mlp_extractor.forward_critic(f)).squeeze(-1)  # noqa: E731
    else:
        raise ValueError(f"head must be 'actor' or 'critic', got {head!r}")
    optim = torch.optim.Adam(params, lr=config.lr)
    gen = torch.Generator().manual_seed(config.seed)
    x_t, y_t = torch.as_tensor(x), torch.as_tensor(y)
    n_batches = -(-len(x_t) // config.batch_size)
    # Cosine decay to 0: the last epochs settle the fit instead of leaving Adam's step-size noise in it,
    # which near the grasp point is the size of the mistakes that stall the learner.
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optim, config.epochs * n_batches)
    loss_sum = 0.0
    for _ in range(config.epochs):
        loss_sum = 0.0
        for idx in torch.randperm(len(x_t), generator=gen).split(config.batch_size):
            loss = torch.mean((forward(policy.extract_features(x_t[idx])) - y_t[idx]) ** 2)
            optim.zero_grad()
            loss.backward()
            optim.step()
            schedule.step()
            loss_sum += loss.item() / n_batches
    return loss_sum
