"""DDIM sampling of the generator (diffusers' DDIMScheduler, the one implementation of the update), with the
U-Net run by onnxruntime (``OnnxEps``, for generation) or torch (``TorchEps``, the reference in tests). The
residual diffusion (``residual.py``) samples its two-channel targets through the same ``ddim_reverse``.

Each frame's start noise (and, with eta > 0, each step's fresh noise) comes from its own generator seeded by
(seed, frame index), so the output for a frame does not depend on batching, sharding or resuming.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from tqdm import tqdm

from runtime.preprocess import DepthSpec, resample
from trainer.dataset import sizes

from .graft import decode, graft
from .model import X0_SCALE, ddim_scheduler, load_config, load_unet
from .prior import DepthPrior


class FrameError(ValueError):
    """Simulated frames the generator cannot take (wrong dtype, rank or resolution)."""


class EpsFn(Protocol):
    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        """x float32 [B, C + Cc, H, W] = d_k ⊕ c (the DDG: C = Cc = 1), timestep t -> predicted noise
        float32 [B, C, H, W]."""
        ...


SESSION_MODES = ("split", "intra", "intra_spin")
"""How ``OnnxEps`` spreads a batch over ``threads`` cores (``python -m trainer ddg bench`` compares them).
split: one single-threaded session called once per frame, ``threads`` calls at a time (measured fastest: a
one-frame call costs the least CPU per frame, as the mid attention's [heads, 768, 768] scores stay in cache);
intra: one call per batch with ``threads`` intra-op threads that sleep when idle; intra_spin: the same with
onnxruntime's default spin-waiting (fast on an idle machine, burns a shared one's cores)."""


class OnnxEps:
    def __init__(self, model_dir: str | Path, threads: int = 2, mode: str = "split") -> None:
        import onnxruntime as ort

        if mode not in SESSION_MODES:
            raise ValueError(f"session mode must be one of {SESSION_MODES}, got {mode!r}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1 if mode == "split" else threads
        opts.inter_op_num_threads = 1
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if mode == "intra_spin" else "0")
        self.session = ort.InferenceSession(str(Path(model_dir) / "unet.onnx"), opts,
                                            providers=["CPUExecutionProvider"])
        # onnxruntime releases the GIL, so Python threads run the single-threaded calls in parallel
        self.pool = ThreadPoolExecutor(threads) if mode == "split" and threads > 1 else None
        self.per_frame = mode == "split"

    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        if not self.per_frame or len(x) == 1:
            return self._run(x, t)
        run = self.pool.map if self.pool else map
        return np.concatenate(list(run(self._run, np.split(x, len(x)), [t] * len(x))))

    def _run(self, x: np.ndarray, t: int) -> np.ndarray:
        return self.session.run(None, {"x": x, "t": np.full(len(x), t, np.int64)})[0]


class TorchEps:
    def __init__(self, model_dir: str | Path, x0_scale: str = X0_SCALE) -> None:
        self.unet, _ = load_unet(model_dir, x0_scale)

    @torch.no_grad()
    def __call__(self, x: np.ndarray, t: int) -> np.ndarray:
        return self.unet(torch.from_numpy(x), torch.full((len(x),), t)).sample.numpy()


def frame_noise(seed: int, indices: np.ndarray, shape: tuple[int, int], step: int = -1, channels: int = 1
                ) -> np.ndarray:
    """float32 [B, channels, H, W]: N(0, I) noise, one generator per (seed, frame index): the start noise, or
    with ``step`` >= 0 the fresh noise that DDIM step ``step`` adds when eta > 0."""
    keys = [[seed, int(i)] if step < 0 else [seed, int(i), step] for i in indices]
    return np.stack([np.random.default_rng(k).standard_normal((channels, *shape), np.float32) for k in keys])


def ddim_sample(eps_fn: EpsFn, c: np.ndarray, noise: np.ndarray, scheduler, eta: float = 0.0,
                step_noise: Callable[[int], np.ndarray] | None = None) -> np.ndarray:
    """Reverse process from ``noise`` [B, 1, H, W] under condition ``c`` [B, H, W] -> d_pred [B, H, W].
    eta = 0 is deterministic DDIM; eta > 0 adds ``step_noise(k)`` at step k (eta = 1: DDPM-like)."""
    return ddim_reverse(eps_fn, c[:, None], noise, scheduler, eta, step_noise)[:, 0]


def ddim_reverse(eps_fn: EpsFn, cond: np.ndarray, noise: np.ndarray, scheduler, eta: float = 0.0,
                 step_noise: Callable[[int], np.ndarray] | None = None) -> np.ndarray:
    """``ddim_sample`` for any channel counts: ``noise`` [B, C, H, W], condition ``cond`` [B, Cc, H, W] ->
    x_0 [B, C, H, W]."""
    x = torch.from_numpy(noise)
    cond = cond.astype(np.float32)
    for k, t in enumerate(scheduler.timesteps):
        eps = eps_fn(np.concatenate([x.numpy(), cond], axis=1), int(t))
        fresh = torch.from_numpy(step_noise(k)) if eta > 0 and step_noise is not None else None
        x = scheduler.step(torch.from_numpy(eps), t, x, eta=eta, variance_noise=fresh).prev_sample
    return x.numpy()


def check_frames(sim_mm, spec: DepthSpec, whose: str = "the model's") -> None:
    """Refuse simulated frames that are not uint16 mm [N, H, W] at ``spec``'s resolution."""
    want = (spec.out_height, spec.out_width)
    if sim_mm.dtype != np.uint16 or sim_mm.ndim != 3 or tuple(sim_mm.shape[1:]) != want:
        raise FrameError(f"simulated depth must be uint16 mm [N, {want[0]}, {want[1]}] ({whose} "
                         f"resolution), got {sim_mm.dtype} {list(sim_mm.shape)}")


