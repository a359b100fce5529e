"""The fixed-rate control loop: newest depth -> 3-frame stack -> action chunk -> one command per tick.

Timing. Tick k has the deadline ``t0 + k * period`` (absolute, so errors never accumulate): its command must
be sent by then. To keep the frame young, a tick does not sample the camera at a fixed phase: it waits
for the last frame due by its *cutoff* (deadline - work_budget * period) and starts work the moment that
frame arrives (a late frame is awaited up to half a camera period), so the frame's age at inference is the
camera's own delay plus transport, not a random share of a period. ``t0`` is phase-locked to the camera at
start so that cutoffs fall between frame arrivals. A tick that sends after its deadline is late; ticks whose
cutoff has already passed when the previous one ends are skipped, never made up in a burst.

Actions. One inference yields ``action_horizon`` actions; the loop executes ``exec_horizon`` of them, one
per tick, as ``q_target = q_measured + delta`` (paper eq. 1) with the gripper thresholded at 0. An action
whose tick was skipped is dropped, not sent late.

Faults. No usable frame for one control period past the expected one (stall), stale robot state, another
session controlling the arm or a non-finite action: the loop commands hold (the joint positions at that
moment, gripper unchanged), reports a status, and resumes when the cause clears - or gives up after a grace
time and exits non-zero, still holding. SIGINT/SIGTERM end the loop with a final hold command.

Input checks. A frame is not used when it arrived too old, is stamped in the future, does not advance the
frame counter, or is blind (too few pixels that are neither 0 = no data nor 65535 = saturated). It counts as
no frame, so the stall rule holds the arm; the hold's status names the last rejection (``stale_frame``,
``frame_from_future``, ``camera_frozen``, ``camera_blind``) instead of ``camera_stalled``.

Output check. A joint delta beyond ``action_limit`` times the metadata's action scale is no policy output
the training ever produced (its actions were clipped to one action scale): the chunk is not executed, the
arm holds and the runtime exits ``EXIT_ACTION`` at once.
"""

from __future__ import annotations

import json
import secrets
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, TextIO

import numpy as np
import zmq

from runtime.cameras import Camera, CameraEnded, CameraError, CameraStalled, Frame
from runtime.policy import NanActionError, Policy, PolicyError
from runtime.preprocess import RESTORE_METHODS, FrameStack, policy_state, preprocess
from runtime.protocol import DEFAULT_ROBOT, DOF, Encoder, Message, robot_endpoints, session_tag
from runtime.transport import CurveKeys, Newest, connect, send

EXIT_OK, EXIT_CAMERA, EXIT_ROBOT, EXIT_POLICY, EXIT_ACTION = 0, 3, 4, 5, 6
STATE_QUEUE = 4096
SATURATED = np.iinfo(np.uint16).max
"""Depth code of a saturated pixel; 0 is "no data"."""


class RobotStalled(RuntimeError):
    """No fresh robot state for longer than the loop tolerates (status ``robot_stalled``)."""


class NotController(RuntimeError):
    """The driver kept executing another session's commands (status ``not_controller``)."""


class ActionOutOfBounds(PolicyError):
    """The policy returned a joint delta beyond the bound its metadata allows (``EXIT_ACTION``)."""


