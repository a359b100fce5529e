"""Observation normalisation of the PPO teacher: one function used in training and at collection time.

Training wraps the vectorised env in ``SharedVecNormalize`` (stable-baselines3's running statistics with
its normalising step replaced by ``normalise``); the checkpoint stores the statistics as plain arrays and
``ObsNormaliser`` applies the same ``normalise`` to single observations when collecting or evaluating.

``masked`` observation entries are set to 0 after normalising: the teacher does not see the arm's joint
velocities (``ARM_VELOCITIES``). A policy cloned from demos with them learnt to repeat its previous action
(the velocity gives it away) instead of reading the state, and stalled wherever it came to rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecNormalize

ARM_VELOCITIES = tuple(range(9, 16))
"""Observation entries of the 7 arm joint velocities (layout in ``trainer.sim.env``)."""


class NormaliserError(ValueError):
    """Normaliser statistics of the wrong shape or unreadable."""


def normalise(obs: np.ndarray, mean: np.ndarray, var: np.ndarray, epsilon: float, clip: float,
              masked: tuple[int, ...] = ()) -> np.ndarray:
    """(obs - mean) / sqrt(var + eps), clipped to +-clip, entries ``masked`` set to 0, in float32."""
    out = np.clip((np.asarray(obs, np.float64) - mean) / np.sqrt(var + epsilon), -clip, clip)
    out[..., list(masked)] = 0.0
    return out.astype(np.float32)


class SharedVecNormalize(VecNormalize):
    masked: tuple[int, ...] = ARM_VELOCITIES

    def _normalize_obs(self, obs: np.ndarray, obs_rms: RunningMeanStd) -> np.ndarray:
        return normalise(obs, obs_rms.mean, obs_rms.var, self.epsilon, self.clip_obs, self.masked)


@dataclass(frozen=True)
class ObsNormaliser:
    mean: np.ndarray
    var: np.ndarray
    count: float
    epsilon: float
    clip: float
    masked: tuple[int, ...] = ()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return normalise(obs, self.mean, self.var, self.epsilon, self.clip, self.masked)

    @classmethod
    def of(cls, venv: SharedVecNormalize) -> ObsNormaliser:
        rms = venv.obs_rms
        return cls(rms.mean.copy(), rms.var.copy(), float(rms.count), float(venv.epsilon),
                   float(venv.clip_obs), tuple(venv.masked))

    def install(self, venv: VecNormalize) -> None:
        """Put these statistics into a training wrapper (resume, or after the warm start)."""
        if venv.obs_rms.mean.shape != self.mean.shape:
            raise NormaliserError(f"normaliser has {self.mean.shape} statistics, env observes "
                                  f"{venv.obs_rms.mean.shape}")
        rms = venv.obs_rms
        rms.mean, rms.var, rms.count = self.mean.copy(), self.var.copy(), self.count
        venv.epsilon, venv.clip_obs, venv.masked = self.epsilon, self.clip, self.masked

    @classmethod
    def fit(cls, obs: np.ndarray, epsilon: float = 1e-8, clip: float = 10.0,
            masked: tuple[int, ...] = ()) -> ObsNormaliser:
        """Statistics of a batch of observations [N, D] (the warm start's demos)."""
        return cls(obs.mean(0), obs.var(0), float(len(obs)), epsilon, clip, masked)

    def save(self, path: Path) -> None:
        np.savez(path, mean=self.mean, var=self.var, count=self.count, epsilon=self.epsilon, clip=self.clip,
                 masked=np.array(self.masked, np.int64))

    @classmethod
    def load(cls, path: Path) -> ObsNormaliser:
        try:
            with np.load(path) as z:
                masked = tuple(int(i) for i in z["masked"]) if "masked" in z else ()
                return cls(z["mean"], z["var"], float(z["count"]), float(z["epsilon"]), float(z["clip"]),
                           masked)
        except (OSError, KeyError) as exc:
            raise NormaliserError(f"cannot read normaliser statistics {path}: {exc}") from None
