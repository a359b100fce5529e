"""Fitting the residual diffusion's two stages (Stable-Sim2Real §3.2 and §3.4) with the DDG's DDPM loop
(``train.train``: EMA, checkpoints, resume), on paired frames (``pairs.py``).

Stage I: x0 = each training pair's target (``residual.encode``), c = its simulated frame.
Stage II: the same target, conditioned on c and on stage I's output on the frame (sampled once and cached,
``residual.stage1_outputs``), with eq. 6's re-weighted loss: each pixel's squared error counts lambda where
the model's discriminator caught stage I's patch (a "distinct" area) and omega where it did not (a "similar"
one), lambda > omega (the paper's best 0.5 / 1.5). ``train.weighted_mse`` takes the mean of w * e^2 over all
pixels, so omega L_sim + lambda L_dis with both sums over the batch's pixels.

Memory: the training arrays are float32, ~150 kB a 96x128 frame for stage I and ~300 kB for stage II; --stride
reads every s-th step of an episode.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from runtime.preprocess import DepthSpec

from .discriminator import caught, load_discriminator
from .model import RESIDUAL_SCALE, UNetConfig, build_unet, load_config, save_model
from .pairs import Pairs, load_pairs
from .point_patches import untile
from .residual import STAGES, ResidualCode, encode, stage1_outputs, stage_condition, stage_dirs, stage_io
from .train import plot_losses, train


@dataclass(frozen=True)
class StageConfig:
    store: tuple[str, ...] = ()
    """Demo store(s) of paired frames: data/depth (clean) and data/depth_sensor (trainer/ddg/pairs.py)."""
    stage: int = 1
    """Which stage to fit: 1 (the residual from the simulated frame) or 2 (stage I's output refined, which
    needs the model's stage1/ and discriminator/)."""
    out: str = "runs/residual/model"
    """Residual model directory; the stage is written to its stage1/ or stage2/ (config.json,
    unet.safetensors, unet.onnx, loss.png)."""
    run: str = "runs/residual/fit"
    """Run directory: the stage's checkpoint (resumed from when present) under stage1/ or stage2/."""
    residual_m: float = 0.5
    """The residual's range (m): (sensor - sim) is clipped to +- this and scaled to [-1, 1]. 0.5 m covers the
    stereo sensor's errors to their 99th percentile (429 mm, docs/ddg.md); a smaller range spreads the small
    errors over more of [-1, 1]. Stage II takes stage I's."""
    residual_mu: float = 0.0
    """mu-law companding of the residual (``residual.ResidualCode``; 0 = linear, the shipped model's): 255
    spreads the sensor's few-mm errors over [-1, 1], less noise on flat regions but less of the sensor's error
    at edges. Stage II takes stage I's."""
    far_m: float = 6.0
    """Far end (m) of the range the condition c sees (the D455 measures to ~6 m, and a stereo sensor's error
    grows with range: at the policy's 1.5 m the far floor is one flat value). Stage II takes stage I's."""
    omega: float = 0.5
    """Stage II: weight of the pixels of patches the discriminator did not catch (eq. 6's omega)."""
    lam: float = 1.5
    """Stage II: weight of the pixels of patches the discriminator caught (eq. 6's lambda)."""
    ddim_steps: int = 10
    """Stage II: DDIM steps of stage I's samples on the training frames."""
    holdout_every: int = 10
    """Every k-th episode of each store is held out (not trained on; the discriminator's report reads it)."""
    stride: int = 1
    """Every s-th step of an episode is read (neighbouring steps are nearly the same view)."""
    steps: int = 6000
    """Optimiser steps."""
    batch: int = 16
    """Frames per step."""
    lr: float = 3e-4
    """AdamW learning rate (cosine decay to 10%)."""
    ema_decay: float = 0.999
    """EMA of the weights; the EMA copy is the model."""
    ckpt_every: int = 250
    """Steps between checkpoints."""
    max_minutes: float = 0.0
    """Stop (and save) after this much wall time; 0 = no limit."""
    seed: int = 0
    """Seed of the batches and noise (and of stage I's samples for stage II)."""
    device: str = "cpu"
    """torch device."""
    threads: int = 2
    """CPU threads."""
    patch: tuple[int, ...] = (48, 64)
    """Train on random windows of this size (rows cols; 0 0 = whole frames): the U-Net is fully
    convolutional, and generation runs on whole frames."""
    channels: tuple[int, ...] = UNetConfig.channels
    """U-Net widths per level."""
    prediction: str = UNetConfig.prediction
    """What the U-Net predicts: v_prediction or epsilon (trainer/ddg/model.py)."""


def fit_stage(cfg: StageConfig) -> Path:
    """Fit stage ``cfg.stage`` and write it to the model directory; returns the stage's directory."""
    torch.set_num_threads(cfg.threads)
    _check(cfg)
    pairs = load_pairs(cfg.store, "train", cfg.holdout_every, cfg.stride)
    spec = _spec(cfg, pairs)
    name = STAGES[cfg.stage - 1]
    code = ResidualCode(cfg.residual_m, cfg.residual_mu)
    x0 = encode(pairs.sim, pairs.real, code)
    if cfg.stage == 1:
        arrays, record = (x0, stage_condition(pairs.sim, spec, code)), {}
    else:
        arrays, record = _stage2_arrays(cfg, pairs, x0, spec, code)
    ucfg, io = UNetConfig(channels=cfg.channels, prediction=cfg.prediction), stage_io(cfg.stage)
    run, title = Path(cfg.run) / name, f"residual stage {cfg.stage} training loss"
    run.mkdir(parents=True, exist_ok=True)
    ema, losses, minutes = train(build_unet(ucfg, spec, io), ucfg, arrays, cfg, run, f"residual {name}",
                                 title)
    out = Path(cfg.out) / name
    extra = {"x0_scale": RESIDUAL_SCALE, "io": list(io), "residual_m": cfg.residual_m,
             "residual_mu": cfg.residual_mu, "stage": cfg.stage,
             "train": {**asdict(cfg), "steps_done": len(losses), "train_minutes": round(minutes, 2),
                       "frames": len(pairs)}, **record}
    save_model(out, ema, ucfg, spec, extra)
    plot_losses(losses, out / "loss.png", title)
    return out


def loss_weights(hit: np.ndarray, shape: tuple[int, int], p: int, omega: float, lam: float) -> np.ndarray:
    """Caught patches bool [N, P] of p x p pixels -> per-pixel loss weights float32 [N, 1, H, W]: ``lam`` on
    each caught patch's pixels, ``omega`` on the rest."""
    return np.where(untile(hit, shape, p), np.float32(lam), np.float32(omega))[:, None]


def _check(cfg: StageConfig) -> None:
    if cfg.stage not in (1, 2):
        raise ValueError(f"--stage must be 1 or 2, got {cfg.stage}")
    if cfg.residual_m <= 0 or cfg.residual_mu < 0:
        raise ValueError(f"--residual-m must be positive and --residual-mu >= 0, got {cfg.residual_m} and "
                         f"{cfg.residual_mu}")
    if min(cfg.omega, cfg.lam) < 0 or not cfg.omega + cfg.lam > 0:
        raise ValueError(f"--omega and --lam must be >= 0 and not both 0, got {cfg.omega} and {cfg.lam}")


def _spec(cfg: StageConfig, pairs: Pairs) -> DepthSpec:
    """The model's DepthSpec: the frames' view over near_m..far_m; stage II's must be stage I's."""
    spec = replace(pairs.spec, far_m=cfg.far_m)
    if cfg.stage == 1:
        return spec
    first = load_config(stage_dirs(cfg.out, 1)[0], RESIDUAL_SCALE)
    code = (first["residual_m"], first.get("residual_mu", 0.0))
    if (first["depth_spec"], code) != (spec, (cfg.residual_m, cfg.residual_mu)):
        raise ValueError(f"stage II must see stage I's frames and encoding: stage I read "
                         f"{first['depth_spec']} with residual_m, mu {code}; these are {spec} "
                         f"with {(cfg.residual_m, cfg.residual_mu)}")
    return spec


def _stage2_arrays(cfg: StageConfig, pairs: Pairs, x0: np.ndarray, spec: DepthSpec, code: ResidualCode
                   ) -> tuple[tuple[np.ndarray, ...], dict]:
    """(x0, c ⊕ stage I's output, the eq.-6 weights) and what to record of them."""
    disc, p = load_discriminator(cfg.out)
    first = stage1_outputs(cfg.out, pairs.sim, cfg.ddim_steps, cfg.seed, cfg.threads)
    hit = caught(disc, pairs.sim, first, pairs.K, p)
    weights = loss_weights(hit, pairs.sim.shape[1:], p, cfg.omega, cfg.lam)
    record = {"discriminator_patch": p, "caught_share": round(float(hit.mean()), 4)}
    return (x0, stage_condition(pairs.sim, spec, code, first), weights), record
