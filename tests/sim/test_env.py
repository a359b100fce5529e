"""GraspEnv: spaces, eq. 1 action scaling, reward terms, student views (depth + state), and the expert."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.world import TABLE_Z
from trainer.policies import Observation, PolicyError, make_policy
from trainer.sim import env as env_module
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import Job, perturb, run_episode
from trainer.teacher.scripted import Phase


@pytest.fixture(scope="module")
def env() -> GraspEnv:
    e = GraspEnv(EnvConfig(objects=("cube", "banana", "can", "lemon"), render_depth=False))
    yield e
    e.close()


def test_reset_gives_documented_views(env: GraspEnv) -> None:
    obs, info = env.reset(seed=3, options={"kind": "cube"})
    assert obs.shape == (40,) and obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert "depth" not in info  # rendering is opt-in per env; the frame is always one call away
    frame = env.frame()
    assert frame.shape == (96, 128) and frame.dtype == np.uint16 and (frame > 0).mean() > 0.5
    assert info["state"].shape == (8,) and info["state"][7] == pytest.approx(0.08, abs=0.002)
    np.testing.assert_allclose(obs[:7], info["state"][:7], atol=1e-6)
    pos, quat = env.world.object_pose()
    np.testing.assert_allclose(obs[25:28], pos, atol=1e-6)
    np.testing.assert_allclose(obs[32:35], [pos[0], pos[1], TABLE_Z + 0.40], atol=1e-6)
    assert obs[35] == pytest.approx(np.log(5))  # cube is category 5
    np.testing.assert_allclose(obs[36:39], pos - obs[18:21], atol=1e-6)
    assert obs[39] == -1.0


def test_named_layout_slices_read_what_they_say(env: GraspEnv) -> None:
    obs, _ = env.reset(seed=4, options={"kind": "banana"})
    env.step(np.r_[np.full(7, 0.5), 1.0].astype(np.float32))  # moving, gripper commanded shut
    obs = env.observation()
    w = env.world
    hand, hand_quat = w.ee_pose()
    obj, obj_quat = w.object_pose()
    fingers, finger_velocities = w.finger_state()
    for name, expected in [("HAND_POSITION", hand), ("HAND_QUAT", hand_quat), ("OBJECT_POSITION", obj),
                           ("OBJECT_QUAT", obj_quat), ("FINGERS", fingers),
                           ("FINGER_VELOCITIES", finger_velocities), ("OBJECT_FROM_HAND", obj - hand),
                           ("LOG_CATEGORY", np.log(4)), ("GRIPPER_COMMAND", 1.0)]:
        np.testing.assert_allclose(obs[getattr(env_module, name)], expected, atol=1e-5, err_msg=name)


def test_action_is_a_scaled_joint_delta(env: GraspEnv) -> None:
    env.reset(seed=4, options={"kind": "cube"})
    q = env.world.q
    action = np.array([0.5, -1.0, 0.2, 0.0, 1.0, -0.3, 0.7, 1.0], np.float32)
    env.step(action)
    np.testing.assert_allclose(env.world.data.ctrl[:7], q + 0.05 * action[:7], atol=1e-9)
    assert env.world.data.ctrl[7] == 0.0  # gripper > 0 closes


def test_bad_action_is_rejected(env: GraspEnv) -> None:
    env.reset(seed=0)
    with pytest.raises(ValueError, match="8 finite"):
        env.step(np.zeros(7))


def test_reward_rewards_reaching_and_penalises_jerk(env: GraspEnv) -> None:
    obs, info = env.reset(seed=5, options={"kind": "cube"})
    policy = make_policy("scripted")
    policy.reset(info)
    _, r, *_, info = env.step(policy.act(Observation(obs, None, info["state"])))
    assert info["terms"]["reach"] > 0 and info["terms"]["accel"] <= 0
    assert np.isfinite(r)


@pytest.mark.parametrize("spec", ["scripted", "reactive"])
@pytest.mark.parametrize("kind,seed", [("cube", 11), ("banana", 12), ("can", 13), ("lemon", 14)])
def test_scripted_expert_grasps_and_lifts(env: GraspEnv, kind: str, seed: int, spec: str) -> None:
    obs, info = env.reset(seed=seed, options={"kind": kind})
    expert = make_policy(spec)
    expert.reset(info)
    lifted_bonus = 0.0
    for _ in range(env.config.max_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(Observation(obs, None, info["state"])))
        lifted_bonus += info["terms"]["bonus"]
        if terminated or truncated:
            break
    assert info["success"], f"{kind} seed {seed} not grasped, expert ended in {expert.phase.name}"
    assert expert.phase == Phase.LIFT and lifted_bonus > 0
    assert env.world.object_pose()[0][2] > TABLE_Z + 0.36
    assert info["state"][7] > 0.01, "fingers must be holding the object, not closed on nothing"


class StandStill:
    """Commands no joint motion and an open gripper, every step."""

    def reset(self, info: dict) -> None:
        pass

    def act(self, obs: Observation) -> np.ndarray:
        return np.array([0.0] * 7 + [-1.0], np.float32)


def test_dart_noise_moves_the_arm_but_the_recorded_actions_are_the_teachers(env: GraspEnv) -> None:
    still = run_episode(env, StandStill(), Job(21, "cube"), record=True)
    noisy = run_episode(env, StandStill(), Job(21, "cube"), record=True, action_noise=0.3)
    again = run_episode(env, StandStill(), Job(21, "cube"), record=True, action_noise=0.3)
    drift = lambda r: np.abs(np.array(r.frames["state"])[:, :7] - r.frames["state"][0][:7]).max()  # noqa: E731
    assert drift(noisy) > 3 * drift(still), "the noise must be executed (standing still sags a little)"
    assert all(np.array_equal(a, StandStill().act(None)) for a in noisy.frames["action"]), "labels stay clean"
    np.testing.assert_array_equal(noisy.frames["state"], again.frames["state"])  # seeded by the job


def test_perturb_leaves_the_gripper_and_the_action_range_alone() -> None:
    action = np.array([0.9] * 7 + [1.0], np.float32)
    assert perturb(action, 0.0, np.random.default_rng(0)) is action
    out = perturb(action, 5.0, np.random.default_rng(0))
    assert out[7] == 1.0 and np.all(np.abs(out[:7]) <= 1.0) and not np.allclose(out[:7], 0.9)
    assert action[0] == np.float32(0.9), "the teacher's action is not modified in place"


def test_unknown_policy_spec_is_one_clear_error() -> None:
    with pytest.raises(PolicyError, match="unknown policy 'magic'"):
        make_policy("magic")
    with pytest.raises(PolicyError, match="needs a path"):
        make_policy("student:")


def test_rgb_view_matches_the_depth_view() -> None:
    env = GraspEnv(EnvConfig(objects=("apple",), render_rgb=True))
    try:
        _, info = env.reset(seed=1)
        assert info["rgb"].shape == (96, 128, 3) and info["rgb"].dtype == np.uint8
        red = (info["rgb"][..., 0] > 120) & (info["rgb"][..., 1] < 60)  # the apple
        assert red.sum() > 10
        assert np.all(info["depth"][red] < np.median(info["depth"][info["depth"] > 0]) + 200)
    finally:
        env.close()
