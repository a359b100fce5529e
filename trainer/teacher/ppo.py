"""PPO teacher on the env's 40-d privileged observation (paper III-A), with stable-baselines3.

Why stable-baselines3 (over rsl_rl / skrl): maintained, CPU-first (rsl_rl assumes batched GPU envs),
ships ``VecNormalize`` and ``SubprocVecEnv`` for a gymnasium env like ours, and saves/loads cleanly.

Checkpoint = a folder: ``model.zip`` (SB3 PPO weights), ``normaliser.npz`` (observation statistics, see
``trainer.teacher.normaliser``), ``teacher.json`` (config, env steps, wall time). ``load(path)`` gives the
``Policy`` that ``make_policy("ppo:PATH")`` hands to collect and evaluate.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from hil_sim.objects import SEEN
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.teacher.normaliser import ObsNormaliser, SharedVecNormalize
from trainer.teacher.observation import TEACHER_OBS_DIM, TeacherObservation, teacher_observation
from trainer.teacher.progress import Progress, TqdmSteps, append_row
from trainer.teacher.warmstart import DaggerConfig, dagger

VEC_KINDS = ("subproc", "dummy")


class TeacherError(ValueError):
    """A bad teacher config or an unreadable checkpoint."""


@dataclass(frozen=True)
class TeacherConfig:
    objects: tuple[str, ...] = SEEN
    """Object kinds to train on (the CLI resolves a comma list of groups and kinds)."""
    steps: int = 200_000
    """PPO env steps of this run, after the warm start's (added to a resumed run's steps)."""
    budget_minutes: float = 30.0
    """Wall-clock budget of this run, warm start included; training stops at the first step past it."""
    n_envs: int = 2
    """Parallel envs (one per core)."""
    vec: str = "dummy"
    """dummy (envs stepped in this process: measured 328 vs 275 env steps/s for subproc on 2 loaded
    cores, the state-only step is too cheap to pay for the pipes) | subproc (one process per env)."""
    seed: int = 0
    dagger_expert_episodes: int = DaggerConfig.expert_episodes
    """Episodes of DAgger's first round, driven by the reactive scripted expert."""
    dagger_episodes: int = DaggerConfig.episodes
    """Episodes per learner round of DAgger; 0 skips DAgger and trains PPO from scratch."""
    dagger_rounds: int = DaggerConfig.rounds
    """DAgger rounds driven by the learner after the expert's round (0: plain behaviour cloning)."""
    dagger_epochs: int = DaggerConfig.epochs
    """Passes over the aggregated DAgger data after each round."""
    n_steps: int = 512
    """Env steps per env per PPO update."""
    batch_size: int = 256
    n_epochs: int = 5
    learning_rate: float = 3e-5
    """Low: PPO fine-tunes a policy that already grasps (3e-4, SB3's default, for a run from scratch)."""
    gamma: float = 0.99
    clip_range: float = 0.1
    log_std_init: float = -2.5
    """Initial log std of the Gaussian actor: small after the warm start so exploration does not wreck it
    (0 from scratch)."""
    net: tuple[int, ...] = (256, 256)
    """actor/critic layers"""
    max_steps: int = 150
    """Episode length in control steps (the env's limit; shorter only for quick tests)."""
    checkpoint_every: int = 10_000
    """Env steps between checkpoints."""

    def __post_init__(self) -> None:
        if self.vec not in VEC_KINDS:
            raise TeacherError(f"vec must be one of {VEC_KINDS}, got {self.vec!r}")
        if self.steps < 1 or self.n_envs < 1 or self.budget_minutes <= 0:
            raise TeacherError(f"steps, n_envs and budget_minutes must be positive, got {self.steps}, "
                               f"{self.n_envs}, {self.budget_minutes}")
        if (self.n_steps * self.n_envs) % self.batch_size:
            raise TeacherError(f"n_steps * n_envs ({self.n_steps * self.n_envs}) must be a multiple of "
                               f"batch_size ({self.batch_size})")

    def dagger(self) -> DaggerConfig:
        return DaggerConfig(rounds=self.dagger_rounds, expert_episodes=self.dagger_expert_episodes,
                            episodes=self.dagger_episodes, epochs=self.dagger_epochs, seed=self.seed)

    def env_config(self, **overrides) -> EnvConfig:
        """State-only env: PPO never looks at depth, rendering it would cost most of the step time."""
        return EnvConfig(objects=self.objects, render_depth=False, max_steps=self.max_steps, **overrides)


def _make_env(config: EnvConfig) -> Monitor:
    torch.set_num_threads(1)
    return Monitor(TeacherObservation(GraspEnv(config)), info_keywords=("success",))


def make_vec_env(config: TeacherConfig, env_config: EnvConfig | None = None) -> SharedVecNormalize:
    """``n_envs`` Monitor-wrapped envs, vectorised, inside the observation normaliser (rewards raw: the
    critic is warm-started on raw returns)."""
    fns = [partial(_make_env, env_config or config.env_config())] * config.n_envs
    venv: VecEnv = SubprocVecEnv(fns) if config.vec == "subproc" and config.n_envs > 1 else DummyVecEnv(fns)
    venv.seed(config.seed)
    return SharedVecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=10.0, gamma=config.gamma)


