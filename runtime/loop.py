"""The fixed-rate control loop: newest depth -> 3-frame stack -> action chunk -> one command per tick.

Timing. Tick k must send its command by its deadline ``t0 + k * period`` (absolute: errors never add up).
It takes the last frame due by its *cutoff* (deadline - work_budget * period), starting work the moment that
frame arrives (a late one is awaited up to half a camera period), so a frame's age at inference is the
camera's own delay, not a random share of a period; ``t0`` is phase-locked to the camera.
A tick that sends after its deadline is late; ticks whose cutoff passed while the previous one ran are
skipped, never made up in a burst, and their actions dropped.

Actions. One inference yields ``action_horizon`` actions, ``exec_horizon`` of them are executed, one per tick,
as ``q_target = q_measured + delta`` (paper eq. 1), the gripper thresholded at 0.

Faults. A frame is refused when it arrived too old, is stamped in the future, does not advance the frame
counter or is blind (too few pixels neither 0 = no data nor 65535 = saturated). No usable frame for one
control period past the expected one, stale robot state, another session holding the arm or a non-finite
action: the loop commands hold (the joints at that moment, gripper unchanged) with a status naming the
cause, resumes when it clears, or exits non-zero after a grace time, still holding. A joint delta beyond
``action_limit`` action scales (training clipped to one) is never executed: hold, exit ``EXIT_ACTION`` at
once. SIGINT/SIGTERM end the loop with a final hold.
"""

from __future__ import annotations

import json
import secrets
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from fractions import Fraction
from typing import TextIO

import numpy as np
import zmq

from runtime.cameras.base import Camera, CameraEnded, CameraError, CameraStalled, Frame
from runtime.policy import NanActionError, Policy, PolicyError
from runtime.preprocess import RESTORE_METHODS, FrameStack, policy_state, preprocess
from runtime.protocol import DEFAULT_ROBOT, DOF, Encoder, Message, robot_endpoints, session_tag
from runtime.transport import CurveKeys, Newest, connect, send

EXIT_OK, EXIT_CAMERA, EXIT_ROBOT, EXIT_POLICY, EXIT_ACTION = 0, 3, 4, 5, 6
SATURATED = np.iinfo(np.uint16).max


class RobotStalled(RuntimeError):
    """No fresh robot state for longer than the loop tolerates (status ``robot_stalled``)."""


class NotController(RuntimeError):
    """The driver kept executing another session's commands (status ``not_controller``)."""


class ActionOutOfBounds(PolicyError):
    """The policy returned a joint delta beyond the bound its metadata allows (``EXIT_ACTION``)."""