@dataclass(frozen=True)
class LoopConfig:
    """Timing and fault tolerances of the control loop."""

    rate_hz: float = 10.0
    """Control rate: one command per tick."""
    seconds: float | None = None
    """Stop cleanly (hold, exit 0) after this long; None runs until SIGINT/SIGTERM."""
    validity_periods: float = 1.5
    """A command's deadline is its send time plus this many periods; the driver drops it after that."""
    startup_timeout_s: float = 10.0
    """How long to wait for the first depth frame and robot state."""
    camera_give_up_s: float = 1.0
    """Hold this long for a stalled camera to come back before exiting non-zero."""
    robot_stale_s: float = 0.1
    """Robot state older than this (10 driver periods at 100 Hz) is not trusted for q_target."""
    robot_give_up_s: float = 5.0
    """Hold this long for the driver's state to come back (e.g. a driver restart) before exiting."""
    policy_give_up_s: float = 1.0
    """Hold this long while every inference gives non-finite actions before exiting."""
    max_frame_age_s: float = 0.1
    """A frame already older than this when it arrives was held up on the way and is dropped. Not tied to
    the control period: a D4xx frame arrives 30-40 ms after exposure, more than a 30 Hz period."""
    work_budget: float = 0.8
    """Share of the period between a tick's frame cutoff and its deadline: preprocessing + inference +
    send must fit in it. It costs no frame age (work starts on the frame's arrival), only sets how late
    the slowest inference may finish."""
    restore: str = "none"
    """Hole restoration before the policy (``runtime.preprocess.RESTORE_METHODS``); ``inpaint`` is for a
    policy trained on clean depth."""
    min_valid_fraction: float = 0.2
    """A frame with a smaller share of valid pixels (neither 0 nor 65535) is blind and not used. A D4xx frame
    has ~4 % holes, the stereo model's up to ~30 %; a covered or dead sensor has ~0 %."""
    max_future_s: float = 0.01
    """A frame stamped as captured more than this after it arrived has a wrong clock and is not used."""
    controller_give_up_s: float = 2.0
    """Hold this long while the driver executes another session's commands before exiting (longer than the
    driver's 1 s lease, so the lease of a runtime that just exited can lapse)."""
    action_limit: float = 2.0
    """Largest joint delta accepted from the policy, in multiples of its metadata's action scale. Training
    clipped actions to one action scale; twice that leaves room for un-clipped diffusion samples."""

    def __post_init__(self) -> None:
        for name in ("rate_hz", "validity_periods", "startup_timeout_s", "camera_give_up_s", "robot_stale_s",
                     "robot_give_up_s", "policy_give_up_s", "max_frame_age_s", "max_future_s",
                     "controller_give_up_s", "action_limit"):
            if not getattr(self, name) > 0:
                raise ValueError(f"loop setting {name} must be positive, got {getattr(self, name)}")
        for name in ("work_budget", "min_valid_fraction"):
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"loop setting {name} must be in (0, 1), got {getattr(self, name)}")
        if self.seconds is not None and not self.seconds > 0:
            raise ValueError(f"loop setting seconds must be positive, got {self.seconds}")
        if self.restore not in RESTORE_METHODS:
            raise ValueError(f"loop setting restore must be one of {RESTORE_METHODS}, got {self.restore!r}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


class RobotLink:
    """The driver seen from the runtime: newest ``state`` (SUB) and ``command`` out (PUSH).

    Its commands carry a secret ``session`` token drawn per process: the driver executes one session at a
    time, and states name the controlling session by its public ``tag``, so the loop can tell whether the arm
    is its own."""

    def __init__(self, address: str = DEFAULT_ROBOT, *, keys: CurveKeys | None = None,
                 ctx: zmq.Context | None = None) -> None:
        ctx = ctx or zmq.Context.instance()
        self.address = address
        state_ep, command_ep = robot_endpoints(address)
        # ~300-byte states at up to 1 kHz, read once per tick or less: queue a few seconds of them.
        self._state = Newest(connect(ctx, zmq.SUB, state_ep, keys=keys, queue=STATE_QUEUE), "state")
        self._cmd = connect(ctx, zmq.PUSH, command_ep, keys=keys)
        self._enc = Encoder()
        self._session = secrets.token_hex(16)
        self.tag = session_tag(self._session)
        """How states name this link's session when it controls the arm."""
        self.latest: Message | None = None
        self.dropped = 0

    @property
    def rejected(self) -> int:
        """Malformed messages refused on the state socket."""
        return self._state.rejected

    def poll(self, timeout_s: float = 0.0) -> Message | None:
        got = self._state.poll(timeout_s)
        if got is not None:
            self.latest = got[0]
        return self.latest

    def command(self, q_target: np.ndarray, gripper: float, *, validity_s: float, t_capture: float) -> int:
        """Send one command; returns its sequence number (counted as dropped if no driver can take it)."""
        seq = self._enc.seq
        now = time.monotonic()
        frames = self._enc.encode("command", q_target=[float(v) for v in q_target], gripper=float(gripper),
                                  deadline=now + validity_s, t_capture=float(t_capture),
                                  session=self._session)
        if not send(self._cmd, frames):
            self.dropped += 1
        return seq

    def close(self) -> None:
        self._state.sock.close()
        self._cmd.close(linger=200)  # the final hold command must still get out


@dataclass
class Tick:
    """What one tick did; written as one JSON line to --metrics (monotonic seconds, null = stage not run)."""

    tick: int
    deadline: float
    late: bool = False
    skipped: bool = False
    cmd_seq: int | None = None
    t_capture: float | None = None
    t_receive: float | None = None
    t_preprocess: float | None = None
    """End of preprocessing = start of inference on inference ticks."""
    t_inference: float | None = None
    """End of inference; null on ticks that execute an action of an earlier chunk."""
    t_send: float | None = None
    frame: int | None = None
    hold: bool = False
    status: str | None = None


_EXIT_CODES = ((CameraError, EXIT_CAMERA), (RobotStalled, EXIT_ROBOT), (NotController, EXIT_ROBOT),
               (ActionOutOfBounds, EXIT_ACTION), (PolicyError, EXIT_POLICY))
"""Fatal error kind -> the runtime's exit status (documented in ``runtime --help``); first match wins."""
_FATAL = tuple(kind for kind, _ in _EXIT_CODES)

_FRAME_REJECTIONS = {"stale_frame": "stale_frames", "frame_from_future": "future_frames",
                     "camera_frozen": "frozen_frames", "camera_blind": "blind_frames"}
"""Frame rejection code -> its counter in ``ControlLoop.counts``."""
# fault code -> (LoopConfig field with its grace time, error raised when it is exceeded)
_GIVE_UP = {"camera_stalled": ("camera_give_up_s", CameraStalled),
            **{code: ("camera_give_up_s", CameraStalled) for code in _FRAME_REJECTIONS},
            "robot_stalled": ("robot_give_up_s", RobotStalled),
            "not_controller": ("controller_give_up_s", NotController),
            "nan_action": ("policy_give_up_s", PolicyError)}


class ControlLoop:
    def __init__(self, policy: Policy, camera: Camera, robot: RobotLink, config: LoopConfig, *,
                 metrics: TextIO | None = None, stop: threading.Event | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.policy, self.camera, self.robot, self.config = policy, camera, robot, config
        self.clock = clock
        """Monotonic seconds; the cameras, the driver and the metrics share this clock (tests swap it)."""
        self.metrics = metrics
        self.stop = stop or threading.Event()
        self.spec = policy.metadata.preprocess
        self.stack = FrameStack(policy.metadata.obs_horizon, policy.metadata.first_frame)
        self.counts = {"ticks": 0, "late": 0, "skipped": 0, "nan_actions": 0, "rejected_messages": 0,
                       **dict.fromkeys(_FRAME_REJECTIONS.values(), 0)}
        self.faults: dict[str, float] = {}
        """Active fault code -> monotonic time it began."""
        self._chunk: np.ndarray | None = None
        self._chunk_tick = 0
        self._frame: Frame | None = None
        self._rejection: tuple[str, str] | None = None
        """Why the newest frame was not used (code, detail); None once a frame is taken."""
        self._used_frame = -1
        self._gripper: float | None = None
        self._hold_q: np.ndarray | None = None
        self._driver_fault = ""

    # ---- the loop -------------------------------------------------------------------------------
    def run(self) -> int:
        """Run until stopped, the time is up or a fatal fault; every exit path ends with a hold command."""
        try:
            self._startup()
            if not self.stop.is_set():  # a signal during start-up: nothing to run, just the final hold
                self._ticks()
            return EXIT_OK
        except CameraEnded as exc:
            self._report("camera_ended", str(exc))
            return EXIT_OK
        except _FATAL as exc:
            self._report("fatal", str(exc))
            return next(code for kind, code in _EXIT_CODES if isinstance(exc, kind))
        finally:
            self._final_hold()
            self.counts["rejected_messages"] = self.robot.rejected + getattr(self.camera, "rejected", 0)

    def _startup(self) -> None:
        """First frames (a few, so a measuring camera knows its period) and the first robot state."""
        self.policy.warmup(3)  # first-call allocations happen here, not in tick 0; a NaN model fails here
        end = self.clock() + self.config.startup_timeout_s
        while self._frame is None and not self.stop.is_set():
            if self.clock() > end:
                why = f" (last refused: {': '.join(self._rejection)})" if self._rejection else ""
                raise CameraStalled(f"camera {self.camera.name}: no usable frame within "
                                    f"{self.config.startup_timeout_s} s of start{why}")
            self._take(self.camera.poll(0.05))
        settle = self.clock() + 4 * self.camera.period_s
        while self.clock() < settle and not self.stop.is_set():
            self._take(self.camera.poll(settle - self.clock()))
        while self.robot.poll(0.05) is None and not self.stop.is_set():
            if self.clock() > end:
                address, waited = self.robot.address, self.config.startup_timeout_s
                raise RobotStalled(f"no robot state on {address} within {waited:g} s of start; is the driver "
                                   f"running? start it: `python -m runtime.franka_driver --bind {address}` "
                                   "(the simulated arm: `python -m hil_sim.driver`)")

    def _first_deadline(self) -> float:
        """Phase-lock the ticks to the camera. Cutoffs fall between frame arrivals, as far from any as the two
        rates allow (half the common period: half a camera period at 10 Hz/30 fps, a sixth at 10 Hz/15 fps),
        so arrival jitter never flips which frame a tick takes."""
        camera_period = self.camera.period_s
        ratio = Fraction(self.config.period / camera_period).limit_denominator(8)
        due = self._frame.t_receive + camera_period
        while due < self.clock():
            due += camera_period
        return due + camera_period / ratio.denominator / 2 + self.config.work_budget * self.config.period

    def _ticks(self) -> None:
        period = self.config.period
        t0 = self._first_deadline()
        end = None if self.config.seconds is None else t0 + self.config.seconds
        k = 0
        while not self.stop.is_set() and (end is None or t0 + k * period <= end):
            self._record(self._tick(Tick(k, t0 + k * period)))
            k += 1
            while self._cutoff(t0 + k * period) < self.clock():  # too late to start: skip, never burst
                self._record(Tick(k, t0 + k * period, late=True, skipped=True))
                k += 1

    def _tick(self, tick: Tick) -> Tick:
        exec_horizon = self.policy.metadata.exec_horizon
        needs_inference = self._chunk is None or tick.tick - self._chunk_tick >= exec_horizon
        frame = self._await_frame(self._cutoff(tick.deadline))
        state, problems = self._robot_state()
        if frame is None:
            problems.update([self._camera_problem()])
        elif not problems:
            tick.t_capture, tick.t_receive, tick.frame = frame.t_capture, frame.t_receive, frame.number
            depth = preprocess(frame.depth, frame.depth_scale, self.spec, restore=self.config.restore)
            obs = self.stack.push(depth)
            tick.t_preprocess = self.clock()
            if needs_inference:
                problems = self._infer(obs, state, tick)
        self._update_faults(problems)
        if problems:
            return self._hold_tick(tick)
        return self._act(tick, self._chunk[tick.tick - self._chunk_tick])

    def _cutoff(self, deadline: float) -> float:
        """A tick uses the last frame due by its cutoff; the rest of the period is the work budget."""
        return deadline - self.config.work_budget * self.config.period

    # ---- stages ---------------------------------------------------------------------------------
    def _await_frame(self, cutoff: float) -> Frame | None:
        """The last frame due by ``cutoff``, returned the moment it arrives; a late one is awaited for up to
        half a camera period. None when the camera has stalled: at once when the stall is new, at the cutoff
        while it lasts (hold commands keep the tick pace)."""
        self._take(self.camera.poll(0.0))  # whatever arrived while the last tick was busy
        while not self.stop.is_set():
            now = self.clock()
            stalls_at = self._frame.t_receive + self.camera.period_s + self.config.period
            if now > stalls_at:  # one control period past the frame that was due
                if now >= cutoff or self._camera_problem()[0] not in self.faults:
                    return None
                self._take(self.camera.poll(cutoff - now))
                continue
            period = self.camera.period_s
            next_due = self._frame.t_receive + period
            fresh = self._frame.number != self._used_frame
            if fresh and next_due > cutoff:
                break  # the newest frame is the last one due by the cutoff
            # the last frame due by the cutoff, even if some before it never come; then a grace for lateness
            last_due = next_due + max(0, (cutoff - next_due) // period) * period
            wait_until = last_due + period / 2 if next_due <= cutoff else cutoff
            if now >= wait_until:
                break  # that frame is too late (or none is due): go on with the newest
            self._take(self.camera.poll(min(wait_until, stalls_at + 1e-4) - now))
        self._used_frame = self._frame.number
        return self._frame

    def _take(self, frame: Frame | None) -> None:
        """Accept a polled frame unless the input checks refuse it (then remember why)."""
        if frame is None:
            return
        self._rejection = self._frame_problem(frame)
        if self._rejection is None:
            self._frame = frame
        else:
            self.counts[_FRAME_REJECTIONS[self._rejection[0]]] += 1

    def _frame_problem(self, frame: Frame) -> tuple[str, str] | None:
        age = frame.t_receive - frame.t_capture
        if age > self.config.max_frame_age_s:
            return "stale_frame", f"frame {frame.number} arrived {1e3 * age:.0f} ms after its capture"
        if -age > self.config.max_future_s:
            return "frame_from_future", (f"frame {frame.number} is stamped {-1e3 * age:.0f} ms after it "
                                         "arrived: the camera's clock is wrong")
        if self._frame is not None and frame.number <= self._frame.number:
            return "camera_frozen", f"frame number {frame.number} does not advance past {self._frame.number}"
        valid = _valid_fraction(frame.depth)
        if valid < self.config.min_valid_fraction:
            return "camera_blind", (f"frame {frame.number} has {100 * valid:.1f} % valid pixels (at least "
                                    f"{100 * self.config.min_valid_fraction:g} % needed)")
        return None

    def _camera_problem(self) -> tuple[str, str]:
        """Why no usable frame came: the last refused frame's reason, else a plain stall."""
        if self._rejection is not None:
            return self._rejection
        refused = getattr(self.camera, "rejected", 0)
        return "camera_stalled", (f"no frame from {self.camera.name} for "
                                  f"{self.clock() - self._frame.t_receive:.3f} s"
                                  + (f" ({refused} malformed messages refused so far)" if refused else ""))

    def _robot_state(self) -> tuple[np.ndarray | None, dict[str, str]]:
        """[q (7), gripper opening] from the newest robot state, or the problems that make it unusable."""
        state = self.robot.poll()
        if state is None or self.clock() - state["t_capture"] > self.config.robot_stale_s:
            return None, {"robot_stalled": f"no robot state for over {self.config.robot_stale_s} s"}
        if state["fault"] != self._driver_fault:  # the driver's own safety verdicts: reported, not acted on
            self._driver_fault = state["fault"]
            self._report("driver", state["fault"] or "fault cleared")
        if state["controller"] not in ("", self.robot.tag):  # our commands are being refused
            return None, {"not_controller": f"the driver executes session {state['controller']}, not this "
                                            f"runtime's ({self.robot.tag}): another process holds the arm"}
        return policy_state(state["q"], state["gripper"], self.policy.metadata.joint_offset_rad), {}

    def _infer(self, obs: np.ndarray, state: np.ndarray, tick: Tick) -> dict[str, str]:
        self._chunk = None
        try:
            chunk = self.policy(obs, state)
        except NanActionError as exc:
            self.counts["nan_actions"] += 1
            return {"nan_action": str(exc)}
        self._check_actions(chunk)
        self._chunk = chunk
        tick.t_inference = self.clock()
        self._chunk_tick = tick.tick
        return {}

    def _check_actions(self, chunk: np.ndarray) -> None:
        """``ActionOutOfBounds`` when a joint delta exceeds ``action_limit`` action scales: a broken or
        hostile policy file must not reach the driver, which would only rate-limit it toward the limits."""
        bound = self.config.action_limit * self.policy.metadata.action_scale
        worst = float(np.max(np.abs(chunk[:, :DOF])))
        if not worst <= bound * (1 + 1e-6):  # float32 outputs: a delta exactly at the bound may round up
            raise ActionOutOfBounds(f"policy output a joint delta of {worst:.4g} rad, beyond the bound "
                                    f"{bound:.4g} rad ({self.config.action_limit:g} x action scale "
                                    f"{self.policy.metadata.action_scale:g}): not executed")

    def _act(self, tick: Tick, action: np.ndarray) -> Tick:
        self._hold_q = None
        q_now = np.asarray(self.robot.latest["q"], dtype=np.float64)
        self._gripper = 1.0 if action[DOF] > 0 else -1.0
        return self._send(tick, q_now + action[:DOF], self._gripper)

    def _hold_tick(self, tick: Tick) -> Tick:
        """Command hold - the position latched when the fault began, gripper unchanged - and forget the
        chunk and the frame history, which the fault made stale (not the episode's first frame: the scene)."""
        self._chunk = None
        self.stack.reset(keep_first=True)
        tick.hold = True
        return self._send(tick, self._hold_target(), self._hold_gripper())

    def _hold_target(self) -> np.ndarray | None:
        if self._hold_q is None and self.robot.latest is not None:
            self._hold_q = np.asarray(self.robot.latest["q"], dtype=np.float64)
        return self._hold_q

    def _hold_gripper(self) -> float:
        if self._gripper is None:  # nothing commanded yet: keep whatever the gripper is doing now
            opening = self.robot.latest["gripper"] if self.robot.latest is not None else 0.08
            self._gripper = 1.0 if opening < 0.039 else -1.0
        return self._gripper

    def _send(self, tick: Tick, q_target: np.ndarray | None, gripper: float) -> Tick:
        tick.status = ",".join(sorted(self.faults)) or None
        if q_target is None:  # never had a robot state: nothing safe to command
            return tick
        tick.cmd_seq = self.robot.command(q_target, gripper, validity_s=self._validity(),
                                          t_capture=tick.t_capture or self.clock())
        tick.t_send = self.clock()
        tick.late = tick.t_send > tick.deadline
        return tick

    def _validity(self) -> float:
        return self.config.validity_periods * self.config.period

    def _final_hold(self) -> None:
        """Last command on every exit path: hold where the arm is now, gripper unchanged."""
        self._hold_q = None
        if self.robot.poll(0.0) is not None:
            self.robot.command(self._hold_target(), self._hold_gripper(), validity_s=self._validity(),
                               t_capture=self.clock())

    # ---- faults and reporting --------------------------------------------------------------------
    def _update_faults(self, problems: dict[str, str]) -> None:
        """Report faults as they begin and clear; raise once one has lasted past its grace time."""
        now = self.clock()
        for code in [c for c in self.faults if c not in problems]:
            del self.faults[code]
            self._report(f"{code}_cleared", "resuming")
        for code, detail in problems.items():
            if code not in self.faults:
                self.faults[code] = now
                self._report(code, detail)
            setting, error = _GIVE_UP[code]
            if now - self.faults[code] > getattr(self.config, setting):
                raise error(f"{code} for {now - self.faults[code]:.2f} s: {detail}")

    def _report(self, code: str, detail: str) -> None:
        print(f"runtime: status {code}: {detail}", file=sys.stderr, flush=True)

    def _record(self, tick: Tick) -> None:
        self.counts["ticks"] += 1
        self.counts["late"] += tick.late
        self.counts["skipped"] += tick.skipped
        if self.metrics is not None:
            self.metrics.write(json.dumps(_jsonable(tick.__dict__)) + "\n")


def _valid_fraction(depth: np.ndarray) -> float:
    """Share of pixels that carry a measurement: neither 0 (no data) nor saturated."""
    return float(np.count_nonzero((depth > 0) & (depth < SATURATED))) / max(depth.size, 1)


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in d.items()}

