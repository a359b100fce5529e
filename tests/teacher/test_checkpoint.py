"""A saved PPO teacher reloads (through ``make_policy("ppo:...")``) and reproduces its actions; resume
continues the env-step count; bad paths and configs fail with clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stable_baselines3 import PPO

from trainer.policies import Observation, make_policy
from trainer.sim.env import GraspEnv
from trainer.teacher.cli import main
from trainer.teacher.normaliser import ObsNormaliser
from trainer.teacher.observation import TEACHER_OBS_DIM, teacher_observation
from trainer.teacher.ppo import TeacherConfig, TeacherError, load
from trainer.teacher.progress import read_curve

from .conftest import TINY


def _observations(n: int) -> list[np.ndarray]:
    env = GraspEnv(TeacherConfig(objects=("cube", "can")).env_config())
    obs = [env.reset(seed=s)[0] for s in range(n)]
    env.close()
    return obs


def test_reload_reproduces_actions(tiny_teacher):
    model = PPO.load(tiny_teacher / "model.zip", device="cpu")
    normaliser = ObsNormaliser.load(tiny_teacher / "normaliser.npz")
    teacher = make_policy(f"ppo:{tiny_teacher}")
    again = load(tiny_teacher / "model.zip")
    for obs in _observations(3):
        expected, _ = model.predict(normaliser(teacher_observation(obs)), deterministic=True)
        got = teacher.act(Observation(obs, None, np.zeros(8, np.float32)))
        assert got.shape == (8,) and got.dtype == np.float32
        np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(again.act(obs), got)


def test_checkpoint_records_progress_and_curve(tiny_teacher):
    meta = json.loads((tiny_teacher / "teacher.json").read_text())
    warm = meta["warm_start"]
    assert warm["rounds"] == 1 and warm["samples"] == warm["env_steps"] > 0
    assert meta["env_steps"] >= warm["env_steps"] + 128  # PPO's step count carries on from DAgger's
    curve = read_curve(tiny_teacher / "progress.csv")
    stages = [line.split(",")[0] for line in (tiny_teacher / "progress.csv").read_text().splitlines()[1:]]
    assert stages[0] == "expert" and stages[1].startswith("dagger1") and set(stages[2:]) == {"ppo"}
    assert np.all(np.diff(curve["env_steps"]) > 0) and curve["env_steps"][1] == warm["env_steps"]
    assert (tiny_teacher / "learning_curve.png").stat().st_size > 1000


def test_resume_continues_step_count(tiny_teacher, tmp_path):
    out = tmp_path / "resumed"
    for name in ("model.zip", "normaliser.npz", "teacher.json", "progress.csv"):
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_bytes((tiny_teacher / name).read_bytes())
    before = json.loads((out / "teacher.json").read_text())["env_steps"]
    assert main(["fit", "--out", str(out), "--steps", "64", "--resume", *TINY]) == 0
    assert json.loads((out / "teacher.json").read_text())["env_steps"] == before + 64


def test_missing_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(TeacherError, match="no PPO teacher checkpoint"):
        load(tmp_path)
    assert main(["fit", "--out", str(tmp_path), "--resume", "--steps", "8", *TINY]) == 2


def test_checkpoint_of_another_observation_is_a_clear_error(tmp_path):
    env = GraspEnv(TeacherConfig(objects=("cube",)).env_config())  # the raw 40-d env, no yaw features
    PPO("MlpPolicy", env, n_steps=8, batch_size=8, device="cpu").save(tmp_path / "model.zip")
    env.close()
    with pytest.raises(TeacherError, match="retrain"):
        load(tmp_path)


def test_config_validation_names_the_bad_value():
    with pytest.raises(TeacherError, match="'threads'"):
        TeacherConfig(vec="threads")
    with pytest.raises(TeacherError, match="multiple of batch_size"):
        TeacherConfig(n_steps=100, n_envs=1, batch_size=64)


def test_shipped_checkpoint_acts():
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[2] / "models" / "teacher"
    teacher = make_policy(f"ppo:{shipped}")
    assert teacher.normaliser.mean.shape == (TEACHER_OBS_DIM,)
    action = teacher.act(_observations(1)[0])
    assert action.shape == (8,) and np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)
