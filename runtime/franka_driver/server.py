"""The driver's ZeroMQ server: PUBlishes ``state`` (and ``status`` on faults), PULLs ``command``.

One loop, two clocks: it wakes on every incoming command (so the receive time it records is the real
arrival, not the next control tick) and on every control step (``state_hz``), where the safety layer
decides the target, the backend gets it, and the state goes out. ``status`` messages share the state
socket so a subscriber sees faults in order with the states around them.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zmq

from runtime.franka_driver.backend import Backend, BackendError
from runtime.franka_driver.safety import CommandRejected, SafetyConfig, SafetyLayer
from runtime.protocol import DEFAULT_ROBOT, Encoder, ProtocolError, decode, robot_endpoints
from runtime.transport import CurveKeys, TransportError, is_loopback

CommandHook = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class DriverConfig:
    """How the driver serves the robot."""

    bind: str = DEFAULT_ROBOT
    """State endpoint (PUB); commands are PULLed on its port + 1. Loopback unless you say otherwise."""
    state_hz: float = 200.0
    """Control-step and state-publish rate (the contract asks >= 100 Hz)."""
    max_message_bytes: int = 65536
    """ZeroMQ disconnects a peer that sends a bigger frame; commands are ~300 bytes."""
    status_repeat_s: float = 1.0
    """A fault that persists is re-announced at most this often."""
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        if not 100.0 <= self.state_hz <= 1000.0:
            raise ValueError(f"state_hz must be in [100, 1000], got {self.state_hz}")
        robot_endpoints(self.bind)  # raises on a malformed address


def check_bind(endpoint: str, keys: CurveKeys | None) -> None:
    """``TransportError`` unless ``endpoint`` is loopback or CurveZMQ keys are given."""
    if keys is None and not is_loopback(endpoint):
        raise TransportError(f"refusing to bind {endpoint} without CurveZMQ keys: it is reachable from "
                             "other hosts; bind 127.0.0.1 or pass --curve-secret")


class DriverServer:
    """Serve ``backend`` until ``stop`` is set. As a context manager it always leaves the arm holding."""

    def __init__(self, backend: Backend, config: DriverConfig = DriverConfig(), *,
                 on_command: CommandHook | None = None, keys: CurveKeys | None = None,
                 context: zmq.Context | None = None) -> None:
        self.backend = backend
        self.config = config
        self.safety = SafetyLayer(backend.tcp, config.safety)
        self._on_command = on_command
        self._keys = keys
        self._ctx = context or zmq.Context.instance()
        self._encoder = Encoder()
        self._fault = ""
        self._announced: dict[str, float] = {}
        self._pub: zmq.Socket | None = None
        self._pull: zmq.Socket | None = None
        self.steps = 0

    def __enter__(self) -> DriverServer:
        state_ep, command_ep = robot_endpoints(self.config.bind)
        try:
            self._pub = self._socket(zmq.PUB, state_ep)
            self._pull = self._socket(zmq.PULL, command_ep)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.safety.hold()
            self.backend.hold()
        finally:
            for sock in (self._pub, self._pull):
                if sock is not None:
                    sock.close(linger=0)
            self._pub = self._pull = None

    def _socket(self, kind: int, endpoint: str) -> zmq.Socket:
        # Not transport.bind: MAXMSGSIZE must be set before bind() for the listener to apply it.
        check_bind(endpoint, self._keys)
        sock = self._ctx.socket(kind)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SNDHWM if kind == zmq.PUB else zmq.RCVHWM, 16)
        sock.setsockopt(zmq.MAXMSGSIZE, self.config.max_message_bytes)
        if self._keys is not None:
            sock.curve_secretkey, sock.curve_publickey, sock.curve_server = (
                self._keys.secret, self._keys.public, True)
        try:
            sock.bind(endpoint)
        except zmq.ZMQError as exc:
            sock.close()
            raise TransportError(f"driver cannot bind {endpoint}: {exc}") from None
        return sock

    def serve(self, stop: threading.Event) -> None:
        """Run control steps at ``state_hz`` and take commands as they come, until ``stop`` is set."""
        if self._pull is None:
            raise RuntimeError("DriverServer.serve() must run inside 'with DriverServer(...)'")
        period = 1.0 / self.config.state_hz
        poller = zmq.Poller()
        poller.register(self._pull, zmq.POLLIN)
        next_step = time.monotonic()
        while not stop.is_set():
            wait_ms = max(0.0, next_step - time.monotonic()) * 1e3
            if poller.poll(math.ceil(wait_ms)):
                self._drain_commands()
            now = time.monotonic()
            if now >= next_step:
                try:
                    self.control_step(now, period)
                except BackendError as exc:
                    self._announce("backend_error", str(exc), force=True)
                    raise
                # Absolute schedule; after a stall, restart from now instead of bursting to catch up.
                next_step = next_step + period if next_step + period > now else now + period

    def _drain_commands(self) -> None:
        while True:
            try:
                frames = self._pull.recv_multipart(zmq.NOBLOCK, copy=True)
            except zmq.Again:
                return
            self.handle(frames, time.monotonic())

    def handle(self, frames: list[bytes], t_receive: float) -> None:
        """Validate one incoming message and hand it to the safety layer; faults become ``status``."""
        try:
            msg = decode(frames)
            if msg.kind != "command":
                raise CommandRejected("wrong_kind", f"driver accepts 'command' messages, got {msg.kind!r}")
            self.safety.accept(q_target=np.asarray(msg["q_target"]), gripper=msg["gripper"],
                               deadline=msg["deadline"], now=t_receive)
        except ProtocolError as exc:
            self._announce("bad_message", str(exc), force=True)
            return
        except CommandRejected as exc:
            self._announce(exc.code, exc.detail, force=True)
            return
        if self._on_command is not None:
            self._on_command({"seq": msg["seq"], "t_send": msg["t_send"], "t_capture": msg["t_capture"],
                              "deadline": msg["deadline"], "t_receive": t_receive})

    def control_step(self, now: float, dt: float) -> None:
        """Read the robot, let the safety layer decide, command the backend, publish the state."""
        reading = self.backend.read()
        step = self.safety.step(q_measured=reading.q, now=now, dt=dt)
        self.backend.command(q_target=step.q_target, gripper_closed=step.gripper_closed)
        for code in step.faults:
            self._announce(code, _FAULT_TEXT.get(code, code))
        if not step.holding and not step.faults:
            self._fault = ""
        self._pub.send_multipart(self._encoder.encode(
            "state", t_capture=reading.t, q=reading.q.tolist(), dq=reading.dq.tolist(),
            gripper=float(reading.gripper_width), holding=step.holding, fault=self._fault))
        self.steps += 1

    def _announce(self, code: str, detail: str, *, force: bool = False) -> None:
        self._fault = code
        now = time.monotonic()
        if not force and now - self._announced.get(code, -math.inf) < self.config.status_repeat_s:
            return
        self._announced[code] = now
        if self._pub is not None:
            self._pub.send_multipart(self._encoder.encode("status", code=code, detail=detail[:500]))


_FAULT_TEXT = {
    "command_timeout": "no live command: holding position",
    "joint_limit": "command clipped to the joint limits minus margin",
    "workspace": "command would take the end-effector out of the workspace box: refused",
}
