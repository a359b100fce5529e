"""What the PPO teacher observes: the env's 40-d privileged observation, re-encoded where an MLP reads it
poorly, nothing added that the 40 numbers do not hold.

- The hand's yaw relative to the object. The expert turns the fingers across the object's narrow axis,
  whichever of the two directions is nearer (``ScriptedExpert._grasp_yaw``): a function of the yaw
  difference modulo pi, which a cloned actor learned badly from two raw quaternions (each with its sign
  ambiguity). ``sin 2e, cos 2e`` of the difference ``e`` are smooth and carry exactly that modulus.
- The category as a one-hot (12 built-ins, then one slot for every user object) beside the env's
  log(category id). Grasp height and closing axis differ per kind; from the one scalar the actor grasped
  79 % of seen-kind episodes, with the one-hot 96 % (docs/teacher.md).

``teacher_observation`` is the one function that makes them, in training (``TeacherObservation``, the env
wrapper) and at use (``PPOTeacher.act``).
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from hil_sim.objects import BUILTIN
from trainer.sim.env import HAND_QUAT, LOG_CATEGORY, OBJECT_QUAT, OBS_DIM

CATEGORIES = len(BUILTIN) + 1
"""One-hot width: the built-in category ids 1..12, then one slot for user objects (ids 13+)."""
TEACHER_OBS_DIM = OBS_DIM + 2 + CATEGORIES


def axis_yaw(quat: np.ndarray, column: int) -> float:
    """Heading in the table plane of axis ``column`` (0 x, 1 y) of the frame ``quat`` (w, x, y, z)."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    axis = mat.reshape(3, 3)[:, column]
    return float(np.arctan2(axis[1], axis[0]))


def teacher_observation(obs: np.ndarray) -> np.ndarray:
    """[40] env observation -> [55]: it, sin 2e and cos 2e (e = object x-axis yaw - finger closing-axis, i.e.
    hand y-axis, yaw), then the category one-hot."""
    obs = np.asarray(obs, np.float32)
    if obs.shape != (OBS_DIM,):
        raise ValueError(f"teacher_observation: expected the env's {OBS_DIM}-d observation, got {obs.shape}")
    e = axis_yaw(obs[OBJECT_QUAT], 0) - axis_yaw(obs[HAND_QUAT], 1)
    category = np.zeros(CATEGORIES)
    category[min(max(int(round(np.exp(obs[LOG_CATEGORY]))), 1), CATEGORIES) - 1] = 1.0
    return np.concatenate([obs, [np.sin(2 * e), np.cos(2 * e)], category]).astype(np.float32)


class TeacherObservation(gym.ObservationWrapper):
    """A ``GraspEnv`` seen through ``teacher_observation``."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (TEACHER_OBS_DIM,), np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return teacher_observation(observation)
