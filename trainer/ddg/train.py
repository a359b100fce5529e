"""DDPM training of the conditional U-Net on real crops (paper eq. 8), with EMA, checkpoints and resume.

Batches and noise are drawn from generators seeded by (seed, step), so a resumed run continues exactly as an
uninterrupted one would. ``train`` is the loop on any (x0, c) arrays, with an optional per-pixel loss weight:
the residual diffusion's two stages (``residual_fit.py``) run it too.
"""

from __future__ import annotations

import copy
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from tqdm import tqdm

from trainer.diffusion import training_target

from .bank import (
    BankConfig,
    bank_prior,
    bank_spec,
    build_bank,
    concat_banks,
    load_bank,
    save_bank,
    training_arrays,
)
from .data import POLICY_SPEC, load_real_dir, split
from .graft import HOLE_THRESHOLD
from .model import UNetConfig, build_unet, ddpm_scheduler, save_model


class LoopSettings(Protocol):
    """What ``train`` reads of a fit's config (``FitConfig``; ``residual_fit.StageConfig``)."""

    steps: int
    batch: int
    lr: float
    ema_decay: float
    ckpt_every: int
    max_minutes: float
    seed: int
    device: str
    patch: tuple[int, ...]


@dataclass(frozen=True)
class FitConfig:
    real: str = "../shared/data/real_depth"
    """Directory of real captures (.npz with depth_m, + MANIFEST.json)."""
    out: str = "runs/ddg/model"
    """Model directory written at the end (config.json, unet.safetensors, unet.onnx, loss.png, frames.txt)."""
    run: str = "runs/ddg/fit"
    """Run directory: checkpoint (resumed from when present), crop bank, loss curve."""
    bank: tuple[str, ...] = ()
    """Prebuilt crop bank(s) .npz to train on (concatenated) instead of building one from --real."""
    sensors: str = "d4xx"
    """Which real frames to learn from: d4xx (RealSense D4xx only) or all (every active sensor)."""
    leave_out: str = ""
    """A capture source to train without (the name before '__', e.g. anygrasp_tracking), for ``ddg metrics
    --source`` to judge the generator on captures it never saw."""
    crops: int = 48
    """Random crops per real frame in the bank."""
    steps: int = 6000
    """Optimiser steps."""
    batch: int = 16
    """Crops per step."""
    lr: float = 3e-4
    """AdamW learning rate (cosine decay to 10%)."""
    ema_decay: float = 0.999
    """EMA of the weights; the EMA copy is the shipped model."""
    ckpt_every: int = 250
    """Steps between checkpoints."""
    max_minutes: float = 0.0
    """Stop (and export) after this much wall time; 0 = no limit. Keeps a shared-CPU run inside its budget."""
    seed: int = 0
    """Seed for the bank, batches and noise."""
    device: str = "cpu"
    """torch device."""
    threads: int = 2
    """torch CPU threads."""
    patch: tuple[int, ...] = (48, 64)
    """Train on random patches of this size (rows cols; 0 0 = whole crops): the net is fully convolutional,
    so a quarter-size patch gives 4x the steps on a CPU budget; generation runs on whole frames."""
    channels: tuple[int, ...] = UNetConfig.channels
    """U-Net widths per level."""
    prediction: str = UNetConfig.prediction
    """What the U-Net predicts: v_prediction or epsilon (see trainer/ddg/model.py)."""
    far_m: float = POLICY_SPEC.far_m
    """Far end (m) of the depth range the prior and the target see; recorded in the model, whose generation
    then uses it too. The policy's own 1.5 m flattens everything beyond it, so a loss that grows with range
    past it (a stereo camera's far floor) cannot be learnt; a larger value can. The student still clips at
    1.5 m."""
    prior: str = "fused"
    """What the condition c is made from in training: fused (the sensor's own depth, holes filled: the
    offline default) or exact (the scene's exact depth of the same view, which simulated captures carry: the
    stand-in for a perfect RGB depth prior). With fused, c already holds what the sensor gets wrong, so the
    generator can learn only its holes; with exact it can learn its wrong depth too. Generation always
    conditions on the simulated depth."""


