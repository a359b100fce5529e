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
    """One raw depth frame: uint16 [height, width] sensor units (0 = no data) of ``depth_scale`` metres.
    Times are this host's ``time.monotonic()``; ``t_device`` is the camera's own stamp, where it has one."""

    depth: np.ndarray
    depth_scale: float
    t_capture: float
    t_receive: float
    number: int
    t_device: float | None = None


class Camera(Protocol):
    name: str
    period_s: float
    """Nominal (or measured) time between frames; the loop's stall detection builds on it."""

    def poll(self, timeout_s: float) -> Frame | None:
        """The newest frame that arrived since the last call, waiting up to ``timeout_s``; None if none."""

    def close(self) -> None: ...


def check_stream(name: str, width: int, height: int, spec: DepthSpec) -> None:
    """Refuse a stream whose size is not the policy's, for the cameras whose frames carry no intrinsics (hil,
    replay): another resolution has other intrinsics, so the fixed crop would show the policy another scene.
    The d455 reader maps any mode onto the policy's view by its intrinsics instead."""
    if (width, height) != (spec.stream_width, spec.stream_height):
        raise StreamMismatch(f"camera {name} streams {width}x{height} depth but the policy expects "
                             f"{spec.stream_width}x{spec.stream_height} (its DepthSpec); record or stream at "
                             f"{spec.stream_width}x{spec.stream_height}")
