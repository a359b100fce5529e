"""Cameras by name: ``d455[:SERIAL|:FILE.bag]``, ``hil[:ADDR]``, ``replay:PATH`` (see each module; what they
give the loop: ``runtime.cameras.base``)."""

from __future__ import annotations

from runtime.cameras.base import Camera, CameraError
from runtime.preprocess import DepthSpec
from runtime.protocol import DEFAULT_CAMERA


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