def fit(cfg: FitConfig) -> Path:
    torch.set_num_threads(cfg.threads)
    run, out = Path(cfg.run), Path(cfg.out)
    run.mkdir(parents=True, exist_ok=True)
    bank, names = _bank(cfg, run)
    ucfg = UNetConfig(channels=cfg.channels, prediction=cfg.prediction)
    ema, losses, minutes = train(build_unet(ucfg), ucfg, training_arrays(bank), cfg, run, "ddg fit")
    extra = {"hole_threshold": HOLE_THRESHOLD, "train": {**asdict(cfg), "steps_done": len(losses),
             "train_minutes": round(minutes, 2), "n_crops": int(len(bank["c"]))}, "frames": names}
    save_model(out, ema, ucfg, bank_spec(bank), extra)
    plot_losses(losses, out / "loss.png")
    (out / "frames.txt").write_text("\n".join(names) + "\n")
    return out


def train(unet: torch.nn.Module, ucfg: UNetConfig, arrays: tuple[np.ndarray, ...], cfg: LoopSettings,
          run: Path, desc: str, title: str = "DDG training loss"
          ) -> tuple[torch.nn.Module, list[float], float]:
    """The DDPM loop on ``arrays`` = (x0, c[, weight]) (``train_step``), checkpointed in ``run`` every
    ``cfg.ckpt_every`` steps and resumed from there; returns (the EMA net on the CPU, every step's loss, the
    minutes it trained, resumed runs' included)."""
    unet = unet.to(cfg.device)
    ema = copy.deepcopy(unet).requires_grad_(False)
    opt = torch.optim.AdamW(unet.parameters(), lr=cfg.lr, weight_decay=1e-4)
    # float(): a numpy scalar in the scheduler state would make the checkpoint unloadable with weights_only
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: float(0.1 + 0.45 * (1 + np.cos(np.pi * s / cfg.steps))))
    parts = {"unet": unet, "ema": ema, "opt": opt, "sched": sched}
    state = resume(run / "ckpt.pt", parts)
    step, losses, elapsed = state["step"], state["losses"], state["elapsed"]
    noise_sched = ddpm_scheduler(ucfg)
    tensors = [torch.from_numpy(a).to(cfg.device) for a in arrays]
    t0 = time.monotonic() - elapsed
    bar = tqdm(range(step, cfg.steps), initial=step, total=cfg.steps, desc=desc)
    for step in bar:
        loss = train_step(unet, opt, noise_sched, *tensors[:2], cfg, step, *tensors[2:])
        sched.step()
        _ema_update(ema, unet, cfg.ema_decay)
        losses.append(loss)
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
        done = step + 1 == cfg.steps or (cfg.max_minutes and time.monotonic() - t0 > 60 * cfg.max_minutes)
        if (step + 1) % cfg.ckpt_every == 0 or done:
            checkpoint(run, parts, step + 1, losses, time.monotonic() - t0)
            plot_losses(losses, run / "loss.png", title)
        if done:
            break
    return ema.cpu(), losses, (time.monotonic() - t0) / 60


def train_step(unet: torch.nn.Module, opt: torch.optim.Optimizer, noise_sched, x0_all: torch.Tensor,
               c_all: torch.Tensor, cfg: LoopSettings, step: int, weight_all: torch.Tensor | None = None
               ) -> float:
    """One eq.-8 step: eps ~ N(0, I), k ~ U{0..K-1}, minimise ||target - net(d_k ⊕ c, k)||^2 with target eps
    or, for a v-prediction model, v = sqrt(abar_k) eps - sqrt(1 - abar_k) d_0. Arrays are [N, H, W] (one
    channel) or [N, C, H, W]; ``weight_all`` [N, 1, H, W] weighs each pixel's squared error
    (``weighted_mse``)."""
    g = torch.Generator().manual_seed(cfg.seed * 1_000_003 + step)
    idx = torch.randint(0, len(x0_all), (cfg.batch,), generator=g)
    picked = [a[idx, None] if a.ndim == 3 else a[idx] for a in (x0_all, c_all, weight_all) if a is not None]
    x0, c, *weight = _patches(picked, cfg.patch, g)
    flip = torch.rand(cfg.batch, generator=g) < 0.5  # horizontal flip, the one mirror a camera allows
    x0, c, *weight = (torch.where(flip[:, None, None, None], a.flip(-1), a) for a in (x0, c, *weight))
    eps = torch.randn(x0.shape, generator=g).to(x0.device)
    k = torch.randint(0, noise_sched.config.num_train_timesteps, (cfg.batch,), generator=g).to(x0.device)
    xk = noise_sched.add_noise(x0, eps, k)
    loss = weighted_mse(unet(torch.cat([xk, c], 1), k).sample, training_target(noise_sched, x0, eps, k),
                        weight[0] if weight else None)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(unet.parameters(), 1.0)
    opt.step()
    return loss.item()