def new_model(config: TeacherConfig, venv: SharedVecNormalize) -> PPO:
    return PPO("MlpPolicy", venv, n_steps=config.n_steps, batch_size=config.batch_size,
               n_epochs=config.n_epochs, learning_rate=config.learning_rate, gamma=config.gamma,
               clip_range=config.clip_range, seed=config.seed, device="cpu", verbose=0,
               policy_kwargs={"net_arch": list(config.net), "log_std_init": config.log_std_init})


def save(out: Path, model: PPO, venv: SharedVecNormalize, config: TeacherConfig, meta: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    ObsNormaliser.of(venv).save(out / "normaliser.npz")
    info = {"config": asdict(config), "env_steps": int(model.num_timesteps), **meta}
    (out / "teacher.json").write_text(json.dumps(info, indent=2))


def train(config: TeacherConfig, out: Path, *, resume: bool = False) -> dict:
    """DAgger warm start (unless resuming or disabled; its policy also saved in ``out/warm_start``), then
    ``config.steps`` PPO env steps or the wall-clock budget, whichever ends first (the warm start's time
    counts against the budget, and its env steps are in the step count); returns ``out/teacher.json``."""
    t0 = time.perf_counter()
    torch.set_num_threads(1)
    venv = make_vec_env(config)
    # Statistics frozen after the warm start: the cloned actor must keep seeing the inputs it was fitted on.
    venv.training = not config.dagger_episodes
    meta: dict = {"wall_s": 0.0}
    out.mkdir(parents=True, exist_ok=True)
    if resume:
        model, meta = _resume(out, venv)
    else:
        (out / "progress.csv").unlink(missing_ok=True)
        model = new_model(config, venv)
        if config.dagger_episodes:
            meta.update(_warm_start(config, model, venv, out))
            wall = round(time.perf_counter() - t0, 1)
            save(out / "warm_start", model, venv, config, {**meta, "wall_s": wall})
    offset = float(meta.get("wall_s", 0.0))

    def snapshot() -> None:
        save(out, model, venv, config, {**meta, "wall_s": round(offset + time.perf_counter() - t0, 1)})

    spent = time.perf_counter() - t0
    progress = Progress(out / "progress.csv", config.budget_minutes * 60 - spent, config.checkpoint_every,
                        snapshot, wall_offset_s=offset + spent)
    try:
        callbacks = [progress, TqdmSteps(config.steps)]
        model.learn(config.steps, callback=callbacks, reset_num_timesteps=False)
    finally:
        venv.close()
    return json.loads((out / "teacher.json").read_text())


def _resume(out: Path, venv: SharedVecNormalize) -> tuple[PPO, dict]:
    if not (out / "model.zip").exists():
        raise TeacherError(f"--resume: no checkpoint in {out}")
    ObsNormaliser.load(out / "normaliser.npz").install(venv)
    model = PPO.load(out / "model.zip", env=venv, device="cpu")
    meta = json.loads((out / "teacher.json").read_text())
    return model, {k: v for k, v in meta.items() if k not in ("config", "env_steps")}


def _warm_start(config: TeacherConfig, model: PPO, venv: SharedVecNormalize, out: Path) -> dict:
    """DAgger, its rows in progress.csv; PPO's step count and normaliser carry on from it."""
    normaliser, summary = dagger(model, config.env_config(), config.dagger(), gamma=config.gamma,
                                 log=lambda row: append_row(out / "progress.csv", row))
    normaliser.install(venv)
    model.num_timesteps = summary["env_steps"]
    return {"warm_start": summary}


class PPOTeacher:
    """The ``Policy`` of a trained checkpoint: the teacher's observation of the privileged state, normalised
    exactly as in training, then the actor's mean action (deterministic)."""

    def __init__(self, model: PPO, normaliser: ObsNormaliser) -> None:
        self.model, self.normaliser = model, normaliser

    def reset(self, env_info: dict) -> None:
        """Memoryless policy: nothing to reset."""

    def act(self, obs) -> np.ndarray:
        priv = np.asarray(getattr(obs, "privileged", obs), np.float32)
        action, _ = self.model.predict(self.normaliser(teacher_observation(priv)), deterministic=True)
        return np.asarray(action, np.float32)


def load(path: str | Path) -> PPOTeacher:
    """A checkpoint folder written by ``train`` (or its ``model.zip``)."""
    folder = Path(path)
    folder = folder.parent if folder.suffix == ".zip" else folder
    if not (folder / "model.zip").is_file():
        raise TeacherError(f"no PPO teacher checkpoint at {path} (expected {folder / 'model.zip'})")
    torch.set_num_threads(1)
    model = PPO.load(folder / "model.zip", device="cpu")
    if model.observation_space.shape != (TEACHER_OBS_DIM,):
        raise TeacherError(f"{folder} observes {model.observation_space.shape} entries, this code's teacher "
                           f"({TEACHER_OBS_DIM},): made before the yaw and category features, retrain it")
    return PPOTeacher(model, ObsNormaliser.load(folder / "normaliser.npz"))
