"""A fake of the slice of pylibfranka 0.21.3's API the franka backend uses, recording every call.

Signatures follow the real bindings (``Robot(ip, RealtimeConfig)``, ``AsyncPositionControlHandler.configure
(robot, Configuration(maximum_joint_velocities, goal_tolerance)) -> ConfigurationResult(handler,
error_message)``, ``set_joint_position_target(JointPositionTarget(joint_positions)) -> CommandResult``,
``Gripper.move(width, speed)``, ``Gripper.grasp(width, speed, force, eps_in, eps_out)``).
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from runtime.franka_driver.kinematics import READY_Q


class FrankaException(Exception):
    pass


class NetworkException(RuntimeError):
    pass


class InvalidOperationException(RuntimeError):
    pass


class RealtimeException(RuntimeError):
    pass


class RealtimeConfig(enum.Enum):
    kEnforce = 0
    kIgnore = 1


@dataclass
class World:
    """What the fake robot did, for the test to inspect."""

    calls: list[tuple] = field(default_factory=list)
    q: np.ndarray = field(default_factory=lambda: READY_Q.copy())
    refuse_targets: bool = False
    refuse_connect: bool = False
    no_realtime_kernel: bool = False
    gripper_done: threading.Event = field(default_factory=threading.Event)


WORLD = World()


class Robot:
    def __init__(self, ip: str, realtime_config: RealtimeConfig = RealtimeConfig.kEnforce) -> None:
        if WORLD.refuse_connect:
            raise NetworkException(f"libfranka: cannot connect to {ip}")
        if WORLD.no_realtime_kernel and realtime_config is RealtimeConfig.kEnforce:
            raise RealtimeException("libfranka: Running kernel does not have realtime capabilities.")
        WORLD.calls.append(("Robot", ip, realtime_config))
        self.controlled = False

    def read_once(self):
        if self.controlled:
            raise InvalidOperationException("another control loop is running")
        return SimpleNamespace(q=WORLD.q.copy(), dq=np.zeros(7))


class Gripper:
    def __init__(self, ip: str) -> None:
        WORLD.calls.append(("Gripper", ip))
        self.width = 0.08

    def move(self, width: float, speed: float) -> bool:
        WORLD.calls.append(("move", width, speed))
        self.width = width
        WORLD.gripper_done.set()
        return True

    def grasp(self, width, speed, force, epsilon_inner=0.005, epsilon_outer=0.005) -> bool:
        WORLD.calls.append(("grasp", width, speed, force, epsilon_inner, epsilon_outer))
        self.width = 0.03
        WORLD.gripper_done.set()
        return True

    def read_once(self):
        return SimpleNamespace(width=self.width, is_grasped=self.width < 0.08)


class _Handler:
    def __init__(self, robot: Robot) -> None:
        self.robot = robot

    def set_joint_position_target(self, target):
        WORLD.calls.append(("target", tuple(target.joint_positions)))
        if WORLD.refuse_targets:
            return SimpleNamespace(was_successful=False, error_message="reflex: joint velocity violation")
        return SimpleNamespace(was_successful=True, error_message=None)

    def stop_control(self) -> None:
        WORLD.calls.append(("stop_control",))
        self.robot.controlled = False


class AsyncPositionControlHandler:
    @dataclass
    class Configuration:
        maximum_joint_velocities: list[float]
        goal_tolerance: float

    @dataclass
    class JointPositionTarget:
        joint_positions: list[float]

    @staticmethod
    def configure(robot: Robot, configuration: Configuration):
        if len(configuration.maximum_joint_velocities) != 7:
            raise ValueError("joint_velocities must have exactly 7 elements")
        WORLD.calls.append(("configure", tuple(configuration.maximum_joint_velocities),
                            configuration.goal_tolerance))
        robot.controlled = True
        return SimpleNamespace(handler=_Handler(robot), error_message=None)
