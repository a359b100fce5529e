"""Wire protocol between camera, runtime and franka_driver (contract; see DESIGN.md).

A message is two ZeroMQ frames: a msgpack header (a map) and a raw payload (bytes, may be empty; depth travels
as the raw uint16 buffer). Every header carries ``v`` (``VERSION``; another version is refused), ``kind``
(``KINDS``), ``seq`` (per sender, +1 per message) and ``t_send``, plus the fields of its kind (``_FIELDS``);
undeclared fields are dropped on decode. Times are CLOCK_MONOTONIC seconds: comparable between processes on
one host (loopback, the default). Version 2 added the controller session: a ``command`` names its sender's
secret ``session``, a ``state`` the public ``session_tag`` of the session the driver executes ("" if none).

``decode`` turns anything malformed, truncated, oversized or of another version into a ``ProtocolError``
naming the problem, never anything else; its text shows untrusted values cut to a bounded size (``repr`` of a
list nested ~1,000 deep raised RecursionError and took the reading process down).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

VERSION = 2
MAX_HEADER_BYTES = 4096
MAX_TEXT = 512  # longest string field, so one field cannot fill the header
MAX_PAYLOAD_BYTES = 1280 * 720 * 2  # the largest D455 depth frame
DOF = 7
# Loopback only by default. A robot address names the driver's state port; its commands go to port + 1.
DEFAULT_CAMERA, DEFAULT_ROBOT = "tcp://127.0.0.1:5555", "tcp://127.0.0.1:5556"


class ProtocolError(ValueError):
    """A message that cannot be accepted. The text says which field and why."""


def _check(what: str, test: Any) -> Any:
    test.what = what
    return test


_INT = _check("an integer", lambda x: isinstance(x, int) and not isinstance(x, bool))
_NUM = _check("a finite number", lambda x: (_INT(x) or isinstance(x, float)) and math.isfinite(x))
_BOOL = _check("a boolean", lambda x: isinstance(x, bool))
_STR = _check(f"a string of 0..{MAX_TEXT} characters", lambda x: isinstance(x, str) and len(x) <= MAX_TEXT)
_SESSION = _check("a string of 16..64 characters", lambda x: isinstance(x, str) and 16 <= len(x) <= 64)
_JOINTS = _check(f"a list of {DOF} finite numbers",
                 lambda x: isinstance(x, (list, tuple)) and len(x) == DOF and all(_NUM(v) for v in x))
_COMMON = {"v": _INT, "kind": _STR, "seq": _INT, "t_send": _NUM}
_FIELDS: dict[str, dict[str, Any]] = {
    # Camera -> runtime. Payload: height*width uint16 little-endian, sensor units of depth_scale metres.
    "depth": {"t_capture": _NUM, "frame": _INT, "width": _INT, "height": _INT, "depth_scale": _NUM},
    # Driver -> runtime, >= 100 Hz. gripper: opening in metres (0 closed .. 0.08 open).
    "state": {"t_capture": _NUM, "q": _JOINTS, "dq": _JOINTS, "gripper": _NUM, "holding": _BOOL,
              "fault": _STR, "controller": _STR},
    # Runtime -> driver. gripper: -1 open / +1 close; deadline: when it goes stale; t_capture: of the newest
    # depth frame behind it (latency accounting); the driver executes one session at a time, seq increasing.
    "command": {"t_capture": _NUM, "q_target": _JOINTS, "gripper": _NUM, "deadline": _NUM,
                "session": _SESSION},
    # Anyone -> anyone: a named condition (e.g. camera_stalled, command_timeout) and free text.
    "status": {"code": _STR, "detail": _STR},
}
KINDS = tuple(_FIELDS)


def session_tag(session: str) -> str:
    """The public name of a session in ``state`` messages: a hash, because every local process can read the
    state stream and the session itself entitles a sender to move the arm."""
    return hashlib.sha256(session.encode()).hexdigest()[:16]


def robot_endpoints(robot: str) -> tuple[str, str]:
    """(state endpoint, command endpoint) of a driver at ``robot`` = tcp://HOST:PORT."""
    head, sep, port = robot.rpartition(":")
    if not (robot.startswith("tcp://") and sep and port.isdigit()):
        raise ValueError(f"robot address must look like tcp://HOST:PORT, got {robot!r}")
    return robot, f"{head}:{int(port) + 1}"


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

    seq: int = 0

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
        if not isinstance(frames, (list, tuple)) or len(frames) != 2:
            raise ProtocolError(f"expected 2 frames (header, payload), got {_show(frames)}")
        raw_header, payload = (_bytes(f) for f in frames)
        if len(raw_header) > MAX_HEADER_BYTES:
            raise ProtocolError(f"header of {len(raw_header)} bytes exceeds {MAX_HEADER_BYTES}")
        try:
            header = msgpack.unpackb(raw_header, raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
        except Exception as exc:  # msgpack raises many types for bad bytes; all mean the same here
            raise ProtocolError(f"header is not valid msgpack: {type(exc).__name__}: {_show(str(exc))}"
                                ) from None
        _validate(header, len(payload))
        declared = {**_COMMON, **_FIELDS[header["kind"]]}
        return Message({k: v for k, v in header.items() if k in declared}, payload)
    except ProtocolError:
        raise
    except Exception as exc:  # a gap in the checks must cost one message, never the reading process
        raise ProtocolError(f"message could not be checked ({type(exc).__name__})") from None


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
    if (version := header.get("v")) != VERSION:
        raise ProtocolError(f"protocol version {_show(version)} not supported (this side speaks {VERSION})")
    kind = header.get("kind")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProtocolError(f"unknown message kind {_show(kind)}; known: {', '.join(KINDS)}")
    for name, check in {**_COMMON, **_FIELDS[kind]}.items():
        if name not in header:
            raise ProtocolError(f"{kind} message lacks field {name!r}")
        if not check(header[name]):
            raise ProtocolError(f"{kind} field {name!r} must be {check.what}, got {_show(header[name])}")
    if payload_len > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {payload_len} bytes exceeds {MAX_PAYLOAD_BYTES}")
    if kind == "depth" and not (header["width"] > 0 and header["height"] > 0):
        raise ProtocolError(f"depth frame size {header['width']}x{header['height']} is not positive")
    expected = header["width"] * header["height"] * 2 if kind == "depth" else 0
    if payload_len != expected:
        raise ProtocolError(f"{kind} payload is {payload_len} bytes, expected {expected}")
