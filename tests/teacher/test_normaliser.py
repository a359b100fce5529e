"""The observation normaliser is one function applied identically in training and at collection time."""

from __future__ import annotations

import numpy as np
import pytest

from trainer.policies import Observation, make_policy
from trainer.sim.env import OBS_DIM
from trainer.teacher.normaliser import ARM_VELOCITIES, NormaliserError, ObsNormaliser
from trainer.teacher.observation import TEACHER_OBS_DIM
from trainer.teacher.ppo import TeacherConfig, make_vec_env, new_model, save


def test_training_wrapper_and_saved_statistics_normalise_identically(tmp_path):
    config = TeacherConfig(objects=("cube",), n_envs=1, vec="dummy", n_steps=8, batch_size=8, max_steps=20)
    venv = make_vec_env(config)
    rng = np.random.default_rng(0)
    try:
        venv.reset()
        for _ in range(6):  # running statistics move with every step, so the check is not at the prior
            normalised, *_ = venv.step(rng.uniform(-1, 1, (1, 8)).astype(np.float32))
        raw = venv.get_original_obs()
        assert not np.allclose(normalised, raw)
        np.testing.assert_array_equal(ObsNormaliser.of(venv)(raw), normalised)
        model = new_model(config, venv)
        save(tmp_path, model, venv, config, {})
    finally:
        venv.close()
    teacher = make_policy(f"ppo:{tmp_path}")  # the collect/evaluate path
    np.testing.assert_array_equal(teacher.normaliser(raw[0]), normalised[0])
    expected, _ = model.predict(normalised[0], deterministic=True)
    acted = teacher.act(Observation(raw[0, :OBS_DIM], None, np.zeros(8, np.float32)))
    np.testing.assert_array_equal(acted, expected)


def test_install_rejects_statistics_of_another_width():
    config = TeacherConfig(objects=("cube",), n_envs=1, vec="dummy", n_steps=8, batch_size=8)
    venv = make_vec_env(config)
    try:
        with pytest.raises(NormaliserError, match="statistics"):
            ObsNormaliser.fit(np.zeros((4, 39), np.float32)).install(venv)
    finally:
        venv.close()


def test_fit_matches_batch_statistics_and_clips():
    obs = np.random.default_rng(1).normal(3.0, 2.0, (500, 40)).astype(np.float32)
    norm = ObsNormaliser.fit(obs, clip=1.5)
    out = norm(obs)
    assert out.dtype == np.float32 and np.abs(out).max() <= 1.5
    np.testing.assert_allclose(norm(obs[:1] * 0 + obs.mean(0)), 0.0, atol=1e-5)


def test_arm_velocities_are_masked_in_training_and_at_use(tmp_path):
    config = TeacherConfig(objects=("cube",), n_envs=1, vec="dummy", n_steps=8, batch_size=8, max_steps=20)
    venv = make_vec_env(config)
    try:
        venv.reset()
        moving, *_ = venv.step(np.ones((1, 8), np.float32))  # joints move: raw velocities are non-zero
        assert np.abs(venv.get_original_obs()[0, list(ARM_VELOCITIES)]).max() > 1e-3
        assert np.all(moving[0, list(ARM_VELOCITIES)] == 0.0)
        saved = ObsNormaliser.of(venv)
        saved.save(tmp_path / "n.npz")
    finally:
        venv.close()
    loaded = ObsNormaliser.load(tmp_path / "n.npz")
    assert loaded.masked == ARM_VELOCITIES == saved.masked
    assert np.all(loaded(np.full(TEACHER_OBS_DIM, 5.0, np.float32))[list(ARM_VELOCITIES)] == 0.0)
