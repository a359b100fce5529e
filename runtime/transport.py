"""ZeroMQ sockets for the runtime, the driver and hil_sim.

Loopback is the default and needs nothing. Any other endpoint crosses a network: binding or connecting to it
requires CurveZMQ keys (encryption + server authentication). Sockets get linger 0: no hang on exit.

Subscribers keep only the newest message (``Newest``): ``zmq.CONFLATE`` breaks two-frame messages, so it
drains what is pending and keeps the last valid one. ZeroMQ refills a full queue from the kernel's TCP buffer
only as it is read, so a queue shorter than what arrives between two reads builds a backlog of old messages
(a 4-deep queue read every 100 ms under 200 Hz states fell 3 s behind in 6 s, measured): a subscriber's
``queue`` must hold what arrives between reads.
"""

from __future__ import annotations

import ipaddress
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth

from runtime.protocol import Message, ProtocolError, decode


class TransportError(ValueError):
    """An endpoint or key setup the transport refuses; the text names the endpoint."""


@dataclass(frozen=True)
class CurveKeys:
    """A CurveZMQ identity: this side's key pair, plus the server's public key when connecting."""

    public: bytes
    secret: bytes
    server_public: bytes | None = None

    @classmethod
    def generate(cls, server_public: bytes | None = None) -> CurveKeys:
        return cls(*zmq.curve_keypair(), server_public)

    @classmethod
    def from_files(cls, secret_file: str | Path, server_public_file: str | Path | None = None) -> CurveKeys:
        """Load ``zmq.auth.create_certificates`` files: ours (``.key_secret``), the server's ``.key``."""
        try:
            public, secret = zmq.auth.load_certificate(str(secret_file))
            server = zmq.auth.load_certificate(str(server_public_file))[0] if server_public_file else None
        except (OSError, ValueError) as exc:
            raise TransportError(f"cannot load CurveZMQ keys: {exc}") from None
        if secret is None:
            raise TransportError(f"{secret_file} holds no secret key (need the .key_secret file)")
        return cls(public, secret, server)


def is_loopback(endpoint: str) -> bool:
    """True for endpoints that cannot leave this host: ipc://, inproc://, tcp:// on a loopback address."""
    scheme, _, rest = endpoint.partition("://")
    if scheme in ("ipc", "inproc"):
        return True
    if scheme != "tcp" or not rest:
        raise TransportError(f"unsupported endpoint {endpoint!r}; use tcp://HOST:PORT, ipc:// or inproc://")
    host = rest.rpartition(":")[0].strip("[]")
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a hostname, an interface name or '*': all may be reachable from outside


def check_bind(endpoint: str, keys: CurveKeys | None) -> None:
    """``TransportError`` unless ``endpoint`` is loopback or CurveZMQ keys are given."""
    if keys is None and not is_loopback(endpoint):
        raise TransportError(f"refusing to bind {endpoint} without CurveZMQ keys: it is reachable from other "
                             "hosts; bind 127.0.0.1 or give keys (--curve-secret)")


def bind(ctx: zmq.Context, socket_type: int, endpoint: str, *, keys: CurveKeys | None = None, queue: int = 4,
         max_bytes: int = -1) -> zmq.Socket:
    """A socket bound at ``endpoint`` (CurveZMQ server keys unless loopback); a peer sending a frame over
    ``max_bytes`` is disconnected."""
    check_bind(endpoint, keys)
    sock = _socket(ctx, socket_type, queue)
    sock.maxmsgsize = max_bytes  # before bind(), or the listener does not apply it
    if keys is not None:
        sock.curve_secretkey, sock.curve_publickey, sock.curve_server = keys.secret, keys.public, True
    return _attach(sock, sock.bind, endpoint)


def connect(ctx: zmq.Context, socket_type: int, endpoint: str, *, keys: CurveKeys | None = None,
            queue: int = 4) -> zmq.Socket:
    """A socket connected to ``endpoint``; CurveZMQ client keys (with the server's key) unless loopback."""
    if keys is None and not is_loopback(endpoint):
        raise TransportError(f"refusing to connect to {endpoint} without CurveZMQ keys: traffic would leave "
                             "this host unauthenticated")
    if keys is not None and keys.server_public is None:
        raise TransportError(f"connecting to {endpoint} with CurveZMQ needs the server's public key")
    sock = _socket(ctx, socket_type, queue)
    if keys is not None:
        sock.curve_secretkey, sock.curve_publickey = keys.secret, keys.public
        sock.curve_serverkey = keys.server_public
    return _attach(sock, sock.connect, endpoint)


def _socket(ctx: zmq.Context, socket_type: int, queue: int) -> zmq.Socket:
    """``queue``: the high-water mark, in messages, of the direction the socket carries."""
    sock = ctx.socket(socket_type)
    sock.linger = 0
    if socket_type in (zmq.SUB, zmq.PULL):
        sock.rcvhwm = queue
    else:
        sock.sndhwm = queue
    if socket_type == zmq.SUB:
        sock.setsockopt(zmq.SUBSCRIBE, b"")
    if socket_type == zmq.PUSH:
        sock.immediate = True  # never queue commands for a driver that is not connected: they would go stale
    return sock


def _attach(sock: zmq.Socket, how: Callable[[str], None], endpoint: str) -> zmq.Socket:
    try:
        how(endpoint)
    except zmq.ZMQError as exc:
        sock.close()
        raise TransportError(f"cannot use endpoint {endpoint}: {exc}") from None
    return sock


def send(sock: zmq.Socket, frames: list[bytes]) -> bool:
    """Send without blocking; False when no peer can take it now (the caller counts it, never waits)."""
    try:
        sock.send_multipart(frames, flags=zmq.NOBLOCK, copy=False)
    except zmq.Again:
        return False
    return True


class Newest:
    """Newest-message-only reader of one message kind on a SUB socket. Malformed messages are counted
    (``rejected``, ``last_error``), never raised: a bad peer must not take the control loop down. Valid
    messages of other kinds (the driver's ``status`` on its state socket) are skipped."""

    def __init__(self, sock: zmq.Socket, kind: str) -> None:
        self.sock, self.kind = sock, kind
        self.rejected = 0
        self.last_error = ""
        self._poller = zmq.Poller()
        self._poller.register(sock, zmq.POLLIN)

    def poll(self, timeout_s: float) -> tuple[Message, float] | None:
        """Wait up to ``timeout_s`` for traffic, drain it all, return (newest valid message, receive time)."""
        deadline = time.monotonic() + max(timeout_s, 0.0)
        while (newest := self.drain()) is None and (remaining := deadline - time.monotonic()) > 0:
            self._poller.poll(max(1, round(remaining * 1000)))
        return newest

    def drain(self) -> tuple[Message, float] | None:
        """Everything pending, without waiting; the newest valid message or None."""
        newest = None
        while True:
            try:
                frames = self.sock.recv_multipart(flags=zmq.NOBLOCK)
            except zmq.Again:
                return newest
            t_receive = time.monotonic()
            try:
                msg = decode(frames)
            except Exception as exc:  # decode raises only ProtocolError; anything else costs one message too
                self.rejected += 1
                self.last_error = str(exc)[:200] if isinstance(exc, ProtocolError) else type(exc).__name__
                continue
            if msg.kind == self.kind:
                newest = (msg, t_receive)
