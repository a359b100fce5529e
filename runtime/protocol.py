"""Wire protocol between camera, runtime and franka_driver (contract; see DESIGN.md).

A message is two ZeroMQ frames: a small msgpack header (a map) and a raw payload (bytes, may be empty).
Depth travels as the raw uint16 buffer in the payload: no per-pixel encoding. Every header carries

    v        schema version (``VERSION``); a peer that speaks another version is refused
    kind     one of ``KINDS``
    seq      sequence number, per sender, +1 per message
    t_send   sender's ``time.monotonic()`` when it sent

plus the fields of its kind (``_FIELDS``); fields a kind does not declare are dropped on decode.
Timestamps are CLOCK_MONOTONIC seconds: comparable between processes on one host (loopback, the default).

``decode`` turns anything malformed, truncated, oversized or of another version into a ``ProtocolError``
naming the problem; it never raises anything else, and its error text shows untrusted values only cut to a
bounded size (containers by type and length alone: ``repr`` of a list nested ~1,000 deep raised
RecursionError and took the reading process down).

Version 2 added the controller session: every ``command`` names the ``session`` (a secret random token of the
runtime process that sent it), and every ``state`` names the ``controller``, the public ``session_tag`` of
the session whose commands the driver is executing ("" when none).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

VERSION = 2
MAX_HEADER_BYTES = 4096
MAX_TEXT = 512
"""Longest string field; the header limit bounds them anyway, this keeps one field from filling it."""
MAX_PAYLOAD_BYTES = 1280 * 720 * 2  # the largest D455 depth frame
DOF = 7


class ProtocolError(ValueError):
    """A message that cannot be accepted. The text says which field and why."""


def _num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _vec(n: int):
    def check(x: Any) -> bool:
        return isinstance(x, (list, tuple)) and len(x) == n and all(_num(v) for v in x)
    check.__doc__ = f"a list of {n} finite numbers"
    return check


def _text(max_len: int, min_len: int = 0):
    def check(x: Any) -> bool:
        return isinstance(x, str) and min_len <= len(x) <= max_len
    check.__doc__ = f"a string of {min_len}..{max_len} characters"
    return check


def _BOOL(x: Any) -> bool:
    return isinstance(x, bool)


_num.__doc__ = "a finite number"
_int.__doc__ = "an integer"
_BOOL.__doc__ = "a boolean"
_STR = _text(MAX_TEXT)
SESSION_CHARS = (16, 64)
"""Length range of a command's ``session`` token (``RobotLink`` draws 32 hex characters)."""

_COMMON = {"v": _int, "kind": _STR, "seq": _int, "t_send": _num}
_FIELDS: dict[str, dict[str, Any]] = {
    # Camera -> runtime. Payload: height*width uint16 little-endian, sensor units of depth_scale metres.
    "depth": {"t_capture": _num, "frame": _int, "width": _int, "height": _int, "depth_scale": _num},
    # Driver -> runtime, >= 100 Hz. gripper: opening width in metres (0 closed .. 0.08 open).
    # controller: session_tag of the session holding the driver's command lease, "" when none.
    "state": {"t_capture": _num, "q": _vec(DOF), "dq": _vec(DOF), "gripper": _num, "holding": _BOOL,
              "fault": _STR, "controller": _STR},
    # Runtime -> driver. gripper: -1 open / +1 close. deadline: monotonic time after which it is stale.
    # t_capture: capture time of the newest depth frame behind it (for latency accounting).
    # session: the sender's secret token; the driver executes one session at a time, seq increasing.
    "command": {"t_capture": _num, "q_target": _vec(DOF), "gripper": _num, "deadline": _num,
                "session": _text(SESSION_CHARS[1], SESSION_CHARS[0])},
    # Anyone -> anyone: a named condition (e.g. camera_stalled, late_tick, nan_action) and free text.
    "status": {"code": _STR, "detail": _STR},
}
KINDS = tuple(_FIELDS)


def session_tag(session: str) -> str:
    """The public name of a session, as ``state`` messages show it. A hash, because the state stream is
    readable by every local process and the session itself is what entitles a sender to move the arm."""
    return hashlib.sha256(session.encode()).hexdigest()[:16]


@dataclass
class Message:
    """A decoded message: its header fields and raw payload."""

    header: dict[str, Any]
    payload: bytes = b""

    @property
    def kind(self) -> str:
        return self.header["kind"]

    def __getitem__(self, key: str) -> Any:
        return self.header[key]

    def depth(self) -> np.ndarray:
        """The payload of a ``depth`` message as a uint16 [height, width] array (a read-only view)."""
        if self.kind != "depth":
            raise ProtocolError(f"a {self.kind} message carries no depth")
        return np.frombuffer(self.payload, dtype="<u2").reshape(self.header["height"], self.header["width"])


