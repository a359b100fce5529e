"""Real captures (``../shared/data/real_depth`` layout) -> uint16 millimetre crops at the policy resolution.

Every crop goes through ``runtime.preprocess.crop_resize``: a capture of any size gets a ``DepthSpec``
with its own stream size and a crop window of the policy's 3:4 aspect, so real frames, simulated
frames and the student all see artifacts at the same scale.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from runtime.preprocess import DepthSpec, crop_resize


class RealDataError(ValueError):
    """A real-capture directory or frame that cannot be used (no frames, no depth, NaNs, bad shapes)."""


POLICY_SPEC = DepthSpec()

# Sources that the data README reserves for its separate held-out set: never train on them.
FORBIDDEN_SOURCES = ("NVlabs/M2T2", "NVlabs/PoseCNN-PyTorch", "CMU-AI-Maker-Space/aims-slam")
FORBIDDEN_SCENES = ("000000130", "000000153")

# D4xx frames kept out of training to judge realism (whole scenes where possible; the tail of the one
# consecutive sequence, so its neighbours in training are at least 1 frame / a few mm of motion apart).
HOLDOUT_FRAMES = (
    "ucn_demo__000006", "ucn_demo__000007", "ucn_demo__000008",
    "cleargrasp_d435__000000123__transparent", "cleargrasp_d435__000000123__opaque",
    *(f"anygrasp_tracking__seq00__{i:03d}" for i in range(24, 30)),
)

_D4XX = re.compile(r"RealSense (D4\d\d|\(D4xx)")


@dataclass(frozen=True)
class RealFrame:
    """One real capture, depth already in sensor units (uint16 mm, 0 = hole)."""

    name: str
    depth_mm: np.ndarray
    sensor: str
    """"d4xx" for RealSense D4xx stereo cameras, "other" for every other active sensor."""
    sequence: str
    index: int
    rgb: np.ndarray | None = None
    window: tuple[int, int] | None = None
    """(top, left) of the policy's crop when the frame was taken by the robot's own camera (a simulated
    capture records its episode's window); None for captures from elsewhere."""
    exact_mm: np.ndarray | None = None
    """The scene's exact depth of the same view, where something independent of the sensor knows it (a
    simulated capture's renderer: what a perfect monocular estimator would make of the RGB); ``ddg fit
    --prior exact`` conditions on it instead of the sensor's own depth. None for real captures."""


def metres_to_mm(depth_m: np.ndarray, name: str = "depth") -> np.ndarray:
    """float metres (0 = hole) -> uint16 mm, the units a RealSense streams."""
    if depth_m.ndim != 2:
        raise RealDataError(f"{name}: depth must be 2-D, got shape {depth_m.shape}")
    if not np.all(np.isfinite(depth_m)):
        raise RealDataError(f"{name}: depth holds {int(np.sum(~np.isfinite(depth_m)))} NaN/inf values "
                            "(holes must be 0)")
    if np.any(depth_m < 0):
        raise RealDataError(f"{name}: depth holds negative values (holes must be 0)")
    return np.clip(np.rint(depth_m * 1000.0), 0, 65535).astype(np.uint16)


def load_real_dir(path: str | Path, sensors: str = "d4xx") -> list[RealFrame]:
    """All frames of a real-capture directory, sorted by name; ``sensors`` = "d4xx" | "all"."""
    root = Path(path)
    files = sorted(root.glob("*.npz")) if root.is_dir() else []
    if not files:
        raise RealDataError(f"no .npz depth frames in {root}")
    if sensors not in ("d4xx", "all"):
        raise RealDataError(f"sensors must be 'd4xx' or 'all', got {sensors!r}")
    manifest = _manifest(root)
    if sensors == "d4xx":  # skip decoding frames the manifest already rules out
        files = [f for f in files if _sensor_kind(manifest.get(f.name, {})) == "d4xx"]
    picked = [_load_frame(f, manifest.get(f.name, {})) for f in files]
    _check_sequences(picked)
    if not picked:
        raise RealDataError(f"no {sensors} frames in {root}")
    return picked


def source_of(name: str) -> str:
    """The capture source a frame's name starts with (``anygrasp_tracking__seq00__024`` ->
    ``anygrasp_tracking``): one camera, lab and kind of scene."""
    return name.split("__")[0]


def split(frames: list[RealFrame], holdout: tuple[str, ...] = HOLDOUT_FRAMES, leave_out: str = ""
          ) -> tuple[list[RealFrame], list[RealFrame]]:
    """(train, held-out) by frame name; ``leave_out``: every frame of that source is held out as well."""
    if leave_out and leave_out not in (sources := sorted({source_of(f.name) for f in frames})):
        raise RealDataError(f"no frames of source {leave_out!r}; the sources are "
                            f"{', '.join(sources)}")
    held = {f.name for f in frames if f.name in holdout or source_of(f.name) == leave_out}
    return [f for f in frames if f.name not in held], [f for f in frames if f.name in held]


def crop_spec(height: int, width: int, scale: float | None = None,
              spec: DepthSpec = POLICY_SPEC) -> DepthSpec:
    """A DepthSpec for a ``height`` x ``width`` stream whose crop has the policy's 3:4 aspect and covers
    ``scale`` of the stream's rows (default: the policy's own share, 300/480), so artifacts land on roughly as
    many policy pixels as on the D455 stream; clamped to the largest window that fits."""
    scale = spec.crop_height / spec.stream_height if scale is None else scale
    aspect = spec.crop_width / spec.crop_height
    crop_h = int(round(min(scale * height, height, width / aspect)))
    crop_h = max(spec.out_height, crop_h)
    crop_w = max(spec.out_width, int(round(crop_h * aspect)))
    if crop_h > height or crop_w > width:
        raise RealDataError(f"a {height}x{width} frame is smaller than the policy resolution "
                            f"{spec.out_height}x{spec.out_width}")
    return replace(spec, stream_height=height, stream_width=width, crop_height=crop_h, crop_width=crop_w)


def policy_crop(depth_mm: np.ndarray, rng: np.random.Generator | None = None, scale: float | None = None,
                spec: DepthSpec = POLICY_SPEC, window: tuple[int, int] | None = None
                ) -> tuple[np.ndarray, DepthSpec, tuple[int, int]]:
    """Crop a frame of any size to the policy resolution with the shared ``crop_resize``: at ``window`` when
    given, else centred when ``rng`` is None, else at random. Returns (uint16 crop, its DepthSpec,
    (top, left))."""
    s = crop_spec(*depth_mm.shape, scale=scale, spec=spec)
    if window is None and rng is None:
        window = s.centred_window()
    elif window is None:
        window = (int(rng.integers(0, s.stream_height - s.crop_height + 1)),
                  int(rng.integers(0, s.stream_width - s.crop_width + 1)))
    return crop_resize(depth_mm, s, window), s, window


def _manifest(root: Path) -> dict[str, dict]:
    f = root / "MANIFEST.json"
    if not f.exists():
        return {}
    return {e["file"]: e for e in json.loads(f.read_text()).get("frames", [])}


def _load_frame(f: Path, meta: dict) -> RealFrame:
    try:
        z = np.load(f)
    except (OSError, ValueError) as e:
        raise RealDataError(f"{f}: not a readable .npz ({e})") from e
    if "depth_m" not in z.files:
        raise RealDataError(f"{f}: no 'depth_m' array (has {sorted(z.files)})")
    depth = metres_to_mm(np.asarray(z["depth_m"], dtype=np.float64), name=str(f))
    rgb = z["rgb"] if "rgb" in z.files else None
    if rgb is not None and rgb.shape[:2] != depth.shape:
        raise RealDataError(f"{f}: rgb {rgb.shape[:2]} and depth {depth.shape} resolutions differ")
    exact = metres_to_mm(np.asarray(z["exact_depth_m"], np.float64), f"{f} exact_depth_m") \
        if "exact_depth_m" in z.files else None
    if exact is not None and exact.shape != depth.shape:
        raise RealDataError(f"{f}: exact_depth_m {exact.shape} and depth {depth.shape} resolutions differ")
    _check_forbidden(f, meta)
    seq = meta.get("sequence_id") or f.stem
    window = tuple(meta["policy_window"]) if "policy_window" in meta else None
    return RealFrame(f.stem, depth, _sensor_kind(meta), seq, int(meta.get("frame_index") or 0), rgb, window,
                     exact)


def _sensor_kind(meta: dict) -> str:
    return "d4xx" if _D4XX.search(meta.get("sensor", "")) else "other"


def _check_forbidden(f: Path, meta: dict) -> None:
    repo, scene = meta.get("source_repo", ""), meta.get("scene_id", "")
    if repo in FORBIDDEN_SOURCES or (repo == "Shreeyak/cleargrasp" and scene.endswith(FORBIDDEN_SCENES)):
        raise RealDataError(f"{f}: comes from the held-out source {repo} {scene}; refusing to use it")


def _check_sequences(frames: list[RealFrame]) -> None:
    shapes: dict[str, tuple[int, int]] = {}
    for fr in frames:
        if shapes.setdefault(fr.sequence, fr.depth_mm.shape) != fr.depth_mm.shape:
            raise RealDataError(f"{fr.name}: resolution {fr.depth_mm.shape} differs from the rest of "
                                f"sequence {fr.sequence} {shapes[fr.sequence]}")
