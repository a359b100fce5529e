"""hil_sim's driver backend over its world: reads, commands, holds, and FK that matches the model."""

import threading

import mujoco
import numpy as np
import pytest

from hil_sim.driver_backend import MujocoBackend
from hil_sim.world import HOME_Q, TABLE_Z, World
from runtime.franka_driver.kinematics import HIL_SIM_Q_OFFSET, Q_MAX, Q_MIN, READY_Q, panda_tcp
from runtime.metadata import PolicyMetadata
from runtime.preprocess import DepthSpec, policy_state


@pytest.fixture(scope="module")
def world():
    w = World(["cube"])
    w.reset("cube", 0, randomise=False)
    yield w
    w.close()


LIBFRANKA_HOME = np.asarray(HOME_Q) + HIL_SIM_Q_OFFSET


def test_tcp_is_the_models_end_effector_in_the_base_frame_and_the_real_arms(world):
    """The backend takes libfranka's angles: its FK is the model's grasp site at the model's angles, and the
    real backend's DH FK (``panda_tcp``) at the same libfranka angles."""
    backend = MujocoBackend(world, threading.Lock())
    for q in (LIBFRANKA_HOME, READY_Q, READY_Q + 0.2):
        world.data.qpos[backend._qadr] = q - HIL_SIM_Q_OFFSET
        mujoco.mj_kinematics(world.model, world.data)
        expected = world.ee_pose()[0] - np.array([0.0, 0.0, TABLE_Z])
        assert np.allclose(backend.tcp(q), expected, atol=1e-9)
        assert np.allclose(backend.tcp(q), panda_tcp(q), atol=1e-3)
    world.reset("cube", 0, randomise=False)


def test_command_sets_actuator_targets_and_hold_freezes_at_measured_pose(world):
    backend = MujocoBackend(world, threading.Lock())
    assert np.allclose(backend.read().q, world.q + HIL_SIM_Q_OFFSET)  # libfranka's angles on the wire
    assert np.all((backend.read().q >= Q_MIN) & (backend.read().q <= Q_MAX))  # the ready pose is in limits
    target = LIBFRANKA_HOME + 0.05
    backend.command(q_target=target, gripper_closed=True)
    assert np.allclose(world.data.ctrl[:7], target - HIL_SIM_Q_OFFSET) and np.all(world.data.ctrl[7:9] == 0.0)
    world.step(0.5)
    reading = backend.read()
    assert np.abs(reading.q - target).max() < 0.02 and reading.gripper_width < 0.08
    backend.hold()
    assert np.allclose(world.data.ctrl[:7], reading.q - HIL_SIM_Q_OFFSET)
    assert np.all(world.data.ctrl[7:9] == 0.0)  # grip kept



def test_the_runtime_builds_the_state_the_student_was_trained_on(world):
    """Training reads ``world.joint_state()`` (the model's angles); on the rig the runtime builds the state
    from the driver's reading (libfranka's angles) and the policy file's joint offset: the same vector."""
    backend = MujocoBackend(world, threading.Lock())
    backend.command(q_target=LIBFRANKA_HOME + 0.1, gripper_closed=True)
    world.step(0.3)
    reading = backend.read()
    offset = PolicyMetadata(DepthSpec()).joint_offset_rad
    runtime_state = policy_state(reading.q, reading.gripper_width, offset)
    assert runtime_state.dtype == world.joint_state().dtype == np.float32
    np.testing.assert_allclose(runtime_state, world.joint_state(), atol=1e-6)
    assert 0 < runtime_state[7] < 0.08  # a gripper part way closed: the opening is the 8th value
    world.reset("cube", 0, randomise=False)
