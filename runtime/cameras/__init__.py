"""Cameras by name: ``d455[:SERIAL|:FILE.bag]``, ``hil[:ADDR]``, ``replay:PATH`` (see each module), and what
every camera gives the control loop: newest raw depth frames with capture and receive times."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from runtime.preprocess import DepthSpec
from runtime.protocol import DEFAULT_CAMERA


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


def open_camera(uri: str, spec: DepthSpec, *, period_s: float = 0.1) -> Camera:
    """Open the camera named by ``uri`` (KIND[:ARG]); ``period_s`` is the control period, a first guess
    of the frame period for cameras that measure theirs. Each kind is imported only when opened (d455 needs
    the optional pyrealsense2)."""
    kind, _, arg = uri.partition(":")
    if kind == "d455":
        from runtime.cameras.d455 import D455Camera

        return D455Camera(spec, arg)
    if kind == "hil":
        from runtime.cameras.hil import HilCamera

        return HilCamera(spec, arg or DEFAULT_CAMERA, period_s=period_s)
    if kind == "replay":
        from runtime.cameras.replay import ReplayCamera

        if not arg:
            raise CameraError("camera replay needs a path: replay:PATH")
        if arg.endswith(".bag"):  # librealsense's recording format, read by the d455 camera's reader
            raise CameraError(f"camera replay:{arg}: .bag recordings play as a camera: use --camera "
                              f"d455:{arg}")
        return ReplayCamera(spec, arg)
    raise CameraError(f"unknown camera {uri!r}; use one of: d455[:SERIAL|:FILE.bag], hil[:ADDR], replay:PATH")
