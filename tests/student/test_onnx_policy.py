"""The "student:ONNX" evaluation policy runs the export through the runtime path and speaks env actions."""

from __future__ import annotations

import numpy as np

from trainer.policies import Observation, make_policy
from trainer.student.onnx_policy import to_env_actions


def observation(rng: np.random.Generator) -> Observation:
    depth = rng.integers(300, 1500, (96, 128)).astype(np.uint16)
    depth[:10] = 0
    return Observation(privileged=np.zeros(40, np.float32), depth=depth, state=np.zeros(8, np.float32))


def test_student_spec_acts_in_env_units_and_replans_every_exec_horizon(untrained_student_onnx):
    policy = make_policy(f"student:{untrained_student_onnx}")
    policy.reset({})
    calls = []
    inner = policy.runtime.__call__
    policy.runtime = lambda depth, state: calls.append(depth.copy()) or inner(depth, state)
    rng = np.random.default_rng(0)
    actions = [policy.act(observation(rng)) for _ in range(10)]
    assert all(a.shape == (8,) and a.dtype == np.float32 for a in actions)
    assert all(np.abs(a[:7]).max() <= 1.0 and a[7] in (-1.0, 1.0) for a in actions)
    assert len(calls) == 2  # exec_horizon 8: steps 0 and 8
    first = calls[0]
    assert first.shape == (3, 96, 128) and np.array_equal(first[0], first[2])  # episode start repeats frame
    assert (first == -1).any()


def test_to_env_actions_undoes_the_action_scale():
    chunk = np.array([[0.05, -0.025, 0, 0, 0, 0, 0.1, 0.3], [0, 0, 0, 0, 0, 0, 0, -0.2]], np.float32)
    env = to_env_actions(chunk, 0.05)
    np.testing.assert_allclose(env[0, :7], [1.0, -0.5, 0, 0, 0, 0, 1.0])
    assert env[:, 7].tolist() == [1.0, -1.0]