@dataclass
class Encoder:
    """Builds outgoing messages for one sender, numbering them."""

    seq: int = field(default=0)

    def encode(self, kind: str, payload: bytes = b"", **fields: Any) -> list[bytes]:
        header = {"v": VERSION, "kind": kind, "seq": self.seq, "t_send": time.monotonic(), **fields}
        _validate(header, len(payload))  # never put a message on the wire that a peer would refuse
        self.seq += 1
        return [msgpack.packb(header, use_bin_type=True), payload]

    def depth(self, frame: np.ndarray, *, t_capture: float, frame_number: int,
              depth_scale: float) -> list[bytes]:
        if frame.dtype != np.uint16 or frame.ndim != 2:
            raise ProtocolError(f"depth frame must be 2-D uint16, got {frame.dtype} {frame.shape}")
        return self.encode("depth", np.ascontiguousarray(frame, dtype="<u2").tobytes(), t_capture=t_capture,
                           frame=frame_number, width=frame.shape[1], height=frame.shape[0],
                           depth_scale=float(depth_scale))


def decode(frames: list[bytes]) -> Message:
    """Parse and validate a two-frame message; ``ProtocolError`` on anything unacceptable."""
    try:
        return _decode(frames)
    except ProtocolError:
        raise
    except Exception as exc:  # a gap in the checks below must cost one message, never the reading process
        raise ProtocolError(f"message could not be checked ({type(exc).__name__})") from None


def _decode(frames: Any) -> Message:
    if not isinstance(frames, (list, tuple)) or len(frames) != 2:
        raise ProtocolError(f"expected 2 frames (header, payload), got {_count(frames)}")
    raw_header, payload = (_bytes(f) for f in frames)
    if len(raw_header) > MAX_HEADER_BYTES:
        raise ProtocolError(f"header of {len(raw_header)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        header = msgpack.unpackb(raw_header, raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
    except Exception as exc:  # msgpack raises many types for bad bytes; all mean the same here
        raise ProtocolError(f"header is not valid msgpack: {type(exc).__name__}: {_show(str(exc))}") from None
    _validate(header, len(payload))
    declared = {**_COMMON, **_FIELDS[header["kind"]]}
    return Message({k: v for k, v in header.items() if k in declared}, payload)


def _bytes(frame: Any) -> bytes:
    if isinstance(frame, bytes):
        return frame
    try:  # zmq.Frame, bytearray, memoryview: anything with a byte buffer, never an int (bytes(10**12))
        return memoryview(frame).tobytes()
    except TypeError:
        raise ProtocolError(f"a frame must be bytes, got {type(frame).__name__}") from None


def _show(value: Any, limit: int = 80) -> str:
    """An untrusted value as error text, bounded: containers by type and length only (``repr`` recurses,
    and a list nested ~1,000 deep fits in one 1 kB header), anything else by its ``repr``, cut."""
    if isinstance(value, (list, tuple, dict)):
        return f"a {type(value).__name__} of {len(value)} items"
    scalar = isinstance(value, (str, bytes, int, float, bool, type(None)))
    text = repr(value) if scalar else type(value).__name__
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _validate(header: Any, payload_len: int) -> None:
    if not isinstance(header, dict):
        raise ProtocolError(f"header must be a map, got {type(header).__name__}")
    version = header.get("v")
    if version != VERSION:
        raise ProtocolError(f"protocol version {_show(version)} not supported (this side speaks {VERSION})")
    kind = header.get("kind")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProtocolError(f"unknown message kind {_show(kind)}; known: {', '.join(KINDS)}")
    for name, check in {**_COMMON, **_FIELDS[kind]}.items():
        if name not in header:
            raise ProtocolError(f"{kind} message lacks field {name!r}")
        if not check(header[name]):
            raise ProtocolError(f"{kind} field {name!r} must be {check.__doc__}, got {_show(header[name])}")
    if payload_len > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {payload_len} bytes exceeds {MAX_PAYLOAD_BYTES}")
    expected = header["width"] * header["height"] * 2 if kind == "depth" else 0
    if kind == "depth" and not (header["width"] > 0 and header["height"] > 0):
        raise ProtocolError(f"depth frame size {header['width']}x{header['height']} is not positive")
    if payload_len != expected:
        raise ProtocolError(f"{kind} payload is {payload_len} bytes, expected {expected}")


def _count(frames: Any) -> str:
    try:
        return str(len(frames))
    except TypeError:
        return type(frames).__name__


# Default endpoints: loopback only. A robot address names the driver's state port; commands go to port + 1.
DEFAULT_CAMERA = "tcp://127.0.0.1:5555"
DEFAULT_ROBOT = "tcp://127.0.0.1:5556"


def robot_endpoints(robot: str) -> tuple[str, str]:
    """(state endpoint, command endpoint) of a driver at ``robot`` = tcp://HOST:PORT."""
    head, sep, port = robot.rpartition(":")
    if not (robot.startswith("tcp://") and sep and port.isdigit()):
        raise ValueError(f"robot address must look like tcp://HOST:PORT, got {robot!r}")
    return robot, f"{head}:{int(port) + 1}"
