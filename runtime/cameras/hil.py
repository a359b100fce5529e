"""``hil[:ADDR]``: depth frames from hil_sim (or any publisher of runtime.protocol ``depth`` messages)."""

from __future__ import annotations

from collections import deque

import numpy as np
import zmq

from runtime.cameras.base import CameraError, Frame, check_stream
from runtime.preprocess import DepthSpec
from runtime.protocol import DEFAULT_CAMERA
from runtime.transport import CurveKeys, Newest, TransportError, connect


class HilCamera:
    """SUB socket, newest frame only. Malformed messages are counted, never fatal; a frame of the wrong
    size is fatal (``StreamMismatch``): it means the publisher and the policy disagree."""

    def __init__(self, spec: DepthSpec, address: str = DEFAULT_CAMERA, *, period_s: float = 0.1,
                 keys: CurveKeys | None = None, ctx: zmq.Context | None = None) -> None:
        self.name = f"hil:{address}"
        self.spec = spec
        try:
            self._sub = Newest(connect(ctx or zmq.Context.instance(), zmq.SUB, address, keys=keys), "depth")
        except TransportError as exc:
            raise CameraError(f"camera {self.name}: {exc}") from None
        self._nominal = period_s
        self._gaps: deque[float] = deque(maxlen=16)
        self._last_capture: float | None = None

    @property
    def period_s(self) -> float:
        """Median of recent capture intervals once there are a few; the nominal period before that."""
        return float(np.median(self._gaps)) if len(self._gaps) >= 3 else self._nominal

    @property
    def rejected(self) -> int:
        return self._sub.rejected

    def poll(self, timeout_s: float) -> Frame | None:
        got = self._sub.poll(timeout_s)
        if got is None:
            return None
        msg, t_receive = got
        check_stream(self.name, msg["width"], msg["height"], self.spec)
        if self._last_capture is not None and msg["t_capture"] > self._last_capture:
            self._gaps.append(msg["t_capture"] - self._last_capture)
        self._last_capture = msg["t_capture"]
        return Frame(msg.depth(), msg["depth_scale"], msg["t_capture"], t_receive, msg["frame"])

    def close(self) -> None:
        self._sub.sock.close()
