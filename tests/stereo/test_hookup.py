"""The stereo sensor where a sensor is chosen: the evaluator's rollout and hil_sim's camera."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.server import SimConfig, _depth_source
from trainer.policies import Observation
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, run_episode
from trainer.sim.sensors import SceneSensor, make_sensor, reads_clean_depth


class _Recorder:
    """A policy that holds still and keeps what it was shown."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def reset(self, info: dict) -> None:
        self.seen.clear()

    def act(self, obs: Observation) -> np.ndarray:
        self.seen.append(obs.depth)
        return np.zeros(8, np.float32)


def test_the_evaluator_shows_the_policy_stereo_depth_through_the_runtime_crop():
    env = GraspEnv(EnvConfig(objects=("cube",), max_steps=2))
    sensor = make_sensor("stereo")
    assert isinstance(sensor, SceneSensor)
    policy = _Recorder()
    try:
        run_episode(env, policy, Job(seed=7, kind="cube"), sensor=sensor)
        clean = env.frame().astype(float)
    finally:
        sensor.close()
        env.close()
    seen = policy.seen[-1]
    assert seen.shape == (96, 128) and seen.dtype == np.uint16
    both = (seen > 0) & (clean > 0)
    assert np.median(np.abs(seen[both].astype(float) - clean[both])) < 15, "not the same scene and window"
    assert ((seen == 0) & (clean > 0)).any(), "stereo holes never reached the policy"


def test_the_evaluators_inpaint_restoration_fills_the_stereo_holes_the_policy_would_see():
    assert not reads_clean_depth("stereo") and reads_clean_depth("ddg:steps=2") and reads_clean_depth("clean")
    env = GraspEnv(EnvConfig(objects=("cube",), max_steps=2, render_depth=False))  # as evaluate builds it
    sensor = make_sensor("stereo")
    policy = _Recorder()
    try:
        run_episode(env, policy, Job(seed=7, kind="cube"), sensor=sensor, restore="inpaint")
    finally:
        sensor.close()
        env.close()
    assert policy.seen[-1].shape == (96, 128) and not (policy.seen[-1] == 0).any()


def test_clean_sensor_is_still_a_plain_function():
    sensor = make_sensor("clean")
    frame = np.arange(12, dtype=np.uint16).reshape(3, 4)
    assert not isinstance(sensor, SceneSensor)
    np.testing.assert_array_equal(sensor(frame), frame)


def test_hil_camera_publishes_stereo_frames_at_the_stream_size(world):
    depth, close = _depth_source(SimConfig(sensor="stereo"), world)
    world.reset("cube", 0, randomise=False)
    try:
        frame = depth()
    finally:
        close()
    assert frame.shape == (480, 848) and frame.dtype == np.uint16
    assert 0.01 < (frame == 0).mean() < 0.9


def test_unknown_hil_sensor_is_refused():
    with pytest.raises(ValueError, match="sensor must be one of clean, stereo"):
        SimConfig(sensor="lidar")
