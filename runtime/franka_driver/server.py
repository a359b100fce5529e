"""The driver's ZeroMQ server: PUBlishes ``state`` (and ``status`` on faults), PULLs ``command``.

One loop, two clocks: it wakes on every incoming command (so the receive time it records is the real
arrival, not the next control tick) and on every control step (``state_hz``), where the safety layer
decides the target, the backend gets it, and the state goes out. ``status`` messages share the state
socket so a subscriber sees faults in order with the states around them.

Hostile input. Every incoming message is handled on its own: whatever it raises (a malformed header, a
refused command, a bug) costs that message only, is counted in ``rejected`` by status code and is reported
as a ``status`` at most once per ``status_repeat_s`` per code, with the number suppressed since (an unlimited
status per bad message let a garbage flood fill the state socket: 85k statuses in 10 s, state rate -12 %).
One wake drains commands only until the next control step is due, so a flood cannot starve the state
stream. Commands are executed for one sender at a time (``lease.Lease``: session + sequence numbers); with
CurveZMQ only client keys in the ``clients`` folder get through the handshake at all.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from runtime.franka_driver.backend import Backend, BackendError
from runtime.franka_driver.lease import Lease
from runtime.franka_driver.safety import CommandRejected, SafetyConfig, SafetyLayer
from runtime.protocol import (
    DEFAULT_ROBOT,
    Encoder,
    Message,
    ProtocolError,
    decode,
    robot_endpoints,
    session_tag,
)
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
    """A persisting fault is re-announced at most this often."""
    refusal_status_s: float = 0.1
    """A refused message's status code is announced at most this often (a flood of them: 10 statuses/s)."""
    lease_s: float = 1.0
    """The controlling session keeps the arm this long after its last accepted command (``Lease``)."""
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        if not 100.0 <= self.state_hz <= 1000.0:
            raise ValueError(f"state_hz must be in [100, 1000], got {self.state_hz}")
        for name in ("status_repeat_s", "refusal_status_s"):
            if not 0 < getattr(self, name) <= 60:
                raise ValueError(f"{name} must be in (0, 60], got {getattr(self, name)}")
        Lease(self.lease_s)  # raises on a bad lease time
        robot_endpoints(self.bind)  # raises on a malformed address


def check_bind(endpoint: str, keys: CurveKeys | None) -> None:
    """``TransportError`` unless ``endpoint`` is loopback or CurveZMQ keys are given."""
    if keys is None and not is_loopback(endpoint):
        raise TransportError(f"refusing to bind {endpoint} without CurveZMQ keys: it is reachable from "
                             "other hosts; bind 127.0.0.1 or pass --curve-secret")


def allowed_clients(folder: str | Path) -> Path:
    """``folder`` if it holds at least one CurveZMQ public key (``*.key``), else ``TransportError``."""
    path = Path(folder)
    if not path.is_dir() or not any(path.glob("*.key")):
        raise TransportError(f"CurveZMQ client allow-list {path} holds no public key (*.key files from "
                             "zmq.auth.create_certificates): no client could connect")
    return path


