"""What every camera gives the control loop: newest raw depth frames with capture and receive times."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from runtime.preprocess import DepthSpec


class CameraError(RuntimeError):
    """A camera that cannot be opened or used; the text names the camera and the problem."""


class CameraStalled(CameraError):
    """No usable frame for longer than the loop tolerates (status ``camera_stalled``)."""


class CameraEnded(CameraError):
    """A recording (replay file, .bag) has no more frames: a normal end, not a fault."""


class StreamMismatch(CameraError):
    """The camera's stream size differs from the one the policy was trained on (DepthSpec)."""


@dataclass(frozen=True)
class Frame:
    """One raw depth frame. Times are ``time.monotonic()`` seconds of this host."""

    depth: np.ndarray
    """uint16 [height, width] in sensor units, 0 = no data."""
    depth_scale: float
    """Metres per sensor unit."""
    t_capture: float
    t_receive: float
    number: int
    """The camera's frame counter (gaps mean dropped frames)."""
    t_device: float | None = None
    """The camera's own timestamp (seconds, its clock), where it has one."""


class Camera(Protocol):
    name: str
    period_s: float
    """Nominal (or measured) time between frames; the loop's stall detection builds on it."""

    def poll(self, timeout_s: float) -> Frame | None:
        """The newest frame that arrived since the last call, waiting up to ``timeout_s``; None if none."""

    def close(self) -> None: ...


def check_stream(name: str, width: int, height: int, spec: DepthSpec) -> None:
    """Refuse a stream whose size is not the policy's: the fixed crop would see a different field of view.

    For the cameras whose frames carry no intrinsics (hil, replay): another resolution has other
    intrinsics, so a pixel-space crop would silently show the policy a scene it was not trained on. The d455
    reader knows its stream's intrinsics and maps any mode onto the policy's view instead
    (``runtime.preprocess.match_stream``).
    """
    if (width, height) != (spec.stream_width, spec.stream_height):
        raise StreamMismatch(f"camera {name} streams {width}x{height} depth but the policy expects "
                             f"{spec.stream_width}x{spec.stream_height} (its DepthSpec); record or stream at "
                             f"{spec.stream_width}x{spec.stream_height}")
