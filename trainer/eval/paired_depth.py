"""``python -m trainer ddg paired``: each depth source against the exact depth of the same view.

The realism metrics (``realism``) compare distributions, and a grafted DDG scores near-perfectly there
while its depth is never wrong: grafting keeps the simulator's exact depth wherever no hole is predicted. A
simulated capture (``python -m trainer.sim.capture``) carries the scene's exact depth beside the sensor's, so
here each DDG is run on that exact depth and, with the sensor itself, judged pixel by pixel against it, in the
policy's crop and depth range: the share of it a source loses, how far off the depth it keeps is, and how
many of its holes fall where the sensor has its own in the same view.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from runtime.preprocess import DepthSpec, crop_resize
from trainer.ddg.baselines import randnoise
from trainer.ddg.data import POLICY_SPEC, RealDataError, RealFrame, load_real_dir
from trainer.ddg.sample import Generator


@dataclass(frozen=True)
class PairedConfig:
    real: str = "runs/stereo_real/heldout48"
    """Simulated captures that carry the exact depth (``exact_depth_m``, as trainer.sim.capture writes)."""
    model: tuple[str, ...] = ("models/ddg_stereo",)
    """DDG model directories to judge, each with and without grafting."""
    steps: int = 5
    """DDIM steps of generation."""
    threads: int = 2
    """onnxruntime threads."""
    json: str = ""
    """Also write the results to this JSON file."""


def policy_range(exact_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """The pixels judged: those whose exact depth lies in the policy's range."""
    return (exact_mm >= spec.near_m * 1000) & (exact_mm <= spec.far_m * 1000)


def wrong_depth(depth_mm: np.ndarray, exact_mm: np.ndarray, spec: DepthSpec = POLICY_SPEC) -> dict:
    """Frames [N, H, W] against the exact depth of the same views, over the pixels whose exact depth lies in
    the policy's range: the share without data (%), and how far off the rest is (mm, and % over 50 mm)."""
    if depth_mm.shape != exact_mm.shape:
        raise ValueError(f"frames {depth_mm.shape} and exact depth {exact_mm.shape} differ in shape")
    in_range = policy_range(exact_mm, spec)
    kept = in_range & (depth_mm > 0)
    off = np.abs(depth_mm[kept].astype(np.float32) - exact_mm[kept])
    if not off.size:
        raise ValueError("no pixel both in the policy's depth range and measured")
    p50, p90, p99 = (float(v) for v in np.percentile(off, [50, 90, 99]))
    return {"holes_pct": round(100 * (1 - kept.sum() / in_range.sum()), 2), "off_median_mm": round(p50, 1),
            "off_p90_mm": round(p90, 1), "off_p99_mm": round(p99, 1),
            "off_over_50mm_pct": round(100 * float(np.mean(off > 50)), 2)}


def hole_agreement(depth_mm: np.ndarray, sensor_mm: np.ndarray, exact_mm: np.ndarray,
                   spec: DepthSpec = POLICY_SPEC) -> dict:
    """Within the policy's range of the exact depth: the share of the sensor's holes the source has too (%),
    and the share of the source's holes that are the sensor's (%). By chance both are near the other's hole
    share; a source that puts holes where the sensor does scores high on both."""
    in_range = policy_range(exact_mm, spec)
    mine, theirs = in_range & (depth_mm == 0), in_range & (sensor_mm == 0)
    both = float((mine & theirs).sum())
    return {"sensor_holes_shared_pct": round(100 * both / max(theirs.sum(), 1), 1),
            "holes_the_sensors_pct": round(100 * both / max(mine.sum(), 1), 1)}


def policy_views(frames: list[RealFrame]) -> tuple[np.ndarray, np.ndarray]:
    """(sensor, exact) uint16 [N, 96, 128]: each frame and its exact depth in its episode's policy crop."""
    missing = [f.name for f in frames if f.exact_mm is None or f.window is None]
    if missing:
        raise RealDataError(f"{len(missing)} frames lack the exact depth or the policy window of a simulated "
                            f"capture (python -m trainer.sim.capture), e.g. {missing[0]}")
    return tuple(np.stack([crop_resize(d, POLICY_SPEC, f.window) for f, d in zip(frames, depth, strict=True)])
                 for depth in ([f.depth_mm for f in frames], [f.exact_mm for f in frames]))


def paired(cfg: PairedConfig) -> dict:
    sensor, exact = policy_views(load_real_dir(cfg.real))
    rng = np.random.default_rng(0)  # randnoise: holes and noise that know nothing of the sensor, for scale
    sources = {"sensor": sensor, "randnoise": np.stack([randnoise(e, rng) for e in exact])}
    for model in cfg.model:
        grafted, ungrafted = Generator(model, cfg.steps, threads=cfg.threads)(exact, np.arange(len(exact)))
        sources.update({f"{model} grafted": grafted, f"{model} ungrafted": ungrafted})
    result = {"frames": len(exact), "config": asdict(cfg),
              "sources": {k: {**wrong_depth(v, exact), **hole_agreement(v, sensor, exact)}
                          for k, v in sources.items()}}
    print(f"{len(exact)} frames; policy range {POLICY_SPEC.near_m}-{POLICY_SPEC.far_m} m of the exact depth")
    print("| source | holes % | of the sensor's holes, shared % | of its holes, the sensor's % | off exact, "
          "median / p90 / p99 mm | off > 50 mm % |\n|---|---|---|---|---|---|")
    for name, s in result["sources"].items():
        print(f"| {name} | {s['holes_pct']} | {s['sensor_holes_shared_pct']} | {s['holes_the_sensors_pct']} "
              f"| {s['off_median_mm']} / {s['off_p90_mm']} / {s['off_p99_mm']} | {s['off_over_50mm_pct']} |")
    if cfg.json:
        Path(cfg.json).parent.mkdir(parents=True, exist_ok=True)
        Path(cfg.json).write_text(json.dumps(result, indent=1) + "\n")
    return result
