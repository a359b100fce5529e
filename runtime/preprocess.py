"""Raw camera depth and robot joints -> policy inputs. The ONE implementation: trainer, DDG, hil_sim and the
runtime import it.

Pipeline (each step its own function so the dataset path can stop half way):

1. ``crop_resize``: uint16 sensor frame -> uint16 frame at the policy resolution. The crop window is
   fixed at deploy time (centred) and randomised per episode in training (paper: 450x580 out of 1280x720,
   scaled here to the 848x480 stream). Resizing is nearest-neighbour on purpose: averaging would blend the
   0 ("no data") pixels into their neighbours and invent flying pixels that the sensor never produced.
   Demos and DDG output are stored after this step, still in sensor units (uint16 millimetres).
2. ``restore_holes`` (deploy-time option, ``runtime --restore``; default ``none``): fill the holes at the
   policy resolution before the policy sees them, for a policy trained on clean depth.
3. ``normalise``: uint16 -> float32. Valid depth is clipped to [near_m, far_m] and mapped to [0, 1];
   0 ("no data") becomes ``invalid_value`` (-1), outside the valid range, so the network can tell
   "nothing measured" from "very near".

``preprocess`` = ``normalise(restore_holes(crop_resize(...)))``; tests prove the two paths are bit-identical.
``policy_state`` builds the ``state`` input, ``FrameStack`` the ``depth`` input's history.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass

import numpy as np


class PreprocessError(ValueError):
    """A depth frame that cannot be turned into a policy input (wrong dtype, shape, window)."""


@dataclass(frozen=True)
class DepthSpec:
    """Stream mode of the camera and the policy's view of it. Travels in the policy file's metadata."""

    stream_width: int = 848
    """D455 depth stream: 848x480 is the vendor's recommended depth mode (best depth quality)."""
    stream_height: int = 480
    crop_height: int = 300
    """Crop window, scaled from the paper's 450x580 of 1280x720 (0.625 x 480 rows, ~0.47 x 848 columns)."""
    crop_width: int = 400
    out_height: int = 96
    """Policy resolution: the crop downsampled by 3.125 in both axes."""
    out_width: int = 128
    near_m: float = 0.3
    """Metric range kept; the D455's min-z at 848x480 is ~0.34 m, the table is ~0.9 m away."""
    far_m: float = 1.5
    invalid_value: float = -1.0
    """Value of a pixel with no depth (sensor 0) after normalisation."""

    def __post_init__(self) -> None:
        if not (0 < self.crop_height <= self.stream_height and 0 < self.crop_width <= self.stream_width):
            raise PreprocessError(f"crop {self.crop_height}x{self.crop_width} does not fit the stream "
                                  f"{self.stream_height}x{self.stream_width}")
        if not (0 < self.out_height <= self.crop_height and 0 < self.out_width <= self.crop_width):
            raise PreprocessError(f"output {self.out_height}x{self.out_width} must be within the crop")
        if not (0 < self.near_m < self.far_m):
            raise PreprocessError(f"need 0 < near_m < far_m, got {self.near_m}, {self.far_m}")
        if 0.0 <= self.invalid_value <= 1.0:
            raise PreprocessError(f"invalid_value {self.invalid_value} collides with valid depth in [0, 1]")

    def centred_window(self) -> tuple[int, int]:
        """(top, left) of the deploy-time crop: centred in the stream."""
        return (self.stream_height - self.crop_height) // 2, (self.stream_width - self.crop_width) // 2

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> DepthSpec:
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise PreprocessError(f"unknown preprocessing parameters {sorted(unknown)}")
        return cls(**d)


@dataclass(frozen=True)
class StreamIntrinsics:
    """Pinhole model of a depth stream: size, focal lengths and principal point in pixels, pixel centres at
    integer coordinates (librealsense's ``rs.intrinsics``: width, height, fx, fy, ppx, ppy)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


TRAINED_STREAM = StreamIntrinsics(848, 480, 424.51, 424.24, 415.71, 249.80)
"""The stream the policies here are trained on: hil_sim's simulated D455 at 848x480 (a test keeps it equal
to ``hil_sim.camera.Intrinsics``)."""


def trained_stream(spec: DepthSpec) -> StreamIntrinsics:
    """The trained stream at ``spec``'s stream size (scaled as ``hil_sim.camera.d455_intrinsics`` does)."""
    base = TRAINED_STREAM
    if (spec.stream_width, spec.stream_height) == (base.width, base.height):
        return base
    sx, sy = spec.stream_width / base.width, spec.stream_height / base.height
    return StreamIntrinsics(spec.stream_width, spec.stream_height, base.fx * sx, base.fy * sy,
                            (base.cx + 0.5) * sx - 0.5, (base.cy + 0.5) * sy - 0.5)


def match_stream(raw: np.ndarray, stream: StreamIntrinsics, target: StreamIntrinsics) -> np.ndarray:
    """A frame of another stream mode (a D4xx at 640x480 or 1280x720, another D400 model) as the trained
    stream ``target`` (``trained_stream(spec)``) would have seen it: each target pixel takes the source
    pixel on the same ray, so the policy's crop keeps its field of view (a pixel-space crop of another mode
    would show it another scene). Nearest pixel on purpose, as in ``crop_resize``; rays the source does not
    see are 0 (no data). A frame of the trained stream itself is returned untouched: the native path stays
    bit-identical to training."""
    if stream == target:
        return raw
    if raw.shape != (stream.height, stream.width):
        raise PreprocessError(f"frame of shape {raw.shape} does not match its stream "
                              f"{stream.width}x{stream.height}")
    cols = _same_ray(target.width, target.cx, target.fx, stream.cx, stream.fx)
    rows = _same_ray(target.height, target.cy, target.fy, stream.cy, stream.fy)
    seen = (rows[:, None] >= 0) & (rows[:, None] < stream.height) & (cols >= 0) & (cols < stream.width)
    out = raw[np.clip(rows, 0, stream.height - 1)[:, None], np.clip(cols, 0, stream.width - 1)]
    return np.where(seen, out, np.uint16(0))


