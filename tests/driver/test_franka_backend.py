"""The franka backend against a fake of pylibfranka's API: what it calls, in which order, and its errors."""

import numpy as np
import pytest

from runtime.franka_driver.backend import BackendError
from runtime.franka_driver.franka_backend import FrankaBackend, FrankaConfig
from runtime.franka_driver.kinematics import DQ_MAX, READY_Q
from tests.driver import fake_pylibfranka as fake


@pytest.fixture()
def world():
    fake.WORLD.__init__()
    return fake.WORLD


def backend(**kw) -> FrankaBackend:
    return FrankaBackend(FrankaConfig(host="10.0.0.2", **kw), lib=fake)


def test_connects_with_realtime_enforced_by_default(world):
    backend()
    assert ("Robot", "10.0.0.2", fake.RealtimeConfig.kEnforce) in world.calls
    assert ("Gripper", "10.0.0.2") in world.calls


def test_connection_failure_is_a_backend_error(world):
    world.refuse_connect = True
    with pytest.raises(BackendError, match="10.0.0.2"):
        backend()


def test_a_kernel_without_realtime_is_a_backend_error_that_names_the_switch(world):
    world.no_realtime_kernel = True
    with pytest.raises(BackendError, match="realtime capabilities.*--no-realtime"):
        backend()
    backend(realtime=False)  # the bench switch connects


def test_first_target_configures_async_handler_with_scaled_velocity_limits(world):
    b = backend(velocity_fraction=0.5)
    b.command(q_target=READY_Q + 0.01, gripper_closed=False)
    configure = next(c for c in world.calls if c[0] == "configure")
    assert np.allclose(configure[1], DQ_MAX * 0.5)
    targets = [c for c in world.calls if c[0] == "target"]
    assert np.allclose(targets[0][1], READY_Q + 0.01)


def test_repeated_target_is_sent_once_and_handler_configured_once(world):
    b = backend()
    for _ in range(3):
        b.command(q_target=READY_Q, gripper_closed=False)
    assert sum(c[0] == "target" for c in world.calls) == 1
    assert sum(c[0] == "configure" for c in world.calls) == 1


def test_refused_target_raises_backend_error_naming_libfranka_reason(world):
    world.refuse_targets = True
    with pytest.raises(BackendError, match="reflex"):
        backend().command(q_target=READY_Q, gripper_closed=False)


def test_hold_stops_the_handler_and_a_new_target_reconfigures(world):
    b = backend()
    b.command(q_target=READY_Q, gripper_closed=False)
    b.hold()
    assert world.calls[-1] == ("stop_control",)
    b.command(q_target=READY_Q, gripper_closed=False)
    assert sum(c[0] == "configure" for c in world.calls) == 2


def test_read_outside_control_returns_state_and_inside_raises_backend_error(world):
    b = backend()
    r = b.read()
    assert np.allclose(r.q, READY_Q) and r.dq.shape == (7,)
    b.command(q_target=READY_Q, gripper_closed=False)
    with pytest.raises(BackendError, match="state"):
        b.read()


def test_gripper_close_grasps_and_open_moves_to_full_width(world):
    b = backend(grasp_force=30.0)
    b.command(q_target=READY_Q, gripper_closed=True)
    assert world.gripper_done.wait(2.0)
    b.close()
    grasp = next(c for c in world.calls if c[0] == "grasp")
    assert grasp[3] == 30.0
    world.gripper_done.clear()
    b2 = backend()
    b2.command(q_target=READY_Q, gripper_closed=False)
    assert world.gripper_done.wait(2.0)
    b2.close()
    assert ("move", 0.08, 0.1) in world.calls


def test_close_leaves_the_arm_holding(world):
    b = backend()
    b.command(q_target=READY_Q, gripper_closed=False)
    b.close()
    assert ("stop_control",) in world.calls


def test_real_pylibfranka_has_the_api_the_fake_mimics():
    lib = pytest.importorskip("pylibfranka")
    handler = lib.AsyncPositionControlHandler
    for name in ("configure", "set_joint_position_target", "get_target_feedback", "stop_control"):
        assert hasattr(handler, name)
    handler.Configuration(maximum_joint_velocities=list(DQ_MAX), goal_tolerance=0.01)
    handler.JointPositionTarget(joint_positions=list(READY_Q))
    for name in ("read_once", "stop"):
        assert hasattr(lib.Robot, name)
    for name in ("FrankaException", "NetworkException", "InvalidOperationException", "RealtimeException"):
        assert issubclass(getattr(lib, name), Exception)
    for name in ("move", "grasp", "read_once"):
        assert hasattr(lib.Gripper, name)
