"""The student's action head with perfect perception (docs/student.md@b8caf57 "The oracle"): the depth encoder
replaced by the episode's true object facts (table position, cos/sin of twice its yaw, kind one-hot), the same
1-D U-Net head, state MLP, eq. 10 loss, EMA and DDIM sampling, trained on the same demos; then run closed loop
in the simulated world without rendering depth (seen kinds, seeds 10000.., randomised episodes). If it too
misses, the head, not perception, is what fails. ``--hand`` adds the hand's pose by forward kinematics of the
joint state (``trainer.student.model.hand_pose``) and the object's offset from the hand. ``--facts-noise-cm``
says how precisely perception must place the object: the oracle then gets the object's position off by a
random error, one per episode.

python research/student_v1/oracle.py fit --out runs/student/oracle/facts [--hand] [--steps 8000]
python research/student_v1/oracle.py evaluate runs/student/oracle/facts/oracle.pt --episodes 60 [--exec 8] \
    [--facts-noise-cm 1.5]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from hil_sim.objects import GROUPS
from trainer.dataset import DemoStore
from trainer.diffusion import training_target
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, run_episode
from trainer.student.config import StudentConfig
from trainer.student.ddim import ddim_plan, ddim_update, training_scheduler
from trainer.student.model import StudentPolicy, hand_pose
from trainer.student.train import ema_update

KINDS = GROUPS["seen"]


def object_facts(episode: dict, kind: str) -> np.ndarray:
    """What the oracle knows of the episode's object: [x, y, cos 2 yaw, sin 2 yaw, kind one-hot]."""
    yaw = episode["object_yaw"]
    kinds = [float(kind == k) for k in KINDS]
    return np.array([*episode["object_xy"], np.cos(2 * yaw), np.sin(2 * yaw), *kinds], dtype=np.float32)