class DriverServer:
    """Serve ``backend`` until ``stop`` is set. As a context manager it always leaves the arm holding.

    ``keys`` (CurveZMQ) need ``clients``, the folder of the public keys allowed to connect: encryption without
    an allow-list would let any key pair that knows the server's public key command the arm."""

    def __init__(self, backend: Backend, config: DriverConfig = DriverConfig(), *,
                 on_command: CommandHook | None = None, keys: CurveKeys | None = None,
                 clients: str | Path | None = None, context: zmq.Context | None = None) -> None:
        if keys is not None and clients is None:
            raise TransportError("CurveZMQ keys need an allow-list of client public keys (clients folder)")
        self.backend = backend
        self.config = config
        self.safety = SafetyLayer(backend.tcp, config.safety)
        self.lease = Lease(config.lease_s)
        self.rejected: Counter[str] = Counter()
        """Refused messages by status code, since start."""
        self._on_command = on_command
        self._keys = keys
        self._clients = None if clients is None else allowed_clients(clients)
        self._ctx = context or zmq.Context.instance()
        self._auth = None
        self._encoder = Encoder()
        self._fault = ""
        self._announced: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()
        self._pub: zmq.Socket | None = None
        self._pull: zmq.Socket | None = None
        self.steps = 0

    def __enter__(self) -> DriverServer:
        state_ep, command_ep = robot_endpoints(self.config.bind)
        try:
            self._start_authenticator()
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
            if self._auth is not None:
                self._auth.stop()
                self._auth = None

    def _start_authenticator(self) -> None:
        """ZeroMQ's ZAP handler on this context: the CURVE handshake succeeds only for allowed keys."""
        if self._keys is None:
            return
        from zmq.auth.thread import ThreadAuthenticator

        self._auth = ThreadAuthenticator(self._ctx)
        self._auth.start()
        self._auth.configure_curve(domain="*", location=str(self._clients))

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
                self._drain_commands(until=next_step)
            now = time.monotonic()
            if now >= next_step:
                try:
                    self.control_step(now, period)
                except BackendError as exc:
                    self._announce("backend_error", str(exc), force=True)
                    raise
                # Absolute schedule; after a stall, restart from now instead of bursting to catch up.
                next_step = next_step + period if next_step + period > now else now + period

    def _drain_commands(self, until: float) -> None:
        """Take what is pending, but no longer than until the next control step is due."""
        while True:
            try:
                frames = self._pull.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            self.handle(frames, time.monotonic())
            if time.monotonic() >= until:
                return

    def handle(self, frames: list[Any], t_receive: float) -> None:
        """One incoming message: execute it or refuse it. Never raises: a refusal, whatever its cause, is
        counted and reported (rate-limited) and the driver goes on with the next message."""
        try:
            self._execute(decode(frames), _client_key(frames), t_receive)
        except CommandRejected as exc:
            self._refuse(exc.code, exc.detail)
        except ProtocolError as exc:
            self._refuse("bad_message", str(exc))
        except Exception as exc:  # a bug must cost one message, not the arm's driver
            self._refuse("handler_error", f"{type(exc).__name__} while handling a message")

    def _execute(self, msg: Message, client: str, t_receive: float) -> None:
        if msg.kind != "command":
            raise CommandRejected("wrong_kind", f"driver accepts 'command' messages, got {msg.kind!r}")
        sender = f"{client}/{msg['session']}"
        self.lease.check(sender, msg["seq"], t_receive)
        self.safety.accept(q_target=np.asarray(msg["q_target"]), gripper=msg["gripper"],
                           deadline=msg["deadline"], now=t_receive)
        if self.lease.renew(sender, msg["seq"], t_receive):
            self._announce("controller", f"session {session_tag(msg['session'])} now controls the arm",
                           force=True)
        if self._on_command is not None:
            self._on_command({"seq": msg["seq"], "t_send": msg["t_send"], "t_capture": msg["t_capture"],
                              "deadline": msg["deadline"], "t_receive": t_receive})

    def _refuse(self, code: str, detail: str) -> None:
        self.rejected[code] += 1
        self._announce(code, detail, every=self.config.refusal_status_s)

    def control_step(self, now: float, dt: float) -> None:
        """Read the robot, let the safety layer decide, command the backend, publish the state."""
        reading = self.backend.read()
        step = self.safety.step(q_measured=reading.q, now=now, dt=dt)
        self.backend.command(q_target=step.q_target, gripper_closed=step.gripper_closed)
        for code in step.faults:
            self._announce(code, _FAULT_TEXT.get(code, code))
        if not step.holding and not step.faults:
            self._fault = ""
        controller = session_tag(self.lease.holder.partition("/")[2]) if self.lease.live(now) else ""
        self._pub.send_multipart(self._encoder.encode(
            "state", t_capture=reading.t, q=reading.q.tolist(), dq=reading.dq.tolist(),
            gripper=float(reading.gripper_width), holding=step.holding, fault=self._fault,
            controller=controller))
        self.steps += 1

    def _announce(self, code: str, detail: str, *, force: bool = False, every: float | None = None) -> None:
        """Publish a status, at most once per ``every`` seconds (default ``status_repeat_s``) per code unless
        forced; the next one says how many were suppressed meanwhile."""
        if code not in _NOT_FAULTS:
            self._fault = code
        now = time.monotonic()
        last = self._announced.get(code, -math.inf)
        if not force and now - last < (every or self.config.status_repeat_s):
            self._suppressed[code] += 1
            return
        self._announced[code] = now
        more = self._suppressed.pop(code, 0)
        if more:
            detail = f"{detail[:400]} (+{more} more like it in the last {now - last:.2f} s)"
        if self._pub is not None:
            self._pub.send_multipart(self._encoder.encode("status", code=code, detail=detail[:500]))


def _client_key(frames: list[Any]) -> str:
    """The CurveZMQ key the authenticator verified for this message's sender; "" without CurveZMQ."""
    try:
        return frames[0].get("User-Id") or ""
    except (AttributeError, IndexError, zmq.ZMQError):  # plain bytes (tests) or no ZAP metadata
        return ""


_NOT_FAULTS = frozenset({"controller", "bad_message", "wrong_kind", "not_controller", "out_of_order",
                         "handler_error"})
"""Status codes about a message or a sender, not about the arm: they never set the state's ``fault``, so a
stranger's garbage does not show up as a fault of the controlling runtime's arm."""

_FAULT_TEXT = {
    "command_timeout": "no live command: holding position",
    "joint_limit": "command clipped to the joint limits minus margin",
    "workspace": "command would take the end-effector out of the workspace box: refused",
}
