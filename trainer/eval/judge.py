"""Realism features and the distances between feature sets (FID, KID).

No pretrained network can be downloaded here, so the judge is a randomly initialised, fixed-seed conv net
(4 layers, channel means of every layer: 288 features). Why it is a fair judge: its weights were tuned on
nothing, so it cannot favour the DDG (or any source) by construction; it is multi-scale and sees exactly what
matters for sim-to-real depth, a hole channel and the shape of valid depth; and every source goes through
the same frozen net. Random conv features are known to rank generative models sensibly (Naeem et al. 2020,
"Reliable Fidelity and Diversity Metrics"). Depth enters relative (per-frame 1st-99th percentile of the valid
pixels -> [0, 1]), so the metric compares artifacts and local geometry, not the camera's distance to the
table, which differs between the real captures and the simulator.

Its limit, measured (docs/ddg.md "Views matched to the real captures"): channel means see how many holes
there are and how large, not whether they fall where a D4xx loses depth (procedural rand-noise holes score as
real as the DDG's on the hole channel alone), and the depth channel still reads the scene's layout.
``ddg paired`` judges hole placement pixel by pixel where the exact scene is known.
"""

from __future__ import annotations

import numpy as np
import torch

FEATURE_SEED = 1234


class RandomEncoder(torch.nn.Module):
    def __init__(self, seed: int = FEATURE_SEED) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        shapes = [(32, 2, 3, 1), (64, 32, 4, 2), (64, 64, 4, 2), (128, 64, 4, 2)]
        self.layers = torch.nn.ModuleList()
        for out_c, in_c, k, stride in shapes:
            conv = torch.nn.Conv2d(in_c, out_c, k, stride=stride, padding=k // 2)
            with torch.no_grad():  # He init from our own generator: identical weights on every machine
                conv.weight.copy_(torch.randn(conv.weight.shape, generator=g) * np.sqrt(2.0 / (in_c * k * k)))
                conv.bias.zero_()
            self.layers.append(conv)

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = []
        for conv in self.layers:
            x = torch.relu(conv(x))
            feats.append(x.mean(dim=(2, 3)))
        return torch.cat(feats, dim=1)


JUDGE_CHANNELS = ("both", "depth", "holes")
"""What the judge sees: both channels, or one with the other zeroed (the same frozen net either way)."""


def encoder_input(depth_mm: np.ndarray, channels: str = "both") -> np.ndarray:
    """uint16 mm [N, H, W] -> float32 [N, 2, H, W]: relative valid depth (0 at holes) and the hole mask;
    ``channels`` = "depth" or "holes" zeroes the other one."""
    if channels not in JUDGE_CHANNELS:
        raise ValueError(f"channels must be one of {JUDGE_CHANNELS}, got {channels!r}")
    out = np.zeros((len(depth_mm), 2, *depth_mm.shape[1:]), np.float32)
    for i, d in enumerate(depth_mm):
        valid = d > 0
        if valid.any():
            lo, hi = np.percentile(d[valid], [1, 99])
            out[i, 0] = np.where(valid, np.clip((d - lo) / max(hi - lo, 1.0), 0, 1), 0)
        out[i, 1] = ~valid
    if channels != "both":
        out[:, 1 if channels == "depth" else 0] = 0
    return out


def features(depth_mm: np.ndarray, encoder: RandomEncoder | None = None, channels: str = "both",
             batch: int = 128) -> np.ndarray:
    enc = encoder or RandomEncoder()
    x = encoder_input(depth_mm, channels)
    return np.concatenate([enc(torch.from_numpy(x[i:i + batch])).numpy() for i in range(0, len(x), batch)])


def fid(a: np.ndarray, b: np.ndarray) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets.

    tr sqrt(Ca Cb) = sum of sqrt(eigenvalues) of the symmetric Ca^1/2 Cb Ca^1/2: two symmetric eigen-
    decompositions instead of a general matrix square root (exact, and fast enough to bootstrap)."""
    mu_a, mu_b = a.mean(0), b.mean(0)
    eps = 1e-6 * np.eye(a.shape[1])
    ca, cb = np.cov(a, rowvar=False) + eps, np.cov(b, rowvar=False) + eps
    w, v = np.linalg.eigh(ca)
    root_a = (v * np.sqrt(np.clip(w, 0, None))) @ v.T
    tr_covmean = np.sqrt(np.clip(np.linalg.eigvalsh(root_a @ cb @ root_a), 0, None)).sum()
    return float(np.sum((mu_a - mu_b) ** 2) + np.trace(ca) + np.trace(cb) - 2 * tr_covmean)


def kid(a: np.ndarray, b: np.ndarray, subsets: int = 50, size: int = 100, seed: int = 0) -> float:
    """Kernel Inception Distance: unbiased MMD^2 with the cubic polynomial kernel, mean over subsets."""
    rng = np.random.default_rng(seed)
    m = min(size, len(a), len(b))
    d = a.shape[1]
    vals = []
    for _ in range(subsets):
        x, y = a[rng.choice(len(a), m, replace=False)], b[rng.choice(len(b), m, replace=False)]
        kxx, kyy, kxy = ((x @ x.T) / d + 1) ** 3, ((y @ y.T) / d + 1) ** 3, ((x @ y.T) / d + 1) ** 3
        off = (kxx.sum() - np.trace(kxx) + kyy.sum() - np.trace(kyy)) / (m * (m - 1))
        vals.append(off - 2 * kxy.mean())
    return float(np.mean(vals))
