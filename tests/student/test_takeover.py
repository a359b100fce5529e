"""``takeover:ONNX``: the student drives, the reactive expert finishes, and collect keeps only the expert's
steps (recovery demos for DAgger-style aggregation)."""

from __future__ import annotations

import numpy as np

from trainer.collect import _record
from trainer.policies import Observation, make_policy
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, Rollout, start_episode
from trainer.student.onnx_policy import StudentOnnxPolicy
from trainer.student.takeover import SWITCH_STEPS
from trainer.teacher.scripted import ReactiveExpert


def test_the_student_drives_until_the_switch_then_the_expert(untrained_student_onnx):
    env = GraspEnv(EnvConfig(objects=("cube",)))
    takeover = make_policy(f"takeover:{untrained_student_onnx}")
    student, expert = StudentOnnxPolicy(untrained_student_onnx), ReactiveExpert()  # fed the same observations
    try:
        switches = []
        for seed in (3, 4):
            info = start_episode(env, takeover, Job(seed, "cube"), ())
            student.reset(info)
            expert.reset(info)
            switches.append(takeover.taught_from)
            assert SWITCH_STEPS[0] <= takeover.taught_from < SWITCH_STEPS[1]
            for t in range(takeover.taught_from + 3):
                obs = Observation(env.observation(), info["depth"], info["state"])
                action, alone, taught = takeover.act(obs), student.act(obs), expert.act(obs)
                np.testing.assert_array_equal(action, alone if t < takeover.taught_from else taught)
                _, _, terminated, truncated, info = env.step(action)
                assert not (terminated or truncated)
        start_episode(env, takeover, Job(3, "cube"), ())
        assert takeover.taught_from == switches[0]  # drawn from the episode's seed
    finally:
        env.close()


def test_collect_stores_the_steps_from_the_takeover_on():
    steps, switch = 10, 4
    frames = {"depth": [np.full((2, 3), t, np.uint16) for t in range(steps)],
              "state": [np.full(8, t, np.float32) for t in range(steps)],
              "action": [np.full(8, t, np.float32) for t in range(steps)]}
    rollout = Rollout(0, "cube", True, steps, {"crop_window": [0, 0]}, np.eye(3), np.eye(4), frames, switch)
    record = _record(rollout, (2, 3))
    assert len(record.action) == len(record.state) == len(record.depth) == steps - switch
    assert record.action[0, 0] == switch and record.depth[-1, 0, 0] == steps - 1
