"""``replay:PATH``: recorded raw depth frames, served at their recorded rate in real time.

Formats (both uint16 sensor units, 0 = no data):
- ``PATH.npz`` with ``depth`` [N, H, W] uint16, optional scalars ``depth_scale`` (metres per unit,
  default 0.001) and ``fps`` (default 30).
- a folder of ``*.npy`` files, each one [H, W] uint16 frame, played in name order, with an optional
  ``meta.json`` {"depth_scale": ..., "fps": ...}.
Frame i becomes available at open + i/fps; its capture time is that instant. After the last frame the
camera raises ``CameraEnded``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from runtime.cameras.base import CameraEnded, CameraError, Frame, check_stream
from runtime.preprocess import DepthSpec

DEFAULT_SCALE = 0.001
DEFAULT_FPS = 30.0


class ReplayCamera:
    def __init__(self, spec: DepthSpec, path: str | Path) -> None:
        self.name = f"replay:{path}"
        self.frames, self.depth_scale, fps = _load(Path(path))
        if not (np.isfinite(fps) and fps > 0 and np.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise CameraError(f"camera {self.name}: fps {fps} and depth_scale {self.depth_scale} must be > 0")
        check_stream(self.name, self.frames.shape[2], self.frames.shape[1], spec)
        self.period_s = 1.0 / fps
        self._start: float | None = None
        self._next = 0

    def poll(self, timeout_s: float) -> Frame | None:
        now = time.monotonic()
        if self._start is None:
            self._start = now
        if self._next >= len(self.frames):
            raise CameraEnded(f"camera {self.name}: all {len(self.frames)} frames played")
        due = self._start + self._next * self.period_s
        if due > now:
            if due > now + timeout_s:
                time.sleep(max(timeout_s, 0.0))
                return None
            time.sleep(due - now)
        newest = min(int((time.monotonic() - self._start) / self.period_s), len(self.frames) - 1)
        self._next = newest + 1
        return Frame(self.frames[newest], self.depth_scale, self._start + newest * self.period_s,
                     time.monotonic(), newest)

    def close(self) -> None:
        pass


def _load(path: Path) -> tuple[np.ndarray, float, float]:
    if path.is_dir():
        files = sorted(path.glob("*.npy"))
        if not files:
            raise CameraError(f"camera replay:{path}: folder holds no *.npy frames")
        meta = json.loads((path / "meta.json").read_text()) if (path / "meta.json").is_file() else {}
        frames = np.stack([np.load(f, allow_pickle=False) for f in files])
        return _checked(path, frames), float(meta.get("depth_scale", DEFAULT_SCALE)), float(
            meta.get("fps", DEFAULT_FPS))
    try:
        with np.load(path, allow_pickle=False) as data:
            frames = data["depth"]
            scale = float(data["depth_scale"]) if "depth_scale" in data else DEFAULT_SCALE
            fps = float(data["fps"]) if "fps" in data else DEFAULT_FPS
    except (OSError, ValueError, KeyError) as exc:
        raise CameraError(f"camera replay:{path}: not a readable .npz with a 'depth' array ({exc})") from None
    return _checked(path, frames), scale, fps


def _checked(path: Path, frames: np.ndarray) -> np.ndarray:
    if frames.dtype != np.uint16 or frames.ndim != 3 or len(frames) == 0:
        raise CameraError(f"camera replay:{path}: need uint16 frames [N, H, W], got {frames.dtype} "
                          f"{frames.shape}")
    return frames