def _same_ray(n: int, c: float, f: float, c_src: float, f_src: float) -> np.ndarray:
    """Index of the source pixel on the ray of each of ``n`` target pixels along one axis."""
    return np.rint((np.arange(n) - c) / f * f_src + c_src).astype(np.int64)


def crop_resize(raw: np.ndarray, spec: DepthSpec, window: tuple[int, int] | None = None) -> np.ndarray:
    """Crop ``raw`` (uint16, H x W, any size holding the window) at ``window`` = (top, left) and
    nearest-neighbour resize to the policy resolution. Returns uint16, still in sensor units."""
    if not isinstance(raw, np.ndarray) or raw.dtype != np.uint16 or raw.ndim != 2:
        got = f"{raw.dtype} array of shape {raw.shape}" if isinstance(raw, np.ndarray) else type(raw).__name__
        raise PreprocessError(f"depth frame must be a 2-D uint16 array, got {got}")
    top, left = spec.centred_window() if window is None else window
    if top < 0 or left < 0 or top + spec.crop_height > raw.shape[0] or left + spec.crop_width > raw.shape[1]:
        raise PreprocessError(f"crop window top={top} left={left} size {spec.crop_height}x{spec.crop_width} "
                              f"does not fit a {raw.shape[0]}x{raw.shape[1]} frame")
    window = raw[top:top + spec.crop_height, left:left + spec.crop_width]
    return resample(window, spec.out_height, spec.out_width)


def resample(depth: np.ndarray, height: int, width: int) -> np.ndarray:
    """Nearest-neighbour resize of ``depth`` [..., H, W] to [..., height, width] (no blending of holes)."""
    rows = _nearest_index(depth.shape[-2], height)
    cols = _nearest_index(depth.shape[-1], width)
    return depth[..., rows[:, None], cols]


RESTORE_METHODS = ("none", "inpaint")


def restore_holes(depth: np.ndarray, method: str = "none") -> np.ndarray:
    """uint16 depth with its 0 pixels filled by ``method``: ``none`` keeps them (a DDG student learnt to
    read them); ``inpaint`` is OpenCV's Navier-Stokes inpainting, radius 3 px (DexGraspNet 2.0's
    deploy-time restoration for a clean-depth policy). A frame with no valid pixel is returned as is."""
    if method not in RESTORE_METHODS:
        raise PreprocessError(f"unknown hole restoration {method!r}; choose one of {RESTORE_METHODS}")
    holes = depth == 0
    if method == "none" or not holes.any() or holes.all():
        return depth
    import cv2  # only deployments that restore pay for OpenCV's import

    return cv2.inpaint(depth, holes.astype(np.uint8), 3, cv2.INPAINT_NS)


def normalise(depth: np.ndarray, depth_scale: float, spec: DepthSpec) -> np.ndarray:
    """uint16 depth in sensor units (``depth_scale`` metres per unit) -> float32 policy values."""
    if depth.dtype != np.uint16:
        raise PreprocessError(f"depth must be uint16 sensor units, got {depth.dtype}")
    if not (np.isfinite(depth_scale) and depth_scale > 0):
        raise PreprocessError(f"depth_scale must be a positive number of metres per unit, got {depth_scale}")
    metres = depth.astype(np.float32) * np.float32(depth_scale)
    scaled = (np.clip(metres, spec.near_m, spec.far_m) - np.float32(spec.near_m)) / np.float32(
        spec.far_m - spec.near_m)
    return np.where(depth == 0, np.float32(spec.invalid_value), scaled).astype(np.float32)


def preprocess(raw: np.ndarray, depth_scale: float, spec: DepthSpec,
               window: tuple[int, int] | None = None, restore: str = "none") -> np.ndarray:
    """Raw sensor frame -> float32 [out_height, out_width] policy input."""
    return normalise(restore_holes(crop_resize(raw, spec, window), restore), depth_scale, spec)


def policy_state(q: np.ndarray, gripper_opening: float, joint_offset: tuple[float, ...] | None = None
                 ) -> np.ndarray:
    """The ``state`` input, float32 [8]: 7 joint angles + gripper opening (m). ``joint_offset`` (the policy
    metadata's ``joint_offset_rad``) turns the angles a robot reports into those the policy was trained on."""
    q = np.asarray(q, dtype=np.float64) + (0.0 if joint_offset is None else np.asarray(joint_offset))
    return np.array([*q, gripper_opening], dtype=np.float32)


class FrameStack:
    """The last ``n`` preprocessed frames, oldest first. The first frame of an episode fills every slot,
    in training and at deploy time alike, so the policy never sees an all-empty history."""

    def __init__(self, n: int = 3) -> None:
        self._frames: deque[np.ndarray] = deque(maxlen=n)

    def push(self, frame: np.ndarray) -> np.ndarray:
        """Add the newest frame; return the stack as float32 [n, H, W]."""
        if not self._frames:
            self._frames.extend([frame] * self._frames.maxlen)
        else:
            self._frames.append(frame)
        return np.stack(self._frames)

    def reset(self) -> None:
        """Forget the history: a new episode, or a history made stale within one."""
        self._frames.clear()


def _nearest_index(src: int, dst: int) -> np.ndarray:
    """Index of the source pixel whose centre is nearest each destination pixel centre."""
    return np.minimum(((np.arange(dst) + 0.5) * src / dst).astype(np.int64), src - 1)
