"""ZeroMQ socket helpers shared by the runtime, franka_driver and hil_sim.

Loopback is the default and needs nothing. Any other endpoint crosses a network, so binding or connecting to
it requires CurveZMQ keys (encryption + server authentication) and is refused without them. Sockets get
linger 0 so a process never hangs on exit over unsent messages.

Subscribers keep only the newest message: ``zmq.CONFLATE`` breaks our two-frame messages, and a high-water
mark of 1 alone still hands out the oldest queued message, so ``Newest`` drains everything pending and keeps
the last valid one. Draining only sees what ZeroMQ has moved into the socket's queue, and ZeroMQ refills a
full queue from the kernel's TCP buffer only as it is read, so a queue shorter than the messages arriving
between two reads lets a backlog of old messages build up behind it (a 4-deep queue read every 100 ms under a
200 Hz state stream fell 3 s behind in 6 s, measured). A subscriber's ``queue`` must therefore hold what
arrives between reads; it is small only for big messages that come slower than they are read (depth).
"""

from __future__ import annotations

import ipaddress
import time
from collections import deque
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
    """Z85 public key of the server a client connects to; unused when binding."""

    @classmethod
    def generate(cls, server_public: bytes | None = None) -> CurveKeys:
        public, secret = zmq.curve_keypair()
        return cls(public, secret, server_public)

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
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a hostname, an interface name or '*': all may be reachable from outside


def bind(ctx: zmq.Context, socket_type: int, endpoint: str, *, keys: CurveKeys | None = None) -> zmq.Socket:
    """A socket bound at ``endpoint``; CurveZMQ server keys are required unless it is loopback."""
    sock = _socket(ctx, socket_type)
    if keys is not None:
        sock.curve_secretkey, sock.curve_publickey, sock.curve_server = keys.secret, keys.public, True
    elif not is_loopback(endpoint):
        sock.close()
        raise TransportError(f"refusing to bind {endpoint} without CurveZMQ keys: it is reachable from other "
                             "hosts; bind 127.0.0.1 or pass keys (CurveKeys.from_files)")
    return _attach(sock, sock.bind, endpoint)


def connect(ctx: zmq.Context, socket_type: int, endpoint: str, *, keys: CurveKeys | None = None,
            queue: int = 4) -> zmq.Socket:
    """A socket connected to ``endpoint``; CurveZMQ client keys (with the server's key) unless loopback.
    ``queue``: a SUB socket's receive high-water mark, in messages (see the module text)."""
    sock = _socket(ctx, socket_type, queue)
    if keys is not None:
        if keys.server_public is None:
            sock.close()
            raise TransportError(f"connecting to {endpoint} with CurveZMQ needs the server's public key")
        sock.curve_secretkey, sock.curve_publickey = keys.secret, keys.public
        sock.curve_serverkey = keys.server_public
    elif not is_loopback(endpoint):
        sock.close()
        raise TransportError(f"refusing to connect to {endpoint} without CurveZMQ keys: traffic would leave "
                             "this host unauthenticated")
    return _attach(sock, sock.connect, endpoint)


def _socket(ctx: zmq.Context, socket_type: int, queue: int = 4) -> zmq.Socket:
    sock = ctx.socket(socket_type)
    sock.linger = 0
    if socket_type == zmq.SUB:
        sock.rcvhwm = queue
        sock.setsockopt(zmq.SUBSCRIBE, b"")
    if socket_type in (zmq.PUSH, zmq.PUB):
        sock.sndhwm = 4
    if socket_type == zmq.PUSH:
        sock.immediate = True  # never queue commands for a driver that is not connected: they would go stale
    return sock


def _attach(sock: zmq.Socket, how, endpoint: str) -> zmq.Socket:
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
    """Newest-message-only reader of one message kind on a SUB socket.

    Malformed messages are counted and remembered (``rejected``, ``last_error``), never raised: a bad peer
    must not take the control loop down. Valid messages of other kinds (e.g. the driver's ``status`` on its
    state socket) are kept aside in ``others``, newest last.
    """

    def __init__(self, sock: zmq.Socket, kind: str) -> None:
        self.sock, self.kind = sock, kind
        self.rejected = 0
        self.last_error = ""
        self.received = 0
        self.others: deque[Message] = deque(maxlen=16)
        self._poller = zmq.Poller()
        self._poller.register(sock, zmq.POLLIN)

    def poll(self, timeout_s: float) -> tuple[Message, float] | None:
        """Wait up to ``timeout_s`` for traffic, drain it all, return (newest valid message, receive time)."""
        deadline = time.monotonic() + max(timeout_s, 0.0)
        while True:
            newest = self.drain()
            remaining = deadline - time.monotonic()
            if newest is not None or remaining <= 0:
                return newest
            self._poller.poll(max(1, round(remaining * 1000)))

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
            if msg.kind != self.kind:
                self.others.append(msg)
                continue
            self.received += 1
            newest = (msg, t_receive)