class Oracle(nn.Module):
    """A ``StudentPolicy`` whose depth features come from the object facts (and the hand) instead."""

    def __init__(self, config: StudentConfig, hand: bool) -> None:
        super().__init__()
        self.hand = hand
        self.student = StudentPolicy(config)
        inputs = 4 + len(KINDS) + (11 if hand else 0)
        self.register_buffer("mean", torch.zeros(inputs))
        self.register_buffer("std", torch.ones(inputs))
        self.facts_mlp = nn.Sequential(nn.Linear(inputs, 128), nn.ReLU(),
                                       nn.Linear(128, self.student.encoder.out_features))

    def inputs(self, facts: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        if not self.hand:
            return facts
        pose = hand_pose(state)
        return torch.cat([facts, pose, facts[:, :2] - pose[:, :2]], dim=-1)

    def obs(self, facts: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        x = (self.inputs(facts, state) - self.mean) / self.std
        return self.student.fuse(self.facts_mlp(x), state)


def demos(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per step: state, action, the episode's object facts, and the episode's end index."""
    store = DemoStore.open(path)
    n, lengths = int(store.episode_ends[-1]), store.episode_lengths
    episodes = [json.loads(str(r)) for r in store.root["meta/randomisation"][:]]
    facts = np.stack([object_facts(e, k) for e, k in zip(episodes, store.kinds, strict=True)])
    state = np.asarray(store.root["data/state"][:n], np.float32)
    action = np.asarray(store.root["data/action"][:n], np.float32)
    return state, action, np.repeat(facts, lengths, axis=0), np.repeat(store.episode_ends, lengths)


def fit(args: argparse.Namespace) -> None:
    torch.set_num_threads(1)
    config = StudentConfig(width=8, head_dims=(32, 64, 128))  # the encoder is unused
    state, action, facts, ends = demos(args.demos)
    net = Oracle(config, args.hand)
    net.student.fit_normalisers(state, action)
    with torch.no_grad():
        x = net.inputs(torch.from_numpy(facts), torch.from_numpy(state))
    net.mean.copy_(x.mean(0))
    net.std.copy_(x.std(0).clamp_min(1e-6))
    params = [p for name, p in net.named_parameters() if not name.startswith("student.encoder")]
    optim = torch.optim.AdamW(params, lr=args.lr, weight_decay=1e-6)
    scheduler = training_scheduler(config.train_timesteps, config.prediction)
    ema = {k: v.clone() for k, v in net.state_dict().items()}
    rng, gen = np.random.default_rng(0), torch.Generator().manual_seed(0)
    started = time.perf_counter()
    for step in range(args.steps):
        for group in optim.param_groups:  # warm-up then cosine, as the student's fit
            group["lr"] = args.lr * min(1.0, (step + 1) / 500) * 0.5 * (1 + np.cos(np.pi * step / args.steps))
        i = rng.integers(0, len(action), args.batch)
        chunk = np.minimum(i[:, None] + np.arange(config.action_horizon), ends[i, None] - 1)
        clean = net.student.action_norm.normalise(torch.from_numpy(action[chunk]))
        noise = torch.randn(clean.shape, generator=gen)
        k = torch.randint(0, config.train_timesteps, (args.batch,), generator=gen)
        obs = net.obs(torch.from_numpy(facts[i]), torch.from_numpy(state[i]))
        loss = nn.functional.mse_loss(net.student(scheduler.add_noise(clean, noise, k), k, obs),
                                      training_target(scheduler, clean, noise, k))
        optim.zero_grad()
        loss.backward()
        optim.step()
        ema_update(ema, net, step, 0.9999)
        if step % 1000 == 0:
            print(f"step {step} loss {loss.item():.4f} {time.perf_counter() - started:.0f} s", flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    torch.save({"config": config.to_json(), "hand": args.hand, "ema": ema}, Path(args.out) / "oracle.pt")
    print(f"{args.steps} steps in {time.perf_counter() - started:.0f} s -> {args.out}/oracle.pt")


class OraclePolicy:
    """The trained oracle as a ``trainer.policies`` policy: K DDIM steps, ``exec_horizon`` actions a chunk."""

    def __init__(self, path: str, ddim_steps: int, exec_horizon: int, facts_noise_cm: float = 0.0) -> None:
        saved = torch.load(path, weights_only=True)
        self.config = StudentConfig.from_json(saved["config"])
        self.net = Oracle(self.config, saved["hand"]).eval()
        self.net.load_state_dict(saved["ema"])
        self.plan, self.exec_horizon = ddim_plan(self.config.train_timesteps, ddim_steps), exec_horizon
        self.generator = torch.Generator().manual_seed(0)
        self.facts_noise, self.rng = facts_noise_cm / 100, np.random.default_rng(0)
        self.facts, self.queue = None, []

    def reset(self, env_info: dict) -> None:
        facts = object_facts(env_info["episode"], env_info["kind"])
        facts[:2] += self.rng.normal(0.0, self.facts_noise, 2)  # one error per episode, like a student's
        self.facts = torch.from_numpy(facts)[None]
        self.queue = []

    @torch.no_grad()
    def act(self, obs) -> np.ndarray:
        if not self.queue:
            cond = self.net.obs(self.facts, torch.from_numpy(obs.state)[None])
            x = torch.randn((1, self.config.action_horizon, self.config.action_dim), generator=self.generator)
            for step in self.plan:
                x = ddim_update(x, self.net.student(x, torch.tensor([step.timestep]), cond), step,
                                self.config.prediction)
            chunk = self.net.student.action_norm.unnormalise(x)[0].numpy()
            chunk[:, :7] = np.clip(chunk[:, :7], -1.0, 1.0)
            chunk[:, 7] = np.where(chunk[:, 7] > 0, 1.0, -1.0)
            self.queue = list(chunk[: self.exec_horizon])
        return self.queue.pop(0)


def evaluate(args: argparse.Namespace) -> None:
    torch.set_num_threads(1)
    env = GraspEnv(EnvConfig(objects=KINDS, render_depth=False))
    policy = OraclePolicy(args.checkpoint, args.ddim_steps, args.exec, args.facts_noise_cm)
    runs = [run_episode(env, policy, Job(10_000 + i, KINDS[i % len(KINDS)])) for i in range(args.episodes)]
    wins = np.array([r.success for r in runs])
    closes = np.array([r.closed_at[1] for r in runs if r.closed_at is not None]) * 100
    aside = np.median(np.hypot(closes[:, 0], closes[:, 1]))
    print(f"{args.checkpoint} (execute {args.exec} of each chunk, object position off by N(0, "
          f"{args.facts_noise_cm} cm) per axis): success {wins.mean():.3f} "
          f"({wins.sum()}/{len(wins)}); object - hand at the first close, mean {closes.mean(0).round(2)} "
          f"std {closes.std(0).round(2)} cm, horizontal median {aside:.2f} cm")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="train the oracle on a demo store")
    f.add_argument("--demos", default="runs/sim/demos_seen.zarr")
    f.add_argument("--out", required=True)
    f.add_argument("--hand", action="store_true", help="also the hand pose and the object's offset from it")
    f.add_argument("--steps", type=int, default=8000)
    f.add_argument("--batch", type=int, default=64)
    f.add_argument("--lr", type=float, default=3e-4)
    e = sub.add_parser("evaluate", help="closed-loop success in the simulated world")
    e.add_argument("checkpoint")
    e.add_argument("--episodes", type=int, default=60)
    e.add_argument("--ddim-steps", type=int, default=4)
    e.add_argument("--exec", type=int, default=8, help="actions executed from each chunk")
    e.add_argument("--facts-noise-cm", type=float, default=0.0,
                   help="std of an error added to the object's table x and y, drawn once per episode")
    args = p.parse_args()
    fit(args) if args.command == "fit" else evaluate(args)


if __name__ == "__main__":
    main()
