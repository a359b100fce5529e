"""Wire protocol between camera, runtime and franka_driver (contract; see DESIGN.md).

A message is two ZeroMQ frames: a small msgpack header (a map) and a raw payload (bytes, may be empty).
Depth travels as the raw uint16 buffer in the payload: no per-pixel encoding. Every header carries

    v        schema version (``VERSION``); a peer that speaks another version is refused
    kind     one of ``KINDS``
    seq      sequence number, per sender, +1 per message
    t_send   sender's ``time.monotonic()`` when it sent

plus the fields of its kind (``_FIELDS``). Timestamps are CLOCK_MONOTONIC seconds: comparable between
processes on one host (the default loopback deployment). ``decode`` turns anything malformed, truncated,
oversized or of another version into a ``ProtocolError`` naming the problem; it never raises anything else.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

VERSION = 1
MAX_HEADER_BYTES = 4096
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


def _is(kind: type, doc: str):
    def check(x: Any) -> bool:
        return isinstance(x, kind) and not isinstance(x, bool)
    check.__doc__ = doc
    return check


_num.__doc__ = "a finite number"
_int.__doc__ = "an integer"
_STR = _is(str, "a string")
def _BOOL(x: Any) -> bool:
    return isinstance(x, bool)


_BOOL.__doc__ = "a boolean"

_COMMON = {"v": _int, "kind": _STR, "seq": _int, "t_send": _num}
_FIELDS: dict[str, dict[str, Any]] = {
    # Camera -> runtime. Payload: height*width uint16 little-endian, sensor units of depth_scale metres.
    "depth": {"t_capture": _num, "frame": _int, "width": _int, "height": _int, "depth_scale": _num},
    # Driver -> runtime, >= 100 Hz. gripper: opening width in metres (0 closed .. 0.08 open).
    "state": {"t_capture": _num, "q": _vec(DOF), "dq": _vec(DOF), "gripper": _num, "holding": _BOOL,
              "fault": _STR},
    # Runtime -> driver. gripper: -1 open / +1 close. deadline: monotonic time after which it is stale.
    # t_capture: capture time of the newest depth frame behind it (for latency accounting).
    "command": {"t_capture": _num, "q_target": _vec(DOF), "gripper": _num, "deadline": _num},
    # Anyone -> anyone: a named condition (e.g. camera_stalled, late_tick, nan_action) and free text.
    "status": {"code": _STR, "detail": _STR},
}
KINDS = tuple(_FIELDS)


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
    if not isinstance(frames, (list, tuple)) or len(frames) != 2:
        raise ProtocolError(f"expected 2 frames (header, payload), got {_count(frames)}")
    raw_header, payload = (bytes(f) for f in frames)
    if len(raw_header) > MAX_HEADER_BYTES:
        raise ProtocolError(f"header of {len(raw_header)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        header = msgpack.unpackb(raw_header, raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
    except Exception as exc:  # msgpack raises many types for bad bytes; all mean the same here
        raise ProtocolError(f"header is not valid msgpack: {type(exc).__name__}: {exc}") from None
    _validate(header, len(payload))
    return Message(header, payload)


def _validate(header: Any, payload_len: int) -> None:
    if not isinstance(header, dict):
        raise ProtocolError(f"header must be a map, got {type(header).__name__}")
    version = header.get("v")
    if version != VERSION:
        raise ProtocolError(f"protocol version {version!r} not supported (this side speaks {VERSION})")
    kind = header.get("kind")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProtocolError(f"unknown message kind {kind!r}; known: {', '.join(KINDS)}")
    for name, check in {**_COMMON, **_FIELDS[kind]}.items():
        if name not in header:
            raise ProtocolError(f"{kind} message lacks field {name!r}")
        if not check(header[name]):
            raise ProtocolError(f"{kind} field {name!r} must be {check.__doc__}, got {header[name]!r:.80}")
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