class Generator:
    """Simulated uint16 mm frames -> (DDG, DDG without grafting) uint16 mm frames.

    ``frames``: the spec of the frames it is given (default: the model's). They may be at another resolution
    of the same crop: the generator runs at its own resolution on a nearest-neighbour copy, and its holes are
    carried back the same way and grafted onto the frames as given (a finer student keeps finer geometry).
    """

    def __init__(self, model_dir: str | Path, steps: int = 10, seed: int = 0, threads: int = 2,
                 backend: str = "onnx", mode: str = "split", eta: float = 0.0, frames: DepthSpec | None = None
                 ) -> None:
        cfg = load_config(model_dir)
        self.spec, self.threshold, self.seed, self.eta = cfg["depth_spec"], cfg["hole_threshold"], seed, eta
        self.frames = frames or self.spec
        same_view = replace(self.frames, out_height=self.spec.out_height, out_width=self.spec.out_width)
        if same_view != self.spec:
            raise FrameError(f"the DDG {model_dir} reads {sizes(self.spec)} over {self.spec.near_m}-"
                             f"{self.spec.far_m} m of a {self.spec.stream_width}x{self.spec.stream_height} "
                             f"stream; frames of another crop, range or stream cannot be carried to it")
        self.scheduler = ddim_scheduler(cfg["unet"], steps)
        self.eps = OnnxEps(model_dir, threads, mode) if backend == "onnx" else TorchEps(model_dir)
        self.prior = DepthPrior(self.spec)

    def check_frames(self, sim_mm) -> None:
        """Refuse frames not at the resolution announced (the U-Net is fully convolutional: it would run)."""
        whose = "the model's" if self.frames == self.spec else "the frames' spec"
        check_frames(sim_mm, self.frames, whose)

    def __call__(self, sim_mm: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.check_frames(sim_mm)
        own = (self.spec.out_height, self.spec.out_width)
        small = resample(sim_mm, *own) if sim_mm.shape[1:] != own else sim_mm
        c, scale = zip(*(self.prior.with_scale(d) for d in small), strict=True)
        c = np.stack(c)
        noise = frame_noise(self.seed, indices, own)
        pred = ddim_sample(self.eps, c, noise, self.scheduler, self.eta,
                           lambda k: frame_noise(self.seed, indices, own, k))
        pred_mm = decode(pred, np.array(scale), self.spec, self.threshold)
        if small is not sim_mm:
            pred_mm = resample(pred_mm, *sim_mm.shape[1:])
        grafted = np.stack([graft(s, p, self.frames) for s, p in zip(sim_mm, pred_mm, strict=True)])
        return grafted, pred_mm


def generate_frames(gen: Callable, sim_mm: np.ndarray, desc: str, batch: int = 16) -> np.ndarray | tuple:
    """Every frame of ``sim_mm`` through a generator (``Generator``, ``ResidualGenerator``), ``batch`` at a
    time, frame i seeded by its index i: its output frames, or each of its outputs' (the DDG's two)."""
    parts = []
    for i in tqdm(range(0, len(sim_mm), batch), desc=desc, unit="batch"):
        frames = sim_mm[i:i + batch]
        parts.append(gen(frames, np.arange(i, i + len(frames))))
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(output) for output in zip(*parts, strict=True))
    return np.concatenate(parts)
