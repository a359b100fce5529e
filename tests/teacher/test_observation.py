"""The teacher's observation: the yaw features (what the expert's grasp turns on, the yaw difference modulo
pi, smooth) and the category one-hot."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hil_sim.objects import KINDS
from trainer.sim.env import OBS_DIM, EnvConfig, GraspEnv
from trainer.teacher.observation import CATEGORIES, TEACHER_OBS_DIM, TeacherObservation, teacher_observation
from trainer.teacher.scripted import _top_down


def _obs(object_yaw: float, closing_yaw: float) -> np.ndarray:
    obs = np.zeros(OBS_DIM, np.float32)
    hand = np.zeros(4)
    mujoco.mju_mat2Quat(hand, _top_down(closing_yaw).ravel())
    obs[21:25] = hand
    obs[28:32] = np.cos(object_yaw / 2), 0.0, 0.0, np.sin(object_yaw / 2)
    return obs


@pytest.mark.parametrize("object_yaw", [-2.5, 0.0, 0.7, 3.0])
def test_features_are_the_doubled_yaw_difference(object_yaw):
    aligned = teacher_observation(_obs(object_yaw, object_yaw))
    across = teacher_observation(_obs(object_yaw, object_yaw + np.pi / 2))
    yaw = slice(OBS_DIM, OBS_DIM + 2)
    np.testing.assert_allclose(aligned[yaw], [0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(across[yaw], [0.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(teacher_observation(_obs(object_yaw, object_yaw + 0.3))[yaw],
                               [np.sin(-0.6), np.cos(-0.6)], atol=1e-6)


def test_features_ignore_the_half_turn_and_the_quaternion_sign():
    obs = _obs(0.4, 1.9)
    turned = _obs(0.4 + np.pi, 1.9)
    flipped = obs.copy()
    flipped[28:32] *= -1
    flipped[21:25] *= -1
    for other in (turned, flipped):
        np.testing.assert_allclose(teacher_observation(other)[OBS_DIM:], teacher_observation(obs)[OBS_DIM:],
                                   atol=1e-6)


BANANA = KINDS["banana"].category_id


@pytest.mark.parametrize(("category_id", "slot"),
                         [(BANANA, BANANA - 1), (12, 11), (13, CATEGORIES - 1), (40, CATEGORIES - 1)])
def test_category_one_hot_with_one_slot_for_user_objects(category_id, slot):
    obs = _obs(0.0, 0.0)
    obs[35] = np.log(category_id)
    one_hot = teacher_observation(obs)[OBS_DIM + 2:]
    assert one_hot.shape == (CATEGORIES,) and one_hot.sum() == 1.0 and one_hot[slot] == 1.0


def test_wrapper_passes_the_env_observation_through():
    env = TeacherObservation(GraspEnv(EnvConfig(objects=("cube",), render_depth=False)))
    obs, _ = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape == (TEACHER_OBS_DIM,)
    np.testing.assert_array_equal(obs, teacher_observation(env.unwrapped.observation()))
    env.close()


def test_rejects_an_observation_of_another_width():
    with pytest.raises(ValueError, match="40-d"):
        teacher_observation(np.zeros(42, np.float32))