@dataclass(frozen=True)
class LoopConfig:
    """Timing and fault tolerances of the control loop (seconds unless named otherwise)."""

    rate_hz: float = 10.0
    seconds: float | None = None  # stop cleanly (hold, exit 0) after this long; None: until SIGINT/SIGTERM
    validity_periods: float = 1.5  # a command's deadline: its send time plus this many periods
    startup_timeout_s: float = 10.0  # wait for the first depth frame and robot state
    camera_give_up_s: float = 1.0  # hold this long for a stalled camera, then exit
    robot_stale_s: float = 0.1  # older robot state (10 driver periods) is not trusted for q_target
    robot_give_up_s: float = 5.0  # hold this long for the driver's state to come back (a driver restart)
    policy_give_up_s: float = 1.0  # hold this long while every inference is non-finite
    max_frame_age_s: float = 0.1  # a frame older on arrival was held up and is dropped (a D4xx: 30-40 ms)
    work_budget: float = 0.8  # share of the period from frame cutoff to deadline: preprocess + infer + send
    restore: str = "none"  # hole restoration (``RESTORE_METHODS``); inpaint for a clean-depth policy
    min_valid_fraction: float = 0.2  # a blind frame has less (a D4xx ~96 %, the stereo model >= 70 %)
    max_future_s: float = 0.01  # a frame stamped further after its arrival has a wrong clock
    controller_give_up_s: float = 2.0  # hold this long while another session holds the arm (> 1 s lease)
    action_limit: float = 2.0  # largest joint delta, in action scales (un-clipped diffusion samples)

    def __post_init__(self) -> None:
        for f in fields(self):
            value, unit = getattr(self, f.name), f.name in ("work_budget", "min_valid_fraction")
            if f.name == "restore" or (f.name == "seconds" and value is None):
                continue
            if not (0 < value < 1 if unit else value > 0):
                raise ValueError(f"loop setting {f.name} must be {'in (0, 1)' if unit else 'positive'}, "
                                 f"got {value}")
        if self.restore not in RESTORE_METHODS:
            raise ValueError(f"loop setting restore must be one of {RESTORE_METHODS}, got {self.restore!r}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


class RobotLink:
    """The driver seen from the runtime: newest ``state`` in (SUB), ``command`` out (PUSH). Commands carry a
    secret ``session`` token drawn per process; states name the controlling session by its public ``tag``."""

    def __init__(self, address: str = DEFAULT_ROBOT, *, keys: CurveKeys | None = None,
                 ctx: zmq.Context | None = None) -> None:
        ctx = ctx or zmq.Context.instance()
        self.address = address
        state_ep, command_ep = robot_endpoints(address)
        # ~300-byte states at up to 1 kHz, read once per tick or less: queue a few seconds of them
        self._state = Newest(connect(ctx, zmq.SUB, state_ep, keys=keys, queue=4096), "state")
        self._cmd = connect(ctx, zmq.PUSH, command_ep, keys=keys)
        self._enc = Encoder()
        self._session = secrets.token_hex(16)
        self.tag = session_tag(self._session)
        self.latest: Message | None = None
        self.dropped = 0

    @property
    def rejected(self) -> int:
        return self._state.rejected

    def poll(self, timeout_s: float = 0.0) -> Message | None:
        got = self._state.poll(timeout_s)
        self.latest = got[0] if got is not None else self.latest
        return self.latest

    def command(self, q_target: np.ndarray, gripper: float, *, validity_s: float, t_capture: float) -> int:
        """Send one command; its sequence number (counted as dropped if no driver can take it)."""
        seq, now = self._enc.seq, time.monotonic()
        frames = self._enc.encode("command", q_target=[float(v) for v in q_target], gripper=float(gripper),
                                  deadline=now + validity_s, t_capture=float(t_capture),
                                  session=self._session)
        self.dropped += not send(self._cmd, frames)
        return seq

    def close(self) -> None:
        self._state.sock.close()
        self._cmd.close(linger=200)  # the final hold command must still get out


@dataclass
class Tick:
    """What one tick did: one JSON line of --metrics (monotonic seconds, null = stage not run)."""

    tick: int
    deadline: float
    late: bool = False
    skipped: bool = False
    cmd_seq: int | None = None
    t_capture: float | None = None
    t_receive: float | None = None
    t_preprocess: float | None = None  # = start of inference on inference ticks
    t_inference: float | None = None  # null on ticks that execute an action of an earlier chunk
    t_send: float | None = None
    frame: int | None = None
    hold: bool = False
    status: str | None = None


_EXIT_CODES = ((CameraError, EXIT_CAMERA), (RobotStalled, EXIT_ROBOT), (NotController, EXIT_ROBOT),
               (ActionOutOfBounds, EXIT_ACTION), (PolicyError, EXIT_POLICY))  # first match wins
_FRAME_REJECTIONS = {"stale_frame": "stale_frames", "frame_from_future": "future_frames",
                     "camera_frozen": "frozen_frames", "camera_blind": "blind_frames"}  # code -> its counter
_GIVE_UP = {"camera_stalled": ("camera_give_up_s", CameraStalled),  # code -> (grace setting, error past it)
            **dict.fromkeys(_FRAME_REJECTIONS, ("camera_give_up_s", CameraStalled)),
            "robot_stalled": ("robot_give_up_s", RobotStalled),
            "not_controller": ("controller_give_up_s", NotController),
            "nan_action": ("policy_give_up_s", PolicyError)}


class ControlLoop:
    def __init__(self, policy: Policy, camera: Camera, robot: RobotLink, config: LoopConfig, *,
                 metrics: TextIO | None = None, stop: threading.Event | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.policy, self.camera, self.robot, self.config = policy, camera, robot, config
        self.metrics = metrics
        self.clock = clock  # the cameras, the driver and the metrics share it (tests swap it)
        self.stop = stop or threading.Event()
        self.stack = FrameStack(policy.metadata.obs_horizon)
        self.counts = {"ticks": 0, "late": 0, "skipped": 0, "nan_actions": 0, "rejected_messages": 0,
                       **dict.fromkeys(_FRAME_REJECTIONS.values(), 0)}
        self.faults: dict[str, float] = {}  # active fault code -> when it began
        self._chunk: np.ndarray | None = None
        self._chunk_tick = 0
        self._frame: Frame | None = None
        self._rejection: tuple[str, str] | None = None  # why the newest frame was refused (code, detail)
        self._used_frame = -1
        self._gripper: float | None = None
        self._hold_q: np.ndarray | None = None
        self._driver_fault = ""

    def run(self) -> int:
        """Run until stopped, the time is up or a fatal fault; every exit path ends with a hold command."""
        try:
            self._startup()
            if not self.stop.is_set():  # a signal during start-up: nothing to run, just the final hold
                self._ticks()
            return EXIT_OK
        except CameraEnded as exc:  # the shared .bag (0.17 s) ends during start-up, before any tick
            idle = "" if self.counts["ticks"] else "; it ended before the first tick: nothing was commanded"
            self._report("camera_ended", f"{exc}{idle}")
            return EXIT_OK
        except tuple(kind for kind, _ in _EXIT_CODES) as exc:
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

    def _ticks(self) -> None:
        """Phase-locked to the camera: cutoffs fall between frame arrivals, as far from any as the two rates
        allow (half the common period), so arrival jitter never flips which frame a tick takes."""
        period, camera_period = self.config.period, self.camera.period_s
        due = self._frame.t_receive + camera_period
        while due < self.clock():
            due += camera_period
        ratio = Fraction(period / camera_period).limit_denominator(8)
        t0 = due + camera_period / ratio.denominator / 2 + self.config.work_budget * period
        end = None if self.config.seconds is None else t0 + self.config.seconds
        k = 0
        while not self.stop.is_set() and (end is None or t0 + k * period <= end):
            self._record(self._tick(Tick(k, t0 + k * period)))
            k += 1
            while self._cutoff(t0 + k * period) < self.clock():  # too late to start: skip, never burst
                self._record(Tick(k, t0 + k * period, late=True, skipped=True))
                k += 1

    def _tick(self, tick: Tick) -> Tick:
        meta = self.policy.metadata
        needs_inference = self._chunk is None or tick.tick - self._chunk_tick >= meta.exec_horizon
        frame = self._await_frame(self._cutoff(tick.deadline))
        state, problems = self._robot_state()
        if frame is None:
            problems.update([self._camera_problem()])
        elif not problems:
            tick.t_capture, tick.t_receive, tick.frame = frame.t_capture, frame.t_receive, frame.number
            obs = self.stack.push(preprocess(frame.depth, frame.depth_scale, meta.preprocess,
                                             restore=self.config.restore))
            tick.t_preprocess = self.clock()
            if needs_inference:
                problems = self._infer(obs, state, tick)
        self._update_faults(problems)
        if problems:  # hold, and forget the chunk and frame history the fault made stale
            self._chunk = None
            self.stack.reset()
            tick.hold = True
            return self._send(tick, self._hold_target(), self._hold_gripper())
        action = self._chunk[tick.tick - self._chunk_tick]
        self._hold_q, self._gripper = None, 1.0 if action[DOF] > 0 else -1.0
        return self._send(tick, np.asarray(self.robot.latest["q"], np.float64) + action[:DOF], self._gripper)

    def _cutoff(self, deadline: float) -> float:
        return deadline - self.config.work_budget * self.config.period

    def _await_frame(self, cutoff: float) -> Frame | None:
        """The last frame due by ``cutoff``, the moment it arrives; a late one is awaited up to half a camera
        period. None when the camera stalled: at once when the stall is new, at the cutoff while it lasts."""
        self._take(self.camera.poll(0.0))  # whatever arrived while the last tick was busy
        period = self.camera.period_s
        while not self.stop.is_set():
            now = self.clock()
            stalls_at = self._frame.t_receive + period + self.config.period
            if now > stalls_at:  # one control period past the frame that was due
                if now >= cutoff or self._camera_problem()[0] not in self.faults:
                    return None
                self._take(self.camera.poll(cutoff - now))
                continue
            next_due = self._frame.t_receive + period
            if self._frame.number != self._used_frame and next_due > cutoff:
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
        if frame is not None:
            self._rejection = self._frame_problem(frame)
            if self._rejection is None:
                self._frame = frame
            else:
                self.counts[_FRAME_REJECTIONS[self._rejection[0]]] += 1

    def _frame_problem(self, frame: Frame) -> tuple[str, str] | None:
        age, n, c = frame.t_receive - frame.t_capture, frame.number, self.config
        if age > c.max_frame_age_s:
            return "stale_frame", f"frame {n} arrived {1e3 * age:.0f} ms after its capture"
        if -age > c.max_future_s:
            return "frame_from_future", (f"frame {n} is stamped {-1e3 * age:.0f} ms after it arrived: the "
                                         "camera's clock is wrong")
        if self._frame is not None and n <= self._frame.number:
            return "camera_frozen", f"frame number {n} does not advance past {self._frame.number}"
        valid = np.count_nonzero((frame.depth > 0) & (frame.depth < SATURATED)) / max(frame.depth.size, 1)
        if valid < c.min_valid_fraction:
            return "camera_blind", (f"frame {n} has {100 * valid:.1f} % valid pixels (at least "
                                    f"{100 * c.min_valid_fraction:g} % needed)")
        return None

    def _camera_problem(self) -> tuple[str, str]:
        """Why no usable frame came: the last refused frame's reason, else a plain stall."""
        if self._rejection is not None:
            return self._rejection
        refused, silent = getattr(self.camera, "rejected", 0), self.clock() - self._frame.t_receive
        return "camera_stalled", (f"no frame from {self.camera.name} for {silent:.3f} s"
                                  + (f" ({refused} malformed messages refused so far)" if refused else ""))

    def _robot_state(self) -> tuple[np.ndarray | None, dict[str, str]]:
        """The policy's state input from the newest robot state, or the problems that make it unusable."""
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
        # a broken or hostile policy file must not reach the driver, which would only rate-limit it
        scale, limit = self.policy.metadata.action_scale, self.config.action_limit
        worst = float(np.max(np.abs(chunk[:, :DOF])))
        if not worst <= limit * scale * (1 + 1e-6):  # float32 outputs: a delta at the bound may round up
            raise ActionOutOfBounds(f"policy output a joint delta of {worst:.4g} rad, beyond the bound "
                                    f"{limit * scale:.4g} rad ({limit:g} x action scale {scale:g}): "
                                    "not executed")
        self._chunk, self._chunk_tick, tick.t_inference = chunk, tick.tick, self.clock()
        return {}

    def _hold_target(self) -> np.ndarray | None:
        """The position latched when the fault began (None before any robot state)."""
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
        if q_target is not None:  # never had a robot state: nothing safe to command
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
            self.metrics.write(json.dumps({k: v.item() if isinstance(v, np.generic) else v
                                           for k, v in tick.__dict__.items()}) + "\n")
