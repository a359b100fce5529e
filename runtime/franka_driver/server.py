"""The driver's ZeroMQ server: PUBlishes ``state`` (and ``status`` on faults), PULLs ``command``.

One loop, two clocks: it wakes on every incoming command (recording its real arrival) and on every control
step (``state_hz``), where the safety layer decides the target, the backend gets it and the state goes out.
``status`` messages share the state socket, so a subscriber sees faults in order with the states around them.

Hostile input. Whatever a message raises (bad header, refused command, a bug) costs that message only: it is
counted in ``rejected`` by status code and reported at most once per ``refusal_status_s`` per code, with the
number suppressed since (a status per bad message let a garbage flood fill the state socket: 85k statuses in
10 s, state rate -12 %). One wake drains commands only until the next control step is due, so a flood cannot
starve the state stream. Commands are executed for one sender at a time (``lease.Lease``); with CurveZMQ only
client keys in the ``clients`` folder get through the handshake at all.
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
from runtime.protocol import DEFAULT_ROBOT, Encoder, ProtocolError, decode, robot_endpoints, session_tag
from runtime.transport import CurveKeys, TransportError, bind

NOT_FAULTS = frozenset({"controller", "bad_message", "wrong_kind", "not_controller", "out_of_order",
                        "handler_error"})
"""Status codes about a message or a sender, not the arm: they never set the state's ``fault``, so a
stranger's garbage does not show up as a fault of the controlling runtime's arm."""
FAULT_TEXT = {"command_timeout": "no live command: holding position",
              "joint_limit": "command clipped to the joint limits minus margin",
              "workspace": "command would take the end-effector out of the workspace box: refused"}


@dataclass(frozen=True)
class DriverConfig:
    """How the driver serves the robot."""

    bind: str = DEFAULT_ROBOT  # state endpoint (PUB); commands are PULLed on its port + 1
    state_hz: float = 200.0  # control-step and state-publish rate (the contract asks >= 100 Hz)
    max_message_bytes: int = 65536  # ZeroMQ disconnects a peer that sends more; commands are ~300 bytes
    status_repeat_s: float = 1.0  # a persisting fault is re-announced at most this often
    refusal_status_s: float = 0.1  # a refused message's status code is announced at most this often
    lease_s: float = 1.0  # the controlling session keeps the arm this long after its last accepted command
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        if not 100.0 <= self.state_hz <= 1000.0:
            raise ValueError(f"state_hz must be in [100, 1000], got {self.state_hz}")
        for name in ("status_repeat_s", "refusal_status_s"):
            if not 0 < getattr(self, name) <= 60:
                raise ValueError(f"{name} must be in (0, 60], got {getattr(self, name)}")
        Lease(self.lease_s)  # raises on a bad lease time
        robot_endpoints(self.bind)  # raises on a malformed address


def allowed_clients(folder: str | Path) -> Path:
    """``folder`` if it holds at least one CurveZMQ public key (``*.key``), else ``TransportError``."""
    path = Path(folder)
    if not path.is_dir() or not any(path.glob("*.key")):
        raise TransportError(f"CurveZMQ client allow-list {path} holds no public key (*.key files from "
                             "zmq.auth.create_certificates): no client could connect")
    return path


class DriverServer:
    """Serve ``backend`` until ``stop`` is set; as a context manager it always leaves the arm holding.
    ``keys`` (CurveZMQ) need ``clients``, the folder of allowed public keys: without an allow-list any key
    pair that knows the server's public key could command the arm. ``on_command`` gets each executed
    command's times (the HIL benchmark's latency)."""

    def __init__(self, backend: Backend, config: DriverConfig = DriverConfig(), *,
                 on_command: Callable[[dict[str, Any]], None] | None = None, keys: CurveKeys | None = None,
                 clients: str | Path | None = None, context: zmq.Context | None = None) -> None:
        if keys is not None and clients is None:
            raise TransportError("CurveZMQ keys need an allow-list of client public keys (clients folder)")
        self.backend, self.config = backend, config
        self.safety = SafetyLayer(backend.tcp, config.safety)
        self.lease = Lease(config.lease_s)
        self.rejected: Counter[str] = Counter()  # refused messages by status code
        self.steps = 0
        self._on_command, self._keys = on_command, keys
        self._clients = None if clients is None else allowed_clients(clients)
        self._ctx = context or zmq.Context.instance()
        self._auth = self._pub = self._pull = None
        self._encoder = Encoder()
        self._fault = ""
        self._announced: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()

    def __enter__(self) -> DriverServer:
        state_ep, command_ep = robot_endpoints(self.config.bind)
        try:
            if self._keys is not None:  # ZeroMQ's ZAP handler: only allowed keys complete the handshake
                from zmq.auth.thread import ThreadAuthenticator

                self._auth = ThreadAuthenticator(self._ctx)
                self._auth.start()
                self._auth.configure_curve(domain="*", location=str(self._clients))
            self._pub = bind(self._ctx, zmq.PUB, state_ep, keys=self._keys, queue=16)
            self._pull = bind(self._ctx, zmq.PULL, command_ep, keys=self._keys, queue=16,
                              max_bytes=self.config.max_message_bytes)
        except BaseException:
            self.__exit__()
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
            if self._auth is not None:
                self._auth.stop()
            self._auth = self._pub = self._pull = None

    def serve(self, stop: threading.Event) -> None:
        """Run control steps at ``state_hz`` and take commands as they come, until ``stop`` is set."""
        if self._pull is None:
            raise RuntimeError("DriverServer.serve() must run inside 'with DriverServer(...)'")
        period = 1.0 / self.config.state_hz
        poller = zmq.Poller()
        poller.register(self._pull, zmq.POLLIN)
        next_step = time.monotonic()
        while not stop.is_set():
            if poller.poll(math.ceil(max(0.0, next_step - time.monotonic()) * 1e3)):
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
            msg = decode(frames)
            if msg.kind != "command":
                raise CommandRejected("wrong_kind", f"driver accepts 'command' messages, got {msg.kind!r}")
            sender = f"{_client_key(frames)}/{msg['session']}"
            self.lease.check(sender, msg["seq"], t_receive)
            self.safety.accept(q_target=np.asarray(msg["q_target"]), gripper=msg["gripper"],
                               deadline=msg["deadline"], now=t_receive)
            if self.lease.renew(sender, msg["seq"], t_receive):
                self._announce("controller", f"session {session_tag(msg['session'])} now controls the arm",
                               force=True)
            if self._on_command is not None:
                self._on_command({"seq": msg["seq"], "t_send": msg["t_send"], "t_capture": msg["t_capture"],
                                  "deadline": msg["deadline"], "t_receive": t_receive})
        except CommandRejected as exc:
            self._refuse(exc.code, exc.detail)
        except ProtocolError as exc:
            self._refuse("bad_message", str(exc))
        except Exception as exc:  # a bug must cost one message, not the arm's driver
            self._refuse("handler_error", f"{type(exc).__name__} while handling a message")

    def _refuse(self, code: str, detail: str) -> None:
        self.rejected[code] += 1
        self._announce(code, detail, every=self.config.refusal_status_s)

    def control_step(self, now: float, dt: float) -> None:
        """Read the robot, let the safety layer decide, command the backend, publish the state."""
        reading = self.backend.read()
        step = self.safety.step(q_measured=reading.q, now=now, dt=dt)
        self.backend.command(q_target=step.q_target, gripper_closed=step.gripper_closed)
        for code in step.faults:
            self._announce(code, FAULT_TEXT.get(code, code))
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
        if code not in NOT_FAULTS:
            self._fault = code
        now = time.monotonic()
        last = self._announced.get(code, -math.inf)
        if not force and now - last < (every or self.config.status_repeat_s):
            self._suppressed[code] += 1
            return
        self._announced[code] = now
        if more := self._suppressed.pop(code, 0):
            detail = f"{detail[:400]} (+{more} more like it in the last {now - last:.2f} s)"
        if self._pub is not None:
            self._pub.send_multipart(self._encoder.encode("status", code=code, detail=detail[:500]))


def _client_key(frames: list[Any]) -> str:
    """The CurveZMQ key the authenticator verified for this message's sender; "" without CurveZMQ."""
    try:
        return frames[0].get("User-Id") or ""
    except (AttributeError, IndexError, zmq.ZMQError):  # plain bytes (tests) or no ZAP metadata
        return ""
