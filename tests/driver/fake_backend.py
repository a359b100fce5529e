"""A kinematic stand-in for a robot: the arm is exactly where it was last told to be."""

from __future__ import annotations

import threading
import time

import numpy as np

from runtime.franka_driver.backend import BackendError, Reading
from runtime.franka_driver.kinematics import READY_Q, panda_tcp


class KinematicArm:
    def __init__(self) -> None:
        self.q = READY_Q.copy()
        self.gripper_closed = False
        self.held = 0
        self.fail_reads = False
        self.history: list[tuple[float, np.ndarray]] = []
        self._lock = threading.Lock()

    def read(self) -> Reading:
        if self.fail_reads:
            raise BackendError("fake robot: communication lost")
        with self._lock:
            return Reading(time.monotonic(), self.q.copy(), np.zeros(7), 0.0 if self.gripper_closed else 0.08)

    def command(self, *, q_target: np.ndarray, gripper_closed: bool) -> None:
        with self._lock:
            self.q = np.array(q_target, dtype=float)
            self.gripper_closed = gripper_closed
            self.history.append((time.monotonic(), self.q.copy()))

    def hold(self) -> None:
        self.held += 1

    def tcp(self, q: np.ndarray) -> np.ndarray:
        return panda_tcp(q)

    def close(self) -> None:
        self.hold()
