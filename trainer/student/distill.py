"""One fit of a recipe student (``StudentConfig.perception``) on labelled steps, resumable, on the GPU when
there is one.

Loss: the action head's denoising loss on the expert's chunk labels (paper eq. 10), plus for a depth student
the perception losses: the readout against the frame's facts (standardised units) and the two supervised
keypoints against the object's and the hand's pixels where they are in view. The head reads the readout
detached: it learns to act on perception as it is, while only the labels teach perception.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from hil_sim.objects import select_kinds
from trainer.diffusion import training_target
from trainer.sim.labels import HAND_PX, OBJECT_PX, OFFSET, READOUT
from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint, TrainingInfo
from trainer.student.config import StudentConfig
from trainer.student.ddim import training_scheduler
from trainer.student.model import PerceptionStudent
from trainer.student.perception import SUPERVISED_KEYPOINTS
from trainer.student.steps import LabelledSteps, StepBatch
from trainer.student.train import CKPT_NAME, ema_update, lr_factor, plot_losses

PRECISIONS = ("fp32", "bf16")


@dataclass(frozen=True)
class DistillConfig:
    steps: int = 4000
    """Optimiser steps of this fit (a resumed fit continues up to this)."""
    batch: int = 128
    lr: float = 3e-4
    """AdamW learning rate, linear warm-up then cosine decay to 0 (the fit ends settled, not noisy)."""
    warmup: int = 200
    weight_decay: float = 1e-6
    facts_loss: float = 1.0
    """Weight of the readout's loss (standardised facts: offset, grasp direction, size)."""
    near_loss: float = 0.0
    """Weight of the readout's horizontal offset error relative to the true offset's length plus
    ``NEAR_SCALE_M`` (squared): an error of 1 cm at the object costs 1, at 20 cm away 1/441. In standardised
    units a centimetre weighs the same everywhere, and the readout learned to say "nearly there" when 1-2 cm
    off (it reports 29 % of such an offset on its own held-out frames, ``readout``'s ``off_target``:
    ``docs/history.md``, 2026-11-27), which closes the fingers beside the object; the world forgives errors
    far from it. Weight 1: 74.2 % of 360 seen-kind episodes against 68.6 % without (no interval cleared)."""
    keypoint_loss: float = 10.0
    """Weight of the supervised keypoints' squared error in [-1, 1] image units (a pixel is ~0.02)."""
    teacher_loss: float = 0.0
    """Weight of the feature teacher's term (``FeatureTeacher``, ``trainer student refit --teacher``): the
    mean squared gap, in the teacher's standard deviations, between the readout's features of the fitted
    frames and the teacher's of the clean frames of the same steps."""
    max_grad_norm: float = 1.0
    """Gradients are scaled down to this total norm before each step, so that one bad batch cannot throw the
    weights far (an unclipped depth fit at lr 3e-4 spiked at step 3330: readout loss 0.004 -> 0.9, keypoints
    0.0005 -> 0.2, still 100x above its old level 400 steps later)."""
    shift_px: int = 0
    """Each training stack is shifted by up to this many pixels in x and y (drawn per sample, the edge
    repeated) and its keypoint labels with it; the offset label, object minus hand, holds under the shift.
    Against a readout that places things by where they sit in the image: the 400-demo fit read its training
    episodes' offsets to 0.15 cm and held-out ones to 1.0 cm (``docs/history.md``, 2026-11-27)."""
    shares: tuple[str, ...] = ()
    """``GROUP=SHARE`` items: each batch draws that share of its steps from the named group's (a group of
    ``hil_sim.objects`` or one kind; a step belongs to the first named group that holds its kind), and what is
    left from the other steps; () draws every step alike. On ``--objects train`` (the 6 seen kinds and 24
    shapes) the seen kinds hold ~20 % of the steps, a fifth of what a recipe on the seen kinds alone gives
    them: the lost ``s2k`` rounds 0-5, on the seen kinds alone, read them to 0.64 cm near the object at round
    4, ``s_dev`` on ``train`` 1.18 cm. A round refitted with ``seen=0.5`` on the same data grasped 66.7
    against 61.1 % seen (18 episodes won, 8 lost: not cleared), its readout no better (``docs/history.md``,
    2026-11-29). A round on the seen kinds scaled (``scaled``) fitted with ``seen=0.4 scaled=0.25
    squares=0.15`` was level with the file before it (2026-11-30)."""
    perception_only: bool = False
    """Fit the perception alone: no denoising term, so the head keeps its weights and the stores need no
    expert chunks (``RoundSpec.horizon`` 0 rounds, ~4x faster to collect). Enough wherever only the readout
    is kept: ``trainer student compose`` takes the perception from a depth student and the head from M0."""
    precision: str = "fp32"
    """The arithmetic of the fit's forward pass: fp32, or bf16 (``torch.autocast``: the weights, the optimiser
    and the losses stay fp32). On 2 CPU cores a recipe round's fit took 1.17 s a step in bf16 against 1.50 in
    fp32 (the network alone 1.77x, ``research/fit_precision.py``; the batch's gathers are not sped up) and
    grasped as well (``recipe.RESUMABLE``)."""
    ema_max: float = 0.999
    ckpt_every: int = 500
    seed: int = 0

    def __post_init__(self) -> None:
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        for name in ("shift_px", "near_loss", "teacher_loss"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("steps", "batch", "ckpt_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        parse_shares(self.shares)
        if not self.max_grad_norm > 0:
            raise ValueError(f"max_grad_norm must be > 0, got {self.max_grad_norm}")


def device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def cpu_flags() -> set[str]:
    """The CPU's feature flags as Linux reports them (empty where /proc/cpuinfo cannot be read)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    return {flag for line in text.splitlines() if line.startswith("flags") for flag in line.split()[2:]}


def warn_slow_bf16(cfg: DistillConfig, dev: torch.device) -> None:
    """One line on stderr where bf16 is asked of a CPU without bf16 arithmetic: torch emulates it there, and a
    recipe round's fit step took 25.9 s against 1.95 s in fp32 (2 cores of an AVX2-only AMD EPYC,
    2026-12-01), where a CPU with it took 1.17 s against 1.50."""
    if cfg.precision != "bf16" or dev.type != "cpu":
        return
    flags = cpu_flags()  # read only where bf16 on a CPU is asked
    if flags and not flags & {"avx512_bf16", "amx_bf16"}:
        print("warning: --precision bf16 on a CPU without bf16 arithmetic (no avx512_bf16 or amx_bf16) is "
              "about 13x slower than fp32 here; the setting is resumable: repeat with --precision fp32",
              file=sys.stderr)


class FeatureTeacher:
    """A depth student that reads the clean frames, whose readout features (``Perception``'s) the fitted
    readout's features of another source's frames of the same steps are pulled toward: cross-modal
    distillation. The features carry the whole scene as the teacher reads it, not just the 12 facts a label
    gives, so a readout of a sensor's depth gets a dense target per frame on the paired frames a round
    stores."""

    SCALE_STEPS = 512
    """Steps (drawn with a fixed seed) over which each feature's standard deviation, its unit, is taken."""

    def __init__(self, net: PerceptionStudent, steps: LabelledSteps) -> None:
        self.net = net.eval().requires_grad_(False)
        index = torch.randint(0, len(steps), (self.SCALE_STEPS,), generator=torch.Generator().manual_seed(0))
        self.scale = self.features(steps.batch(index)).std(dim=0).clamp_min(1e-3)

    def features(self, batch: StepBatch) -> torch.Tensor:
        with torch.no_grad():
            return self.net.perceive(batch.teacher_depth, batch.state)[0].float()

    def loss(self, features: torch.Tensor, batch: StepBatch) -> torch.Tensor:
        return (((features - self.features(batch)) / self.scale) ** 2).mean()


def losses(net: PerceptionStudent, scheduler, batch: StepBatch, gen: torch.Generator, cfg: DistillConfig,
           teacher: FeatureTeacher | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """The total loss of ``batch`` and its terms, the network run in ``cfg.precision``, the losses in fp32."""
    with torch.autocast(gen.device.type, dtype=torch.bfloat16, enabled=cfg.precision == "bf16"):
        return _losses(net, scheduler, batch, gen, cfg, teacher)


def _losses(net: PerceptionStudent, scheduler, batch: StepBatch, gen: torch.Generator,
            cfg: DistillConfig, teacher: FeatureTeacher | None) -> tuple[torch.Tensor, dict[str, float]]:
    terms = {}
    if not cfg.perception_only:  # drawn first, as by every fit before the option: the same draws
        clean = net.action_norm.normalise(batch.chunk)
        noise = torch.randn(clean.shape, generator=gen, device=gen.device)
        k = torch.randint(0, scheduler.config.num_train_timesteps, (clean.shape[0],), generator=gen,
                          device=gen.device)
        noisy = scheduler.add_noise(clean, noise, k)
    if net.perception is None:
        obs = net.encode(batch.labels, batch.state)
    else:
        batch = shifted(batch, cfg.shift_px, gen)
        features, facts, keypoints = net.perceive(batch.depth, batch.state)
        facts, keypoints = facts.float(), keypoints.float()
        obs = None if cfg.perception_only else net.fuse(features, facts.detach(), batch.state)
        truth = net.label_norm.normalise(batch.labels[:, :READOUT])
        terms["facts"] = nn.functional.mse_loss(facts, truth)
        if cfg.near_loss:
            terms["near"] = near_error(net.label_norm.unnormalise(facts), batch.labels)
        pixels = torch.stack([batch.labels[:, OBJECT_PX], batch.labels[:, HAND_PX]], dim=1)  # [B, 2, 2]
        seen = (pixels.abs() <= 1).all(dim=-1)
        error = ((keypoints[:, :SUPERVISED_KEYPOINTS] - pixels) ** 2).sum(dim=-1)
        terms["keypoints"] = (error * seen).sum() / seen.sum().clamp_min(1)
        if teacher is not None:
            terms["teacher"] = teacher.loss(features.float(), batch)
    if not cfg.perception_only:
        terms["denoise"] = nn.functional.mse_loss(net(noisy, k, obs).float(),
                                                  training_target(scheduler, clean, noise, k))
    total = (terms.get("denoise", 0.0) + cfg.facts_loss * terms.get("facts", 0.0)
             + cfg.near_loss * terms.get("near", 0.0) + cfg.keypoint_loss * terms.get("keypoints", 0.0)
             + cfg.teacher_loss * terms.get("teacher", 0.0))
    return total, {name: float(value.detach()) for name, value in terms.items()}


NEAR_SCALE_M = 0.01
"""``near_error``'s length scale: errors count relative to the true offset once it is beyond about this."""


def near_error(facts: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Squared horizontal offset error (facts in metres) over (true offset + NEAR_SCALE_M)^2, batch mean."""
    true = labels[:, OFFSET][:, :2]
    error = ((facts[:, OFFSET][:, :2] - true) ** 2).sum(dim=-1)
    return (error / (true.norm(dim=-1) + NEAR_SCALE_M) ** 2).mean()


def shifted(batch: StepBatch, max_px: int, gen: torch.Generator) -> StepBatch:
    """``batch`` with each depth stack moved by a random whole-pixel shift in [-max_px, max_px] (x and y, the
    edge repeated) and its object and hand pixel labels (and its teacher's stack) moved alike."""
    if max_px == 0:
        return batch
    b, _, h, w = batch.depth.shape
    pixels = torch.randint(-max_px, max_px + 1, (b, 2), generator=gen, device=gen.device)
    step = pixels.float() * torch.tensor([2 / (w - 1), 2 / (h - 1)], device=pixels.device)  # label units
    theta = torch.zeros(b, 2, 3, device=pixels.device)
    theta[:, 0, 0] = theta[:, 1, 1] = 1.0
    theta[:, :, 2] = -step  # output pixel p reads input p - shift: the content moves by +shift
    grid = nn.functional.affine_grid(theta, list(batch.depth.shape), align_corners=True)
    depth, teacher = (None if d is None else nn.functional.grid_sample(d, grid, mode="nearest",
                                                                       padding_mode="border",
                                                                       align_corners=True)
                      for d in (batch.depth, batch.teacher_depth))
    labels = batch.labels.clone()
    for columns in (OBJECT_PX, HAND_PX):
        labels[:, columns] += step
    return StepBatch(depth, batch.state, labels, batch.chunk, teacher)


def training_layout(net: PerceptionStudent) -> PerceptionStudent:
    """``net`` with its convolution weights channels-last when it sits on the CPU, so that its feature maps
    follow: oneDNN's kernels for that layout (the max-pool above all) are faster there. A width-32 fit step on
    2 cores, bf16: 1.63 against 2.18 s (fp32 3.79 against 4.23; width 16, bf16: 0.88 against 1.03; medians of
    ``research/fit_precision.py --layouts``). The values, and so the checkpoints, agree to float rounding."""
    return net.to(memory_format=torch.channels_last) if next(net.parameters()).device.type == "cpu" else net


def start(out: Path, model_cfg: StudentConfig, info: TrainingInfo, steps: LabelledSteps,
          init: Path | None) -> Checkpoint:
    """The fit's checkpoint: resumed from ``out``, else ``init``'s EMA weights (a DAgger round refits from
    the last round's student, normalisers kept), else fresh with normalisers fitted to ``steps``."""
    path = out / CKPT_NAME
    if path.is_file():
        ckpt = checkpoint.load(path)
        if ckpt.config != model_cfg:
            raise ValueError(f"{path} is a {ckpt.config}, not the requested {model_cfg}; use another folder")
        return ckpt
    if init is not None:
        source = checkpoint.load(init)
        return Checkpoint(model_cfg, info, ema={k: v.clone() for k, v in source.ema.items()},
                          model={k: v.clone() for k, v in source.ema.items()})
    if steps.chunk_np is None:
        raise ValueError("a student fitted from scratch needs the expert's chunks: a perception-only fit "
                         "starts from a trained student (--init)")
    ckpt = checkpoint.fresh(model_cfg, info)
    net = PerceptionStudent(model_cfg)
    net.load_state_dict(ckpt.model)
    net.fit_normalisers(steps.state_np, steps.chunk_np, steps.labels_np)
    ckpt.model = net.state_dict()
    ckpt.ema = {k: v.clone() for k, v in ckpt.model.items()}
    return ckpt


def distill(steps: LabelledSteps, out: Path, model_cfg: StudentConfig, cfg: DistillConfig,
            info: TrainingInfo, init: Path | None = None, teacher: FeatureTeacher | None = None) -> dict:
    """Fit to ``cfg.steps`` into ``out``/ckpt.pt (with loss.png); returns a summary."""
    if (teacher is None) != (cfg.teacher_loss == 0):
        raise ValueError("a feature teacher and --teacher-loss > 0 go together")
    if cfg.perception_only and model_cfg.perception != "depth":
        raise ValueError(f"a perception-only fit needs a depth student, not perception="
                         f"{model_cfg.perception!r}")
    out.mkdir(parents=True, exist_ok=True)
    ckpt = start(out, model_cfg, info, steps, init)
    # the loss term a fit's curve and summary follow, and what it is
    tracked, what = (("facts", "readout MSE (standardised facts)") if cfg.perception_only
                     else ("denoise", "noise MSE (eq. 10)"))
    dev = steps.device
    warn_slow_bf16(cfg, dev)
    net = training_layout(PerceptionStudent(model_cfg).to(dev))
    net.load_state_dict(ckpt.model)
    ema = {k: v.to(dev) for k, v in ckpt.ema.items()}
    optim = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    if ckpt.optimizer is not None:
        optim.load_state_dict(ckpt.optimizer)
    scheduler = training_scheduler(model_cfg.train_timesteps, model_cfg.prediction)
    scheduler.alphas_cumprod = scheduler.alphas_cumprod.to(dev)
    seed = cfg.seed * 1_000_003 + ckpt.step
    gen = torch.Generator(device=dev).manual_seed(seed)
    sampler = torch.Generator().manual_seed(seed)
    weights = batch_weights(steps.kinds, cfg.shares)
    began, first, terms = time.perf_counter(), ckpt.step, {}
    bar = tqdm(range(ckpt.step, cfg.steps), initial=ckpt.step, total=cfg.steps, desc=f"fit {out.name}")
    for step in bar:
        for group in optim.param_groups:
            group["lr"] = cfg.lr * lr_factor(step, cfg)
        index = (torch.randint(0, len(steps), (cfg.batch,), generator=sampler) if weights is None
                 else torch.multinomial(weights, cfg.batch, replacement=True, generator=sampler))
        batch = steps.batch(index)
        loss, terms = losses(net, scheduler, batch, gen, cfg, teacher)
        terms["grad_norm"] = optimise(net, optim, loss, cfg.max_grad_norm)
        ema_update(ema, net, step, cfg.ema_max)
        ckpt.losses.append(terms[tracked])
        ckpt.step = step + 1
        bar.set_postfix({k: f"{v:.4f}" for k, v in terms.items()})
        if ckpt.step % cfg.ckpt_every == 0 or ckpt.step == cfg.steps:
            save(out, ckpt, net, ema, optim, what)
    return {"steps": ckpt.step, "steps_this_run": ckpt.step - first, "device": str(dev),
            "precision": cfg.precision, "seconds": round(time.perf_counter() - began, 1), "last_terms": terms,
            f"{tracked}_last_100": float(np.mean(ckpt.losses[-100:])) if ckpt.losses else None}


def parse_shares(shares: tuple[str, ...]) -> dict[str, float]:
    """``("seen=0.4", "scaled=0.25")`` -> ``{"seen": 0.4, "scaled": 0.25}``: each share in (0, 1), together
    at most 1."""
    parsed = {}
    for item in shares:
        name, sep, value = item.partition("=")
        try:
            share = float(value) if sep and name else None
        except ValueError:
            share = None
        if share is None or not 0 < share < 1 or name in parsed:
            raise ValueError(f"shares wants distinct GROUP=SHARE items with each share between 0 and 1 "
                             f"(exclusive), got {item!r}")
        parsed[name] = share
    if sum(parsed.values()) > 1 + 1e-9:
        raise ValueError(f"shares add up to {sum(parsed.values()):g}, more than the whole batch")
    return parsed


def batch_weights(kinds: np.ndarray, shares: tuple[str, ...]) -> torch.Tensor | None:
    """Each step's chance of being drawn, so that each named group's steps make up its share of a batch and
    the other steps what is left (when every step is in a named group, the shares weigh the groups against
    each other); None (draw every step alike) without shares."""
    parsed = parse_shares(shares)
    if not parsed:
        return None
    group = np.full(len(kinds), "", dtype=object)  # "": the steps of no named group
    for name in reversed(parsed):  # the first named group that holds a kind wins
        group[np.isin(kinds, select_kinds(name))] = name
    left = 1.0 - sum(parsed.values())
    weights = np.zeros(len(kinds))
    for name, share in [*parsed.items(), ("", left)]:
        members = group == name
        if name and not members.any():
            raise ValueError(f"shares name {name!r}, but no step's kind is in it (or in it alone: the first "
                             "named group that holds a kind takes its steps)")
        if members.any() and share <= 1e-9:
            raise ValueError(f"shares leave nothing for the {members.sum()} steps of other kinds")
        weights[members] = share / max(1, members.sum())
    return torch.from_numpy(weights)


def optimise(net: nn.Module, optim: torch.optim.Optimizer, loss: torch.Tensor, max_grad_norm: float) -> float:
    """One optimiser step on ``loss`` with the gradients clipped to ``max_grad_norm``; their norm before."""
    optim.zero_grad(set_to_none=True)
    loss.backward()
    norm = float(nn.utils.clip_grad_norm_(net.parameters(), max_grad_norm))
    optim.step()
    return norm


def save(out: Path, ckpt: Checkpoint, net: nn.Module, ema: dict[str, torch.Tensor],
         optim: torch.optim.Optimizer, what: str) -> None:
    """The checkpoint, and the plot of ``ckpt.losses`` (``what`` they are)."""
    ckpt.model = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    ckpt.ema = {k: v.detach().cpu() for k, v in ema.items()}
    ckpt.optimizer = optim.state_dict()
    checkpoint.save(out / CKPT_NAME, ckpt)
    plot_losses(ckpt.losses, out / "loss.png", what)
