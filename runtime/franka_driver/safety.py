"""The driver's safety layer: pure numpy, no I/O, so every rule is tested directly.

Each control step the layer turns (the newest accepted command, the measured joints, the clock) into the
joint target streamed to the backend:

* a command is live until its own deadline, and never longer than ``max_command_age_s`` after it arrived,
  so a runtime that dies or hangs leaves the arm holding within that age (plus one driver step);
* the target is clipped into the joint limits minus a margin;
* the streamed target moves toward the command at most ``velocity_fraction`` of the Panda's velocity
  limits per step: 10 Hz commands become a smooth, bounded-velocity trajectory, and nothing jumps;
* a step that would take the end-effector out of (or further out of) the workspace box is refused;
* the gripper changes state only past a hysteresis band and after a minimum dwell.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from runtime.franka_driver.kinematics import DOF, DQ_MAX, Q_MAX, Q_MIN


class CommandRejected(ValueError):
    """A command the driver will not execute; ``code`` is the status code sent back."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(f"{code}: {detail}")
        self.code = code
        self.detail = detail


@dataclass(frozen=True)
class SafetyConfig:
    """Limits the driver enforces on every command, whatever the runtime sends."""

    max_command_age_s: float = 0.2
    """A command is dropped this long after it arrived even if its deadline is later; with one driver step
    on top this keeps 'runtime gone -> arm holding' under 250 ms."""
    velocity_fraction: float = 0.5
    """Fraction of the Panda's joint velocity limits the streamed target may move at."""
    joint_margin_rad: float = 0.05
    """Distance kept from every joint limit."""
    workspace_min: tuple[float, float, float] = (0.15, -0.6, 0.02)
    """Lower corner of the box the end-effector (TCP) must stay in, robot base frame, metres."""
    workspace_max: tuple[float, float, float] = (0.85, 0.6, 0.9)
    """Upper corner of the workspace box."""
    gripper_close_above: float = 0.5
    """Gripper command above which an open gripper closes (commands are -1 open .. +1 close)."""
    gripper_open_below: float = -0.5
    """Gripper command below which a closed gripper opens."""
    gripper_dwell_s: float = 0.3
    """Minimum time between two gripper changes: a flickering policy output does not chatter the hand."""

    def __post_init__(self) -> None:
        if not 0 < self.max_command_age_s <= 0.25:
            raise ValueError(f"max_command_age_s must be in (0, 0.25], got {self.max_command_age_s}")
        if not 0 < self.velocity_fraction <= 1:
            raise ValueError(f"velocity_fraction must be in (0, 1], got {self.velocity_fraction}")
        if not 0 <= self.joint_margin_rad < 0.2:
            raise ValueError(f"joint_margin_rad must be in [0, 0.2), got {self.joint_margin_rad}")
        if not all(lo < hi for lo, hi in zip(self.workspace_min, self.workspace_max, strict=True)):
            raise ValueError(f"workspace box {self.workspace_min}..{self.workspace_max} is empty")
        if not self.gripper_open_below < self.gripper_close_above:
            raise ValueError(f"gripper hysteresis needs open_below < close_above, got "
                             f"{self.gripper_open_below} >= {self.gripper_close_above}")
        if self.gripper_dwell_s < 0:
            raise ValueError(f"gripper_dwell_s must be >= 0, got {self.gripper_dwell_s}")


@dataclass(frozen=True)
class Command:
    """A command as the safety layer sees it; built from a wire ``command`` message."""

    q_target: np.ndarray
    gripper: float
    deadline: float
    t_receive: float


@dataclass(frozen=True)
class Step:
    """What one control step decided."""

    q_target: np.ndarray
    gripper_closed: bool
    holding: bool
    faults: tuple[str, ...] = ()
    """Status codes raised this step (e.g. ``command_timeout``, ``workspace``, ``joint_limit``)."""


@dataclass
class SafetyLayer:
    """Stateful filter between accepted commands and the backend. ``fk`` maps joints -> TCP position."""

    fk: Callable[[np.ndarray], np.ndarray]
    config: SafetyConfig = field(default_factory=SafetyConfig)
    _command: Command | None = None
    _target: np.ndarray | None = None
    _gripper_closed: bool = False
    _gripper_changed_at: float = -np.inf
    _holding: bool = True

    def accept(self, *, q_target: np.ndarray, gripper: float, deadline: float, now: float) -> None:
        """Take a new command or raise ``CommandRejected`` (the previous command stays in force)."""
        q = np.asarray(q_target, dtype=float)
        if q.shape != (DOF,):
            raise CommandRejected("bad_command", f"q_target must have shape ({DOF},), got {q.shape}")
        if not (np.all(np.isfinite(q)) and np.isfinite(gripper) and np.isfinite(deadline)):
            raise CommandRejected("bad_command", "q_target, gripper and deadline must be finite")
        if deadline <= now:
            raise CommandRejected("stale_command", f"deadline passed {1e3 * (now - deadline):.1f} ms ago")
        self._command = Command(q.copy(), float(gripper), float(deadline), now)

    def step(self, *, q_measured: np.ndarray, now: float, dt: float) -> Step:
        """The target for the next ``dt`` seconds."""
        if self._target is None:
            self._target = np.clip(np.asarray(q_measured, dtype=float), *self._bounds())
        faults: list[str] = []
        cmd = self._live_command(now)
        if cmd is None:
            if not self._holding:
                faults.append("command_timeout")
            self._holding = True
            return Step(self._target.copy(), self._gripper_closed, True, tuple(faults))
        self._holding = False
        self._target = self._move_toward(cmd.q_target, dt, faults)
        self._update_gripper(cmd.gripper, now)
        return Step(self._target.copy(), self._gripper_closed, False, tuple(faults))

    def hold(self) -> None:
        """Drop the current command: the target freezes where it is."""
        self._command = None

    def _live_command(self, now: float) -> Command | None:
        cmd = self._command
        if cmd is None or now >= min(cmd.deadline, cmd.t_receive + self.config.max_command_age_s):
            self._command = None
            return None
        return cmd

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        m = self.config.joint_margin_rad
        return Q_MIN + m, Q_MAX - m

    def _move_toward(self, goal: np.ndarray, dt: float, faults: list[str]) -> np.ndarray:
        lo, hi = self._bounds()
        clipped = np.clip(goal, lo, hi)
        if not np.array_equal(clipped, goal):
            faults.append("joint_limit")
        max_step = DQ_MAX * self.config.velocity_fraction * dt
        proposal = self._target + np.clip(clipped - self._target, -max_step, max_step)
        # A step may not take the TCP further out of the box; one that brings it back in is allowed, so an
        # arm that starts outside can still be driven home.
        outside = self._outside_box(proposal)
        if outside == 0.0 or outside < self._outside_box(self._target):
            return proposal
        faults.append("workspace")
        return self._target

    def _outside_box(self, q: np.ndarray) -> float:
        tcp = np.asarray(self.fk(q), dtype=float)
        lo, hi = np.asarray(self.config.workspace_min), np.asarray(self.config.workspace_max)
        return float(np.linalg.norm(np.maximum(lo - tcp, 0.0) + np.maximum(tcp - hi, 0.0)))

    def _update_gripper(self, command: float, now: float) -> None:
        if now - self._gripper_changed_at < self.config.gripper_dwell_s:
            return
        want = (command > self.config.gripper_close_above if not self._gripper_closed
                else not command < self.config.gripper_open_below)
        if want != self._gripper_closed:
            self._gripper_closed = want
            self._gripper_changed_at = now
