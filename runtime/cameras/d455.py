"""``d455[:SERIAL|:FILE.bag]``: an Intel RealSense D455 through pyrealsense2, or a ``.bag`` recording of one.

Live: the depth stream is requested in the policy's stream mode (DepthSpec size, z16) at ``fps``, the depth
scale is read from the device, and frames carry the device's timestamps mapped onto this host's monotonic
clock. Only a D455 is accepted live: the policy learnt the D455's artifacts.

Playback (``.bag``): real time off, so every recorded frame is delivered, none skipped, as fast as the loop
asks; a frame's capture time is then the moment it is played (its recorded stamp stays in ``t_device``).
Any D400-family recording is accepted (the only public one at hand is a D435) with a warning.

Any depth mode the camera offers (640x480, 848x480, 1280x720, ...) is mapped onto the policy's stream by the
stream's own intrinsics (``runtime.preprocess.match_stream``): the policy sees the same field of view.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from runtime.cameras.base import CameraEnded, CameraError, Frame
from runtime.preprocess import DepthSpec, StreamIntrinsics, match_stream, trained_stream

try:
    import pyrealsense2 as rs
except ImportError as exc:  # the [realsense] extra; on Debian it also needs libusb-1.0-0
    raise CameraError(f"camera d455 needs pyrealsense2 (pip install '.[realsense]'): {exc}") from None

D400_PREFIX = "Intel RealSense D4"
_HOST_DOMAINS = (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time)


class D455Camera:
    def __init__(self, spec: DepthSpec, source: str = "", *, fps: int = 30) -> None:
        self.playback = source.endswith(".bag")
        self.name = f"d455:{source}" if source else "d455"
        self._pipe = rs.pipeline()
        cfg = self._config(spec, source, fps)
        # Device and stream are checked on the resolved configuration, before anything streams: stopping a
        # playback right after its start races librealsense's reader thread (heap corruption under load).
        try:
            self._check(cfg.resolve(rs.pipeline_wrapper(self._pipe)), spec)
            profile = self._pipe.start(cfg)
        except CameraError:
            raise
        except RuntimeError as exc:  # librealsense's own errors: no device, unreadable recording
            raise CameraError(f"camera {self.name}: cannot start the depth stream ({exc})") from None
        self._device = profile.get_device()
        if self.playback:
            self._device.as_playback().set_real_time(False)
        self.depth_scale = float(self._device.first_depth_sensor().get_depth_scale())
        self._offset: float | None = None

    def _config(self, spec: DepthSpec, source: str, fps: int) -> rs.config:
        cfg = rs.config()
        if self.playback:
            if not Path(source).is_file():
                raise CameraError(f"camera {self.name}: no such recording")
            cfg.enable_device_from_file(source, repeat_playback=False)
            cfg.enable_stream(rs.stream.depth)  # whatever was recorded; its size is checked before start
        else:
            if source:
                cfg.enable_device(source)
            cfg.enable_stream(rs.stream.depth, spec.stream_width, spec.stream_height, rs.format.z16, fps)
        return cfg

    def _check(self, profile: rs.pipeline_profile, spec: DepthSpec) -> None:
        model = profile.get_device().get_info(rs.camera_info.name)
        if self.playback:
            if not model.startswith(D400_PREFIX):
                raise CameraError(f"camera {self.name}: recording is from {model!r}, not a D400 camera")
            if "D455" not in model:
                print(f"runtime: WARNING camera {self.name} plays a {model} recording; the policy expects "
                      "D455 depth (accepted in playback: same D400 depth pipeline)", file=sys.stderr)
        elif "D455" not in model:
            raise CameraError(f"camera {self.name}: found {model!r}; the live runtime needs a D455")
        stream = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        self.stream_size = (stream.width(), stream.height())
        k = stream.get_intrinsics()
        self.intrinsics = StreamIntrinsics(k.width, k.height, k.fx, k.fy, k.ppx, k.ppy)
        self._trained = trained_stream(spec)
        if self.stream_size != (spec.stream_width, spec.stream_height):
            print(f"runtime: camera {self.name} streams {k.width}x{k.height}: mapped onto the policy's "
                  f"{spec.stream_width}x{spec.stream_height} view by its intrinsics", file=sys.stderr)
        self.period_s = 1.0 / stream.fps()

    def poll(self, timeout_s: float) -> Frame | None:
        frames = None if self.playback else self._drain()
        if frames is None:
            ok, frames = self._pipe.try_wait_for_frames(max(1, round(timeout_s * 1000)))
            if not ok:
                if self.playback and self._playback_stopped():
                    raise CameraEnded(f"camera {self.name}: end of recording")
                return None
        t_receive = time.monotonic()
        depth = frames.get_depth_frame()
        t_capture = t_receive if self.playback else self._to_monotonic(depth, t_receive)
        raw = match_stream(np.array(depth.get_data(), dtype=np.uint16), self.intrinsics, self._trained)
        return Frame(raw, self.depth_scale, t_capture, t_receive,
                     int(depth.get_frame_number()), depth.get_timestamp() / 1000.0)

    def _playback_stopped(self) -> bool:
        return self._device.as_playback().current_status() == rs.playback_status.stopped

    def _drain(self) -> rs.composite_frame | None:
        """Newest pending frameset of a live stream, dropping older ones."""
        newest = None
        while (frames := self._pipe.poll_for_frames()):
            newest = frames
        return newest

    def _to_monotonic(self, depth: rs.depth_frame, t_receive: float) -> float:
        """Capture time on this host's monotonic clock. Host-domain stamps (the D400 default, global time)
        convert exactly; a bare device clock is mapped by the smallest receive-minus-device offset seen, i.e.
        relative to the fastest delivery."""
        stamp = depth.get_timestamp() / 1000.0
        if depth.get_frame_timestamp_domain() in _HOST_DOMAINS:
            return stamp - (time.time() - time.monotonic())
        offset = t_receive - stamp
        self._offset = offset if self._offset is None else min(self._offset, offset)
        return stamp + self._offset

    def close(self) -> None:
        self._pipe.stop()
