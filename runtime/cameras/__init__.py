"""Cameras by name: ``d455[:SERIAL|:FILE.bag]``, ``hil[:ADDR]``, ``replay:PATH`` (see each module)."""

from __future__ import annotations

from collections.abc import Callable

from runtime.cameras.base import (
    Camera,
    CameraEnded,
    CameraError,
    CameraStalled,
    Frame,
    StreamMismatch,
    check_stream,
)
from runtime.preprocess import DepthSpec
from runtime.protocol import DEFAULT_CAMERA

__all__ = ["Camera", "CameraEnded", "CameraError", "CameraStalled", "Frame", "StreamMismatch", "check_stream",
           "open_camera", "CAMERAS"]


def _d455(spec: DepthSpec, arg: str, period_s: float) -> Camera:
    from runtime.cameras.d455 import D455Camera  # pyrealsense2 is an optional extra: import on demand

    return D455Camera(spec, arg)


def _hil(spec: DepthSpec, arg: str, period_s: float) -> Camera:
    from runtime.cameras.hil import HilCamera

    return HilCamera(spec, arg or DEFAULT_CAMERA, period_s=period_s)


def _replay(spec: DepthSpec, arg: str, period_s: float) -> Camera:
    from runtime.cameras.replay import ReplayCamera

    if not arg:
        raise CameraError("camera replay needs a path: replay:PATH")
    if arg.endswith(".bag"):  # librealsense's recording format, read by the d455 camera's reader
        raise CameraError(f"camera replay:{arg}: .bag recordings play as a camera: use --camera d455:{arg}")
    return ReplayCamera(spec, arg)


Opener = Callable[[DepthSpec, str, float], Camera]
CAMERAS: dict[str, Opener] = {"d455": _d455, "hil": _hil, "replay": _replay}


def open_camera(uri: str, spec: DepthSpec, *, period_s: float = 0.1) -> Camera:
    """Open the camera named by ``uri`` (KIND[:ARG]); ``period_s`` is the control period, a first guess
    of the frame period for cameras that measure theirs."""
    kind, _, arg = uri.partition(":")
    if kind not in CAMERAS:
        raise CameraError(f"unknown camera {uri!r}; use one of: d455[:SERIAL|:FILE.bag], hil[:ADDR], "
                          "replay:PATH")
    return CAMERAS[kind](spec, arg, period_s)
