"""Training bookkeeping for the PPO teacher: CSV learning curve (DAgger rounds, then one row per PPO
rollout), wall-clock budget, periodic checkpoints, and the learning-curve PNG (success rate and return vs
environment steps)."""

from __future__ import annotations

import csv
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

CSV_FIELDS = ("stage", "env_steps", "wall_s", "episodes", "mean_return", "success_rate", "mean_length",
              "steps_per_s", "eval_success")
"""``stage``: expert (its own episodes), daggerN (learner round N, deterministic) or ppo (training rollouts,
stochastic actions). ``steps_per_s`` is blank for the warm-start rows. ``eval_success``, the actor alone
(deterministic) on held-out episodes after the row's round, is filled for the warm-start rows only."""


def append_row(csv_path: Path, row: dict) -> None:
    """One learning-curve row (fields missing from ``row`` stay blank); writes the header first."""
    new = not csv_path.exists()
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, CSV_FIELDS, extrasaction="ignore")
        if new:
            writer.writeheader()
        writer.writerow({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()})


class Progress(BaseCallback):
    """After each rollout: one CSV row over the episodes that ended in it; stops at the wall-clock budget
    and calls ``save`` every ``checkpoint_every`` env steps and at the end."""

    def __init__(self, csv_path: Path, budget_s: float, checkpoint_every: int, save: Callable[[], None],
                 wall_offset_s: float = 0.0) -> None:
        super().__init__()
        self.csv_path, self.budget_s, self.every, self.save = csv_path, budget_s, checkpoint_every, save
        self.wall_offset_s = wall_offset_s
        self._episodes: list[dict] = []
        self._t0 = self._t_rollout = time.perf_counter()
        self._steps_rollout = 0
        self._last_save = 0

    @property
    def wall_s(self) -> float:
        return self.wall_offset_s + time.perf_counter() - self._t0

    def _on_training_start(self) -> None:
        self._last_save = self.num_timesteps

    def _on_rollout_start(self) -> None:
        self._t_rollout, self._steps_rollout = time.perf_counter(), self.num_timesteps

    def _on_step(self) -> bool:
        self._episodes += [info["episode"] for info in self.locals["infos"] if "episode" in info]
        return time.perf_counter() - self._t0 < self.budget_s

    def _on_rollout_end(self) -> None:
        eps, self._episodes = self._episodes, []
        rate = (self.num_timesteps - self._steps_rollout) / max(time.perf_counter() - self._t_rollout, 1e-9)
        mean = lambda k: float(np.mean([e[k] for e in eps])) if eps else float("nan")  # noqa: E731
        append_row(self.csv_path, {"stage": "ppo", "env_steps": self.num_timesteps, "wall_s": self.wall_s,
                                   "episodes": len(eps), "mean_return": mean("r"),
                                   "success_rate": mean("success"), "mean_length": mean("l"),
                                   "steps_per_s": rate})
        if self.num_timesteps - self._last_save >= self.every:
            self.save()
            self._last_save = self.num_timesteps

    def _on_training_end(self) -> None:
        self.save()


class TqdmSteps(BaseCallback):
    """Env-step progress bar (SB3's own needs ``rich``, which this project does not install)."""

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, desc="PPO", unit="step")
        self._start = self.num_timesteps

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self._start - self.bar.n)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def read_curve(csv_path: Path) -> dict[str, np.ndarray]:
    with csv_path.open() as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r.get(k) or "nan") for r in rows]) for k in CSV_FIELDS if k != "stage"}


def plot_curves(curves: dict[str, Path], png: Path, smooth: int = 5) -> None:
    """Success rate and mean return vs env steps, one line per labelled CSV (moving average of ``smooth``
    rollouts: each rollout ends only a handful of episodes), and the held-out success of the warm start's
    rounds as markers."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(11, 4))
    for label, path in curves.items():
        c = read_curve(path)
        for ax, key in ((ax_s, "success_rate"), (ax_r, "mean_return")):
            ax.plot(c["env_steps"], _moving_average(c[key], smooth), label=label)
        held_out = np.isfinite(c["eval_success"])
        if held_out.any():
            ax_s.plot(c["env_steps"][held_out], c["eval_success"][held_out], "o", ms=4,
                      label=f"{label}: actor alone, held-out")
    ax_s.set(xlabel="env steps", ylabel="success rate", ylim=(-0.02, 1.02))
    ax_r.set(xlabel="env steps", ylabel="mean episode return (eq. 2-7)")
    for ax in (ax_s, ax_r):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Trailing mean over the last ``n`` finite values (rollouts with no finished episode are NaN)."""
    out = np.full(len(x), np.nan)
    for i in range(len(x)):
        window = x[max(0, i - n + 1): i + 1]
        window = window[np.isfinite(window)]
        if len(window):
            out[i] = window.mean()
    return out
