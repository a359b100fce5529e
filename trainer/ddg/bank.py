"""Training pairs (x0, c) from real captures, with depth augmentations done once up front.

Each frame yields ``crops`` random windows (size jittered around the policy's share of the stream) and a
depth scale jitter (the real captures sit at 0.3-0.7 m, the simulated table at ~0.9 m). Flips are applied
on the fly in training. The bank keeps the crop in sensor units (uint16 mm), c = the prior of the
temporally fused crop (float16) and that prior's ``frame_scale``; ``training_arrays`` gives x0 = the raw
crop ``encode``d on c's scale (holes -1, valid depth in [0, 1]). With ``prior="exact"`` c is made from
the scene's exact depth of the same view instead (a simulated capture's), so what the sensor gets wrong is in
x0 and not in c: the generator can learn it. A bank is a plain .npz, so it travels to another machine
without the raw data.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from runtime.preprocess import DepthSpec, crop_resize

from .data import POLICY_SPEC, RealFrame, crop_spec
from .graft import encode
from .prior import DepthPrior, temporal_fuse


@dataclass(frozen=True)
class BankConfig:
    crops: int = 48
    """Random crops per real frame."""
    scale_range: tuple[float, float] = (0.45, 0.8)
    """Crop height as a share of the stream's rows (the policy's own share is 0.625)."""
    depth_jitter: tuple[float, float] = (0.85, 1.8)
    """Multiplicative depth scale jitter, log-uniform."""
    seed: int = 0
    far_m: float = POLICY_SPEC.far_m
    """Far end of the depth range the prior and the target see (m); see ``FitConfig.far_m``."""
    prior: str = "fused"
    """What c is made from; see ``FitConfig.prior``."""


def fused_frames(frames: list[RealFrame]) -> dict[str, np.ndarray]:
    """Frame name -> depth with holes temporally filled from its sequence neighbours (itself if alone)."""
    by_seq: dict[str, list[RealFrame]] = defaultdict(list)
    for f in frames:
        by_seq[f.sequence].append(f)
    out = {}
    for seq in by_seq.values():
        seq.sort(key=lambda f: f.index)
        fused = temporal_fuse(np.stack([f.depth_mm for f in seq])) if len(seq) > 1 else [seq[0].depth_mm]
        out.update({f.name: d for f, d in zip(seq, fused, strict=True)})
    return out


def build_bank(frames: list[RealFrame], cfg: BankConfig = BankConfig()) -> dict[str, np.ndarray]:
    """{"depth_mm": uint16 [N, H, W], "c": float16 [N, H, W], "scale": float32 [N, 2] (lo, span),
    "frame": int [N], "names": str [F], "far_m": float (the range's far end), "prior": c's source}."""
    rng = np.random.default_rng(cfg.seed)
    sources = prior_sources(frames, cfg.prior)
    prior = DepthPrior(range_spec(cfg.far_m))
    crops, c, scales, idx = [], [], [], []
    for i, f in enumerate(tqdm(frames, desc="crop bank", leave=False)):
        for _ in range(cfg.crops):
            s = crop_spec(*f.depth_mm.shape, scale=rng.uniform(*cfg.scale_range))
            win = (int(rng.integers(0, s.stream_height - s.crop_height + 1)),
                   int(rng.integers(0, s.stream_width - s.crop_width + 1)))
            k = np.exp(rng.uniform(*np.log(cfg.depth_jitter)))
            raw, base = (_scaled(crop_resize(d, s, win), k) for d in (f.depth_mm, sources[f.name]))
            if (raw > 0).mean() < 0.2:  # a window that is mostly hole teaches nothing about geometry
                continue
            prior_c, scale = prior.with_scale(base)
            crops.append(raw)
            c.append(prior_c.astype(np.float16))
            scales.append(scale)
            idx.append(i)
    return {"depth_mm": np.stack(crops), "c": np.stack(c), "scale": np.array(scales, np.float32),
            "frame": np.array(idx),
            "names": np.array([f.name for f in frames]), "far_m": np.float64(cfg.far_m), "prior": cfg.prior}


def prior_sources(frames: list[RealFrame], prior: str) -> dict[str, np.ndarray]:
    """Frame name -> the depth its c is made from: the sensor's own, temporally fused (``fused``), or the
    scene's exact depth of the same view (``exact``)."""
    if prior == "fused":
        return fused_frames(frames)
    if prior != "exact":
        raise ValueError(f"unknown prior {prior!r}: fused or exact")
    missing = [f.name for f in frames if f.exact_mm is None]
    if missing:
        raise ValueError(f"--prior exact needs each frame's exact depth (exact_depth_m, as "
                         f"trainer.sim.capture writes); {len(missing)} frames have none, e.g. {missing[0]}")
    return {f.name: f.exact_mm for f in frames}


def range_spec(far_m: float) -> DepthSpec:
    """The policy's DepthSpec with the generator's depth range ending at ``far_m``."""
    return replace(POLICY_SPEC, far_m=far_m)


def bank_spec(bank: dict[str, np.ndarray]) -> DepthSpec:
    """The DepthSpec the bank's prior and targets were made with (older banks: the policy's)."""
    return range_spec(float(bank.get("far_m", POLICY_SPEC.far_m)))


def bank_prior(bank: dict[str, np.ndarray]) -> str:
    """What the bank's c was made from (older banks: the fused sensor depth)."""
    return str(bank.get("prior", "fused"))


def training_arrays(bank: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(x0, c) float32 [N, H, W] on the generator's scale."""
    if "scale" not in bank:
        raise ValueError("crop bank has no 'scale' array (built before the relative target); rebuild it")
    spec = bank_spec(bank)
    x0 = np.stack([encode(d, s, spec) for d, s in zip(bank["depth_mm"], bank["scale"], strict=True)])
    return x0, bank["c"].astype(np.float32)


def concat_banks(banks: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One bank from several (e.g. D4xx crops + other-sensor crops), frame indices kept distinct."""
    far, prior = {bank_spec(b).far_m for b in banks}, {bank_prior(b) for b in banks}
    if len(far) > 1:
        raise ValueError(f"crop banks made with different depth ranges (far_m {sorted(far)}) cannot be mixed")
    if len(prior) > 1:
        raise ValueError(f"crop banks made with different priors ({sorted(prior)}) cannot be mixed")
    offsets = np.cumsum([0] + [len(b["names"]) for b in banks[:-1]])
    return {"depth_mm": np.concatenate([b["depth_mm"] for b in banks]),
            "c": np.concatenate([b["c"] for b in banks]),
            "scale": np.concatenate([b["scale"] for b in banks]),
            "frame": np.concatenate([b["frame"] + o for b, o in zip(banks, offsets, strict=True)]),
            "names": np.concatenate([b["names"] for b in banks]), "far_m": np.float64(far.pop()),
            "prior": prior.pop()}


def save_bank(bank: dict[str, np.ndarray], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **bank)


def load_bank(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _scaled(depth_mm: np.ndarray, k: float) -> np.ndarray:
    return np.where(depth_mm > 0, np.clip(np.rint(depth_mm * k), 1, 65535), 0).astype(np.uint16)
