"""Hole and noise statistics of a depth frame, computed the same way on real captures and on the sensor.

* ``hole_fraction``: share of pixels without depth.
* ``band_ratio``: width of the left no-data band over its D4xx theory f*B/z (z the frame's median
  depth); 1 means the band is exactly the strip the right imager cannot see.
* hole sizes: connected holes right of the band, in millionths of the frame area (size-independent).
* ``plane_sigma_px``: noise on flat patches as disparity in the sensor's own pixels (the D4xx "subpixel
  RMS"; depth noise is sigma_z = sigma_d z^2 / (f B)), so sensors and distances compare. The plane is
  fitted to disparity f B / z, where a slanted plane is exactly linear (in depth it is curved).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

PATCH_FRACTION = 1 / 40
"""Plane-fit patch side as a fraction of the frame width (16 px at 640)."""
QUIET_QUANTILE = 25
"""Patches are fitted anywhere; the quietest quarter are the flat ones, where noise is the sensor's."""


@dataclass(frozen=True)
class Camera:
    """What the statistics need to know of the sensor: focal length (px) and stereo baseline (m)."""

    fx: float
    baseline_m: float
    pixel_scale: float = 1.0
    """Sensor pixels per pixel of the depth image given (the simulation matches at 1/n of its stream)."""


def hole_stats(depth_m: np.ndarray, cam: Camera, seen: np.ndarray | None = None) -> dict:
    """Hole fraction, left band and hole-size quantiles of one frame (0 = no data), counted over the
    pixels in ``seen`` (default all: in a simulation, where a surface lies within the sensor's range)."""
    seen = np.ones(depth_m.shape, bool) if seen is None else seen
    holes = (depth_m <= 0) & seen
    h, w = holes.shape
    area = max(int(seen.sum()), 1)
    z_med = float(np.median(depth_m[depth_m > 0])) if np.any(depth_m > 0) else float("nan")
    band = left_band(holes, seen)
    rest = holes[:, band:]
    sizes = np.zeros(0)
    if rest.size:  # OpenCV crashes on an empty image (a frame that is all band)
        _, _, comp, _ = cv2.connectedComponentsWithStats(np.ascontiguousarray(rest, np.uint8), connectivity=8)
        sizes = comp[1:, cv2.CC_STAT_AREA] / area
    return {"hole_fraction": float(holes.sum() / area), "band_px_per_width": band / w,
            "band_ratio": band / (cam.fx * cam.baseline_m / z_med),
            "holes_outside_band": float(rest.sum() / area),
            "holes_per_frame": sizes.size,
            "hole_size_p50_ppm": 1e6 * float(np.median(sizes)) if sizes.size else 0.0,
            "hole_size_p90_ppm": 1e6 * float(np.percentile(sizes, 90)) if sizes.size else 0.0,
            "median_z_m": z_med}


def left_band(holes: np.ndarray, seen: np.ndarray | None = None) -> int:
    """Columns from the left edge that are mostly (> 50 % of their ``seen`` pixels) without depth."""
    seen = np.ones(holes.shape, bool) if seen is None else seen
    mostly = holes.sum(axis=0) > 0.5 * np.maximum(seen.sum(axis=0), 1)
    return int(np.argmin(mostly)) if not mostly.all() else holes.shape[1]


def plane_noise(depth_m: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(z, sigma_d px) of the quiet patches: the quietest ``QUIET_QUANTILE`` % of the fully valid ones."""
    h, w = depth_m.shape
    side = max(8, round(w * PATCH_FRACTION))
    v, u = np.mgrid[0:side, 0:side].astype(np.float64)
    design = np.column_stack([u.ravel(), v.ravel(), np.ones(side * side)])
    pinv = np.linalg.pinv(design)
    zs, sig = [], []
    for top in range(0, h - side + 1, side):
        for left in range(0, w - side + 1, side):
            patch = depth_m[top:top + side, left:left + side].astype(np.float64).ravel()
            if np.all(patch > 0):
                disp = cam.fx * cam.baseline_m / patch  # a plane is linear in disparity, not in depth
                zs.append(float(patch.mean()))
                sig.append(float((disp - design @ (pinv @ disp)).std()) * cam.pixel_scale)
    zs, sig = np.asarray(zs), np.asarray(sig)
    if sig.size == 0:
        return zs, sig
    quiet = sig <= np.percentile(sig, QUIET_QUANTILE)
    return zs[quiet], sig[quiet]


def noise_vs_z(zs: np.ndarray, sig: np.ndarray, edges: np.ndarray) -> list[dict]:
    """Median disparity noise and the matching depth noise (mm) in each z bin with patches."""
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        inside = (zs >= lo) & (zs < hi)
        if inside.sum() >= 3:
            rows.append({"z_m": round(float(zs[inside].mean()), 3), "patches": int(inside.sum()),
                         "sigma_d_px": round(float(np.median(sig[inside])), 4)})
    return rows
