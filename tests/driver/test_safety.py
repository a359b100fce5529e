"""The safety layer, directly: expiry, velocity clamp, joint margins, workspace box, gripper hysteresis."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.franka_driver.kinematics import DQ_MAX, Q_MAX, Q_MIN, READY_Q, panda_tcp
from runtime.franka_driver.safety import CommandRejected, SafetyConfig, SafetyLayer

DT = 0.005


def layer(**kw) -> SafetyLayer:
    return SafetyLayer(panda_tcp, SafetyConfig(**kw))


def test_holds_measured_pose_before_any_command():
    s = layer()
    step = s.step(q_measured=READY_Q, now=0.0, dt=DT)
    assert step.holding and np.allclose(step.q_target, READY_Q)


def test_command_expires_at_its_deadline_and_the_arm_holds():
    s = layer()
    s.accept(q_target=READY_Q + 0.1, gripper=-1, deadline=0.1, now=0.0)
    moving = s.step(q_measured=READY_Q, now=0.01, dt=DT)
    assert not moving.holding
    held = s.step(q_measured=READY_Q, now=0.1, dt=DT)
    assert held.holding and "command_timeout" in held.faults
    assert np.array_equal(held.q_target, moving.q_target)  # freezes where it was: no jump back or forward


def test_far_deadline_is_capped_by_max_command_age():
    s = layer(max_command_age_s=0.2)
    s.accept(q_target=READY_Q + 0.1, gripper=-1, deadline=100.0, now=0.0)
    assert not s.step(q_measured=READY_Q, now=0.19, dt=DT).holding
    assert s.step(q_measured=READY_Q, now=0.2, dt=DT).holding


@pytest.mark.parametrize("q, code", [
    (np.full(6, 0.1), "bad_command"),
    (np.array([np.nan, 0, 0, -1, 0, 1, 0]), "bad_command"),
])
def test_malformed_commands_are_refused(q, code):
    with pytest.raises(CommandRejected) as err:
        layer().accept(q_target=q, gripper=0.0, deadline=1.0, now=0.0)
    assert err.value.code == code


def test_stale_command_is_refused_and_previous_stays():
    s = layer()
    s.accept(q_target=READY_Q, gripper=-1, deadline=1.0, now=0.0)
    with pytest.raises(CommandRejected, match="stale_command"):
        s.accept(q_target=READY_Q + 1, gripper=-1, deadline=0.05, now=0.1)
    assert not s.step(q_measured=READY_Q, now=0.11, dt=DT).holding


def test_step_is_clamped_to_velocity_limits():
    s = layer(velocity_fraction=0.5)
    s.step(q_measured=READY_Q, now=0.0, dt=DT)
    s.accept(q_target=READY_Q + np.array([0.5, 0.0, 0.5, 0.5, 0.5, 0.5, 0.5]) * 0.1, gripper=-1,
             deadline=1.0, now=0.0)
    step = s.step(q_measured=READY_Q, now=0.001, dt=DT)
    assert np.all(np.abs(step.q_target - READY_Q) <= DQ_MAX * 0.5 * DT + 1e-12)
    assert np.abs(step.q_target - READY_Q).max() > 0  # it does move


def test_target_converges_without_exceeding_the_clamp():
    s = layer()
    goal = READY_Q + 0.05
    prev = s.step(q_measured=READY_Q, now=0.0, dt=DT).q_target
    for i in range(1, 40):
        s.accept(q_target=goal, gripper=-1, deadline=i * DT + 0.1, now=i * DT)
        q = s.step(q_measured=prev, now=i * DT, dt=DT).q_target
        assert np.all(np.abs(q - prev) <= DQ_MAX * 0.5 * DT + 1e-12)
        prev = q
    assert np.allclose(prev, goal)


def test_joint_limits_keep_a_margin():
    s = layer(joint_margin_rad=0.05)
    s.accept(q_target=np.where(np.arange(7) == 3, 0.5, READY_Q), gripper=-1, deadline=10.0, now=0.0)
    q, faults = READY_Q, set()
    for i in range(400):
        step = s.step(q_measured=q, now=i * 0.001, dt=0.02)
        q, faults = step.q_target, faults | set(step.faults)
    assert "joint_limit" in faults
    assert q[3] <= Q_MAX[3] - 0.05 + 1e-12 and np.all(q >= Q_MIN + 0.05 - 1e-12)


def test_workspace_box_refuses_steps_that_leave_it():
    tcp_z = panda_tcp(READY_Q)[2]
    s = layer(workspace_max=(0.85, 0.6, tcp_z + 0.01))
    s.step(q_measured=READY_Q, now=0.0, dt=DT)
    up = READY_Q.copy()
    up[3] += 0.4  # unfolding the elbow raises the hand
    assert panda_tcp(up)[2] > tcp_z + 0.01
    faults = set()
    for i in range(100):
        s.accept(q_target=up, gripper=-1, deadline=i * DT + 0.1, now=i * DT)
        step = s.step(q_measured=READY_Q, now=i * DT, dt=DT)
        faults |= set(step.faults)
        assert panda_tcp(step.q_target)[2] <= tcp_z + 0.01
    assert "workspace" in faults


def test_gripper_hysteresis_and_dwell():
    s = layer(gripper_dwell_s=0.3)
    states = []
    for t, g in [(0.0, 0.4), (0.1, 0.6), (0.2, -0.6), (0.35, -0.4), (0.45, -0.6)]:
        s.accept(q_target=READY_Q, gripper=g, deadline=t + 0.1, now=t)
        states.append(s.step(q_measured=READY_Q, now=t, dt=DT).gripper_closed)
    # 0.4: inside the band, stays open; 0.6 closes; -0.6 too soon after (dwell); -0.4 in band; -0.6 opens
    assert states == [False, True, True, True, False]


@pytest.mark.parametrize("kw", [{"max_command_age_s": 0.3}, {"velocity_fraction": 0},
                                {"joint_margin_rad": -1}, {"workspace_min": (1, 0, 0)},
                                {"gripper_open_below": 0.6}])
def test_config_rejects_unsafe_values(kw):
    with pytest.raises(ValueError, match=next(iter(kw)).split("_")[0]):
        SafetyConfig(**kw)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=7, max_size=7), st.floats(-5, 5))
def test_any_finite_command_yields_a_bounded_step(q, g):
    s = layer()
    s.step(q_measured=READY_Q, now=0.0, dt=DT)
    s.accept(q_target=np.array(q), gripper=g, deadline=1.0, now=0.0)
    step = s.step(q_measured=READY_Q, now=0.001, dt=DT)
    assert np.all(np.abs(step.q_target - READY_Q) <= DQ_MAX * 0.5 * DT + 1e-12)
    assert np.all(step.q_target >= Q_MIN) and np.all(step.q_target <= Q_MAX)
