"""DDIM sampling of the generator (diffusers' DDIMScheduler, the one implementation of the update), with the
U-Net run by onnxruntime (``OnnxEps``, for generation) or torch (``TorchEps``, the reference in tests).

Each frame's start noise comes from its own generator seeded by (seed, frame index), so the output for a frame
does not depend on batching, sharding or resuming.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from .graft import decode, graft
from .model import ddim_scheduler, load_config, load_unet
from .prior import DepthPrior


class EpsFn(Protocol):
    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        """x float32 [B, 2, H, W] = d_k ⊕ c, timestep t -> predicted noise float32 [B, 1, H, W]."""
        ...


class OnnxEps:
    def __init__(self, model_dir: str | Path, threads: int = 2) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(Path(model_dir) / "unet.onnx"), opts,
                                            providers=["CPUExecutionProvider"])

    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        return self.session.run(None, {"x": x, "t": np.full(len(x), t, np.int64)})[0]


class TorchEps:
    def __init__(self, model_dir: str | Path) -> None:
        self.unet, _ = load_unet(model_dir)

    @torch.no_grad()
    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        return self.unet(torch.from_numpy(x), torch.full((len(x),), t)).sample.numpy()


def frame_noise(seed: int, indices: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """float32 [B, 1, H, W]: N(0, I) start noise, one generator per (seed, frame index)."""
    return np.stack([np.random.default_rng([seed, int(i)]).standard_normal(shape, np.float32)
                     for i in indices])[:, None]


def ddim_sample(eps_fn: EpsFn, c: np.ndarray, noise: np.ndarray, scheduler) -> np.ndarray:
    """Reverse process from ``noise`` [B, 1, H, W] under condition ``c`` [B, H, W] -> d_pred [B, H, W]."""
    x = torch.from_numpy(noise)
    cond = c[:, None].astype(np.float32)
    for t in scheduler.timesteps:
        eps = eps_fn(np.concatenate([x.numpy(), cond], axis=1), int(t))
        x = scheduler.step(torch.from_numpy(eps), t, x, eta=0.0).prev_sample
    return x.numpy()[:, 0]


class Generator:
    """Simulated uint16 mm frames -> (DDG, DDG without grafting) uint16 mm frames."""

    def __init__(self, model_dir: str | Path, steps: int = 10, seed: int = 0, threads: int = 2,
                 backend: str = "onnx") -> None:
        cfg = load_config(model_dir)
        self.spec, self.threshold, self.seed = cfg["depth_spec"], cfg["hole_threshold"], seed
        self.scheduler = ddim_scheduler(cfg["unet"], steps)
        self.eps = OnnxEps(model_dir, threads) if backend == "onnx" else TorchEps(model_dir)
        self.prior = DepthPrior(self.spec)

    def __call__(self, sim_mm: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.stack([self.prior(d) for d in sim_mm])
        noise = frame_noise(self.seed, indices, sim_mm.shape[1:])
        pred_mm = decode(ddim_sample(self.eps, c, noise, self.scheduler), self.spec, self.threshold)
        grafted = np.stack([graft(s, p, self.spec) for s, p in zip(sim_mm, pred_mm, strict=True)])
        return grafted, pred_mm