def weighted_mse(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None
                 ) -> torch.Tensor:
    """Mean squared error, each pixel's (every channel's) error times its ``weight`` when given: the mean
    over all pixels of w * e^2, i.e. eq. 6's omega L_sim + lambda L_dis with both sums over the batch's
    pixels."""
    if weight is None:
        return torch.nn.functional.mse_loss(pred, target)
    return (weight * (pred - target) ** 2).mean()


def _patches(tensors: list[torch.Tensor], patch: tuple[int, ...], g: torch.Generator) -> list[torch.Tensor]:
    """One random window (the same for the whole batch and every tensor, so each stays one tensor) of size
    ``patch``."""
    h, w = tensors[0].shape[-2:]
    ph, pw = (patch[0] or h, patch[1] or w) if patch else (h, w)
    top = int(torch.randint(0, h - ph + 1, (1,), generator=g))
    left = int(torch.randint(0, w - pw + 1, (1,), generator=g))
    return [t[..., top:top + ph, left:left + pw] for t in tensors]


def plot_losses(losses: list[float], path: Path, title: str = "DDG training loss") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(losses, alpha=0.3, lw=0.5, label="step")
    w = max(1, len(losses) // 50)
    ax.plot(np.convolve(losses, np.ones(w) / w, mode="valid"), label=f"mean of {w}")
    ax.set(xlabel="step", ylabel="eps MSE (eq. 8)", yscale="log", title=title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _bank(cfg: FitConfig, run: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    if cfg.bank and cfg.leave_out:
        raise ValueError("--leave-out picks frames of --real; a prebuilt --bank holds its crops already")
    if cfg.bank:
        bank = concat_banks([load_bank(Path(b)) for b in cfg.bank])
    else:
        far = "" if cfg.far_m == POLICY_SPEC.far_m else f"_far{cfg.far_m:g}"
        prior = "" if cfg.prior == "fused" else f"_{cfg.prior}"
        without = f"_without_{cfg.leave_out}" if cfg.leave_out else ""
        cached = run / f"bank_{cfg.sensors}_{cfg.crops}_{cfg.seed}{far}{prior}{without}.npz"
        if cached.exists():
            bank = load_bank(cached)
        else:
            train, _ = split(load_real_dir(cfg.real, cfg.sensors), leave_out=cfg.leave_out)
            bank = build_bank(train, BankConfig(crops=cfg.crops, seed=cfg.seed, far_m=cfg.far_m,
                                                prior=cfg.prior))
            save_bank(bank, cached)
    if bank_spec(bank).far_m != cfg.far_m:
        raise ValueError(f"--far-m {cfg.far_m} but the crop bank was made with far_m {bank_spec(bank).far_m}")
    if bank_prior(bank) != cfg.prior:
        raise ValueError(f"--prior {cfg.prior} but the crop bank was made with prior {bank_prior(bank)}")
    return bank, [str(n) for n in bank["names"]]


def _ema_update(ema: torch.nn.Module, model: torch.nn.Module, decay: float) -> None:
    with torch.no_grad():
        torch._foreach_lerp_(list(ema.parameters()), list(model.parameters()), 1.0 - decay)


def checkpoint(run: Path, parts: dict, step: int, losses: list[float], elapsed: float) -> None:
    """``run``/ckpt.pt: the state of each of ``parts`` (name -> anything with a ``state_dict``), the step, the
    losses and the wall time so far."""
    tmp = run / "ckpt.pt.tmp"
    torch.save({**{name: part.state_dict() for name, part in parts.items()}, "step": step, "losses": losses,
                "elapsed": elapsed}, tmp)
    os.replace(tmp, run / "ckpt.pt")  # atomic: a kill mid-save never leaves a broken checkpoint


def resume(path: Path, parts: dict) -> dict:
    """Load ``parts`` from the checkpoint at ``path`` if there is one; returns it (step 0 without)."""
    if not path.exists():
        return {"step": 0, "losses": [], "elapsed": 0.0}
    ck = torch.load(path, map_location="cpu", weights_only=True)
    for name, part in parts.items():
        part.load_state_dict(ck[name])
    return ck
