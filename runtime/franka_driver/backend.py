"""What the driver needs from a robot: read it, stream a joint target + gripper, hold, and its kinematics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


class BackendError(RuntimeError):
    """The robot (or simulator) refused an operation or lost its connection."""


@dataclass(frozen=True)
class Reading:
    """One sample of the robot's state."""

    t: float
    """Monotonic time of the sample, seconds."""
    q: np.ndarray
    dq: np.ndarray
    gripper_width: float
    """Opening of the hand, metres."""


class Backend(Protocol):
    def read(self) -> Reading:
        """The newest state; never blocks for long (the state is published at >= 100 Hz)."""
        ...

    def command(self, *, q_target: np.ndarray, gripper_closed: bool) -> None:
        """Stream a joint-position target (already made safe by the driver) and the gripper state."""
        ...

    def hold(self) -> None:
        """Stop where the arm is: called on every exit path."""
        ...

    def tcp(self, q: np.ndarray) -> np.ndarray:
        """End-effector (TCP) position (3,) in the robot base frame for joints ``q``."""
        ...

    def close(self) -> None:
        ...
