"""The real Franka Panda through pylibfranka 0.21.3 (``pip install .[franka]``).

Thin on purpose: libfranka's ``AsyncPositionControlHandler`` interpolates the targets we stream (at the
driver's state rate, already velocity-limited by the safety layer) inside libfranka's own 1 kHz loop,
so no Python runs at 1 kHz (its docs warn the GIL makes that jitter). The gripper is a separate slow
device: each open/close is sent from a worker thread so a 1 s grasp never stalls the state stream.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from runtime.franka_driver.backend import BackendError, Reading
from runtime.franka_driver.kinematics import DQ_MAX, GRIPPER_MAX_WIDTH, panda_tcp


@dataclass(frozen=True)
class FrankaConfig:
    """Connection and hand settings for the real robot."""

    host: str = "172.16.0.2"  # robot (FCI) address
    realtime: bool = True  # enforce a real-time kernel (libfranka's kEnforce); off only for bench tests
    goal_tolerance: float = 0.01  # libfranka's goal tolerance for a joint target, radians
    velocity_fraction: float = 0.5  # of the datasheet's joint velocity limits, for libfranka's interpolator
    grasp_speed: float = 0.1  # m/s
    grasp_force: float = 40.0  # N


class FrankaBackend:
    """``Backend`` over pylibfranka. ``lib`` is the module (tests pass a fake with the same API)."""

    def __init__(self, config: FrankaConfig = FrankaConfig(), *, lib: Any = None) -> None:
        if lib is None:
            import pylibfranka as lib  # optional dependency: only the real robot needs it
        self._lib = lib
        # pylibfranka's exception types do not share one base (NetworkException is a RuntimeError).
        self._errors = (lib.FrankaException, lib.NetworkException, lib.InvalidOperationException,
                        lib.RealtimeException)
        self.config = config
        rt = lib.RealtimeConfig.kEnforce if config.realtime else lib.RealtimeConfig.kIgnore
        try:
            self._robot = lib.Robot(config.host, rt)
            self._gripper = lib.Gripper(config.host)
        except self._errors as exc:
            hint = " (--no-realtime on a bench machine)" if isinstance(exc, lib.RealtimeException) else ""
            raise BackendError(f"cannot connect to the Franka at {config.host!r}: {exc}{hint}") from exc
        self._handler: Any = None
        self._last_q: np.ndarray | None = None
        self._gripper_closed: bool | None = None
        self._gripper_width = GRIPPER_MAX_WIDTH
        self._hand = ThreadPoolExecutor(max_workers=1, thread_name_prefix="franka-hand")
        self._hand_job: Future | None = None
        self._lock = threading.Lock()

    def read(self) -> Reading:
        # Unverified on hardware: libfranka's Robot::readOnce refuses while a control handler owns the
        # robot, and pylibfranka 0.21.3 does not expose the state the async handler reads. A failure here
        # surfaces as BackendError (fault status + hold) rather than a silently stale state.
        try:
            state = self._robot.read_once()
        except self._errors as exc:
            raise BackendError(f"cannot read the Franka's state: {exc}") from exc
        width = self._gripper_width
        return Reading(time.monotonic(), np.asarray(state.q, float), np.asarray(state.dq, float), width)

    def command(self, *, q_target: np.ndarray, gripper_closed: bool) -> None:
        q = np.asarray(q_target, dtype=float)
        if self._last_q is None or not np.array_equal(q, self._last_q):
            target = self._lib.AsyncPositionControlHandler.JointPositionTarget(joint_positions=q.tolist())
            result = self._active_handler().set_joint_position_target(target)
            if result.error_message is not None:
                raise BackendError(f"libfranka refused the joint target: {result.error_message}")
            self._last_q = q.copy()
        if gripper_closed != self._gripper_closed:
            self._set_gripper(gripper_closed)

    def hold(self) -> None:
        # Stopping the handler lets libfranka bring the arm to rest on its own trajectory, then hold.
        with self._lock:
            handler, self._handler, self._last_q = self._handler, None, None
        if handler is not None:
            handler.stop_control()

    def tcp(self, q: np.ndarray) -> np.ndarray:
        return panda_tcp(q)

    def close(self) -> None:
        self.hold()
        self._hand.shutdown(wait=True)

    def _active_handler(self) -> Any:
        with self._lock:
            if self._handler is None:
                handler_cls = self._lib.AsyncPositionControlHandler
                cfg = handler_cls.Configuration(
                    maximum_joint_velocities=(DQ_MAX * self.config.velocity_fraction).tolist(),
                    goal_tolerance=self.config.goal_tolerance)
                result = handler_cls.configure(self._robot, cfg)
                if result.error_message is not None:
                    raise BackendError(f"libfranka async position control: {result.error_message}")
                self._handler = result.handler
            return self._handler

    def _set_gripper(self, closed: bool) -> None:
        if self._hand_job is not None and not self._hand_job.done():
            return  # the hand is still moving; the next step retries with the then-current wish
        self._gripper_closed = closed
        self._hand_job = self._hand.submit(self._move_hand, closed)

    def _move_hand(self, closed: bool) -> None:
        cfg = self.config
        if closed:
            self._gripper.grasp(0.0, cfg.grasp_speed, cfg.grasp_force, 0.005, GRIPPER_MAX_WIDTH)
        else:
            self._gripper.move(GRIPPER_MAX_WIDTH, cfg.grasp_speed)
        self._gripper_width = float(self._gripper.read_once().width)
