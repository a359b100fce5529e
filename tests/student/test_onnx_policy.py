"""The "student:ONNX" evaluation policy runs the export through the runtime path and speaks env actions."""

from __future__ import annotations

import numpy as np

from runtime.preprocess import normalise
from trainer.policies import Observation, make_policy
from trainer.student.onnx_policy import to_env_actions


def observation(rng: np.random.Generator) -> Observation:
    depth = rng.integers(300, 1500, (96, 128)).astype(np.uint16)
    depth[:10] = 0
    return Observation(privileged=np.zeros(40, np.float32), depth_frame=depth, state=np.zeros(8, np.float32))


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


def test_only_the_frames_an_inference_stacks_are_made_and_the_inputs_are_unchanged(untrained_student_onnx):
    """Sensor models are costly: a lazy frame is made only when it will be in the next inference's stack,
    and the stacks equal those of a policy that read every frame."""
    policy = make_policy(f"student:{untrained_student_onnx}")
    policy.reset({})
    stacks, made = [], []
    inner = policy.runtime.__call__
    policy.runtime = lambda depth, state: stacks.append(depth.copy()) or inner(depth, state)
    frames = [observation(np.random.default_rng(i)).depth for i in range(20)]
    for step, frame in enumerate(frames):
        policy.act(Observation(np.zeros(40, np.float32), lambda s=step, f=frame: made.append(s) or f,
                               np.zeros(8, np.float32)))
    horizon, execute = policy.meta.obs_horizon, policy.meta.exec_horizon
    assert made == [s for s in range(20) if s % execute == 0 or execute - s % execute < horizon]
    for k, stack in enumerate(stacks):
        t = k * execute
        expected = [frames[max(0, t - j)] for j in range(horizon - 1, -1, -1)]
        np.testing.assert_array_equal(stack, [normalise(d, 0.001, policy.meta.preprocess) for d in expected])


def test_an_episode_acts_the_same_whatever_ran_before_it_in_the_process(untrained_student_onnx):
    """Evaluation workers take jobs in no fixed order: an episode's start noise and sensor draws must come
    from its own seed, or the same command measures another success rate each time."""
    from trainer.sim.env import EnvConfig, GraspEnv
    from trainer.sim.rollout import Job, run_episode
    from trainer.sim.sensors import make_sensor

    env = GraspEnv(EnvConfig(objects=("cube",), max_steps=12))
    fresh = lambda: (make_policy(f"student:{untrained_student_onnx}"), make_sensor("randnoise"))  # noqa: E731
    try:
        policy, sensor = fresh()
        run_episode(env, policy, Job(5, "cube"), sensor=sensor)
        after = run_episode(env, policy, Job(6, "cube"), sensor=sensor, record=True)
        policy, sensor = fresh()
        alone = run_episode(env, policy, Job(6, "cube"), sensor=sensor, record=True)
        other = run_episode(env, policy, Job(7, "cube"), sensor=sensor, record=True)
    finally:
        env.close()
    np.testing.assert_array_equal(after.frames["depth_sensor"], alone.frames["depth_sensor"])
    np.testing.assert_array_equal(after.frames["action"], alone.frames["action"])
    assert not np.array_equal(other.frames["depth_sensor"][0], alone.frames["depth_sensor"][0])


def test_reseeding_the_runtime_policy_repeats_its_start_noise(untrained_student_onnx):
    policy = make_policy(f"student:{untrained_student_onnx}").runtime
    stack, state = np.zeros((3, 96, 128), np.float32), np.zeros(8, np.float32)
    policy.reseed(3)
    first = policy(stack, state)
    assert not np.array_equal(policy(stack, state), first), "the start noise must matter to this test"
    policy.reseed(3)
    np.testing.assert_array_equal(policy(stack, state), first)
