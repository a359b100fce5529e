"""Warm start of the PPO teacher from the scripted expert: behaviour cloning of the actor, and a fit of
the critic to the demos' discounted returns so the first PPO updates do not undo the cloning.

On 2 shared CPU cores PPO from a random Gaussian policy barely finds a grasp in a session's budget; the
cloned actor starts where the scripted expert is and PPO then improves it on the eq. 2-7 reward.
"""

from __future__ import annotations

import multiprocessing as mp
from dataclasses import dataclass
from functools import partial

import numpy as np
import torch
from stable_baselines3 import PPO
from tqdm import tqdm

from trainer.sim.env import EnvConfig, GraspEnv
from trainer.teacher.normaliser import ObsNormaliser
from trainer.teacher.scripted import ScriptedExpert


@dataclass(frozen=True)
class Demos:
    obs: np.ndarray
    """float32 [N, 40] privileged observations."""
    actions: np.ndarray
    """float32 [N, 8] scripted actions, clipped to the action box."""
    returns: np.ndarray
    """float32 [N] discounted return from each step on."""
    episodes: int
    successes: int


_CACHE: dict = {}


def _episode(config: EnvConfig, gamma: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    if _CACHE.get("config") != config:
        _CACHE.update(config=config, env=GraspEnv(config), expert=ScriptedExpert())
    env, expert = _CACHE["env"], _CACHE["expert"]
    obs, info = env.reset(seed=seed)
    expert.reset(info)
    observations, actions, rewards = [], [], []
    while True:
        action = np.clip(expert.act(obs), -1.0, 1.0)
        observations.append(obs)
        actions.append(action)
        obs, r, terminated, truncated, info = env.step(action)
        rewards.append(r)
        if terminated or truncated:
            break
    returns = np.zeros(len(rewards), np.float32)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running
        returns[t] = running
    return np.array(observations, np.float32), np.array(actions, np.float32), returns, bool(info["success"])


def scripted_demos(config: EnvConfig, episodes: int, *, seed: int, gamma: float, workers: int = 1) -> Demos:
    """Run the scripted expert for ``episodes`` (seeds seed, seed+1, ...); keep the successful ones."""
    work = partial(_episode, config, gamma)
    seeds = range(seed, seed + episodes)
    bar = partial(tqdm, total=episodes, desc="scripted demos", unit="ep")
    if workers <= 1:
        results = list(bar(map(work, seeds)))
    else:
        with mp.get_context("spawn").Pool(workers) as pool:
            results = list(bar(pool.imap(work, seeds)))
    kept = [r for r in results if r[3]] or results
    return Demos(*(np.concatenate([r[i] for r in kept]) for i in range(3)), episodes,
                 sum(r[3] for r in results))


def clone(model: PPO, demos: Demos, normaliser: ObsNormaliser, *, epochs: int, batch_size: int = 256,
          lr: float = 1e-3, seed: int = 0) -> dict[str, float]:
    """Fit the actor's mean to the demo actions (MSE) and the critic to their returns, in place."""
    policy = model.policy
    obs = torch.as_tensor(normaliser(demos.obs))
    act = torch.as_tensor(demos.actions)
    ret = torch.as_tensor(demos.returns)
    params = [p for name, p in policy.named_parameters() if name != "log_std"]
    optim = torch.optim.Adam(params, lr=lr)
    gen = torch.Generator().manual_seed(seed)
    losses = {"bc_actor_mse": 0.0, "bc_value_mse": 0.0}
    for _ in tqdm(range(epochs), desc="behaviour cloning", unit="epoch"):
        for idx in torch.randperm(len(obs), generator=gen).split(batch_size):
            latent_pi, latent_vf = policy.mlp_extractor(policy.extract_features(obs[idx]))
            actor = torch.mean((policy.action_net(latent_pi) - act[idx]) ** 2)
            value = torch.mean((policy.value_net(latent_vf).squeeze(-1) - ret[idx]) ** 2)
            optim.zero_grad()
            (actor + 0.1 * value).backward()
            optim.step()
            losses = {"bc_actor_mse": actor.item(), "bc_value_mse": value.item()}
    return losses
