"""``python -m trainer student fit``: train the student on paper eq. 10 with EMA, checkpoints and resume.

Runs data-parallel under ``torchrun --nproc_per_node N`` (gloo on CPU): each rank draws its own share of
the global batch; rank 0 keeps the EMA, writes checkpoints, the loss curve and the progress bar.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from trainer.argspec import add_dataclass_args, from_args
from trainer.dataset import DEPTH_SOURCES, DatasetError, sizes
from trainer.diffusion import training_target
from trainer.menu import command_line
from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint, TrainingInfo
from trainer.student.config import StudentConfig
from trainer.student.data import Batch, DemoDataset
from trainer.student.ddim import training_scheduler
from trainer.student.model import StudentPolicy

CKPT_NAME = "ckpt.pt"


class FitError(ValueError):
    """Training options that cannot work (bad batch, a resume that disagrees with the checkpoint)."""


@dataclass(frozen=True)
class FitConfig:
    demos: str
    """Demo store (zarr) written by `python -m trainer collect`."""
    out: str
    """Run folder: ckpt.pt (resumed if present), loss.png, summary.json."""
    depth_source: str = "gt"
    """Depth the student sees: gt | randnoise | ddg | ddg_nograft | sensor (what `collect --sensor` kept)."""
    episodes: int = 0
    """Train on the store's first this many episodes (0 = all): e.g. those whose DDG depth is generated
    while `trainer ddg generate` is still working through the rest."""
    steps: int = 20000
    """Optimiser steps in total (a resumed run continues up to this)."""
    batch: int = 64
    """Global batch size, split evenly across torchrun ranks."""
    lr: float = 1e-4
    """AdamW learning rate (diffusion_policy: 1e-4), linear warm-up then cosine decay."""
    warmup: int = 500
    """Warm-up steps of the learning rate."""
    weight_decay: float = 1e-6
    object_loss: float = 1.0
    """Weight of the auxiliary loss: predict the object's table position (privileged, sim-only) from the
    depth features, and with the model's ``--hand-target`` the hand's offset from it. Without it the
    students learned to ignore depth (docs/student.md); 0 = eq. 10 alone."""
    ema_max: float = 0.9999
    """Ceiling of the EMA decay; the decay ramps up as 1 - (1 + step)^-0.75 (diffusion_policy)."""
    ckpt_every: int = 500
    """Steps between checkpoints (also written at the end)."""
    init: str = ""
    """Start a new run from this checkpoint's EMA weights and normalisers instead of random ones (e.g. the
    GT-depth student, fine-tuned on DDG depth); the model options must be the checkpoint's. The step count,
    optimiser and LR schedule start afresh."""
    seed: int = 0
    threads: int = 0
    """torch intra-op threads per process (0 = torch's default)."""

    def __post_init__(self) -> None:
        if self.depth_source not in DEPTH_SOURCES:
            raise FitError(f"--depth-source {self.depth_source!r}: choose one of {sorted(DEPTH_SOURCES)}")
        if self.episodes < 0:
            raise FitError(f"--episodes must be >= 0 (0 = all), got {self.episodes}")
        for name in ("steps", "batch", "ckpt_every"):
            if getattr(self, name) < 1:
                raise FitError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")


class DenoisingLoss(nn.Module):
    """Paper eq. 10 plus ``object_weight`` x the auxiliary object-position loss, in one forward, so
    DistributedDataParallel sees the whole graph. Returns (total, eq. 10 term)."""

    def __init__(self, policy: StudentPolicy, object_weight: float = 0.0) -> None:
        super().__init__()
        self.policy = policy
        self.object_weight = object_weight
        self.scheduler = training_scheduler(policy.config.train_timesteps, policy.config.prediction)

    def forward(self, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        clean = self.policy.action_norm.normalise(batch.action)
        noise = torch.randn(clean.shape, generator=generator)
        steps = self.scheduler.config.num_train_timesteps
        k = torch.randint(0, steps, (clean.shape[0],), generator=generator)
        noisy = self.scheduler.add_noise(clean, noise, k)
        features = self.policy.encoder(batch.depth)
        obs = self.policy.fuse(features, batch.state)
        target = training_target(self.scheduler, clean, noise, k)
        denoising = nn.functional.mse_loss(self.policy(noisy, k, obs), target)
        if not self.object_weight:
            return denoising, denoising
        located = nn.functional.mse_loss(self.policy.object_head(features), batch.targets)
        return denoising + self.object_weight * located, denoising


def ema_update(ema: dict[str, torch.Tensor], model: nn.Module, step: int, ema_max: float) -> None:
    decay = min(ema_max, 1.0 - (1.0 + step) ** -0.75)
    state = model.state_dict()
    floats = [name for name, value in state.items() if value.dtype.is_floating_point]
    with torch.no_grad():
        ema_values = [ema[name] for name in floats]
        torch._foreach_mul_(ema_values, decay)
        torch._foreach_add_(ema_values, [state[name] for name in floats], alpha=1.0 - decay)


def lr_factor(step: int, cfg: FitConfig) -> float:
    if step < cfg.warmup:
        return (step + 1) / cfg.warmup
    progress = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return 0.5 * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def start_or_resume(cfg: FitConfig, model_cfg: StudentConfig, data: DemoDataset) -> Checkpoint:
    """The run folder's checkpoint if there is one (it must match the data and model), else a fresh one
    with normalisation statistics fitted to the demos."""
    path = Path(cfg.out) / CKPT_NAME
    fingerprint = data.fingerprint()
    if path.is_file():
        ckpt = checkpoint.load(path)
        if ckpt.config != model_cfg:
            raise FitError(f"{path} was trained with {ckpt.config}, not {model_cfg}; use another --out")
        for key in ("demos_sha256", "depth_source"):
            trained_on = ckpt.info.data.get(key)
            if trained_on != fingerprint[key]:
                raise FitError(f"{path} was trained on other data ({key} {trained_on!r}, "
                               f"not {fingerprint[key]!r}); use another --out")
        return ckpt
    info = TrainingInfo(depth_spec=data.spec, action_scale=data.action_scale,
                        control_rate_hz=data.control_rate_hz, trained=True,
                        data={**fingerprint, "command": command_line()})
    if cfg.init:
        return warm_start(Path(cfg.init), model_cfg, info, data)
    ckpt = checkpoint.fresh(model_cfg, info, seed=cfg.seed)
    net = StudentPolicy(model_cfg)
    net.load_state_dict(ckpt.model)
    fit_to_demos(net, data)
    ckpt.model = net.state_dict()
    ckpt.ema = {k: v.clone() for k, v in ckpt.model.items()}
    return ckpt


def warm_start(init: Path, model_cfg: StudentConfig, info: TrainingInfo, data: DemoDataset) -> Checkpoint:
    """A new run whose weights, EMA and normalisers are ``init``'s EMA weights (a student of the same
    configuration)."""
    source = checkpoint.load(init)
    if source.config != model_cfg:
        raise FitError(f"--init {init} is a {source.config}, not the requested {model_cfg}")
    if source.info.depth_spec != data.spec:
        raise FitError(f"--init {init} was trained on {sizes(source.info.depth_spec)}; {data.path} holds "
                       f"{sizes(data.spec)}")
    info = replace(info, data={**info.data, "init": str(init.resolve()),
                               "init_sha256": checkpoint.sha256(init)})
    return Checkpoint(model_cfg, info, ema={k: v.clone() for k, v in source.ema.items()},
                      model={k: v.clone() for k, v in source.ema.items()})


def fit_to_demos(net: StudentPolicy, data: DemoDataset) -> None:
    """The network's normalisation statistics from the training demos (object positions where recorded)."""
    net.fit_normalisers(data.state, data.action, data.raw_targets)


def plot_losses(losses: list[float], path: Path, what: str = "noise MSE (eq. 10)") -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.5))
    steps = np.arange(1, len(losses) + 1)
    ax.plot(steps, losses, lw=0.5, alpha=0.4, label="per step")
    window = max(1, len(losses) // 50)
    if len(losses) >= window:
        smooth = np.convolve(losses, np.ones(window) / window, mode="valid")
        ax.plot(steps[window - 1:], smooth, lw=1.5, label=f"mean of {window}")
    ax.set(xlabel="step", ylabel=what, yscale="log", title="student training loss")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fit(cfg: FitConfig, model_cfg: StudentConfig) -> dict:
    rank, world = setup_distributed()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    if cfg.batch % world:
        raise FitError(f"--batch {cfg.batch} must be divisible by the {world} torchrun processes")
    data = DemoDataset.stacked_as(cfg.demos, cfg.depth_source, model_cfg, hand_target=model_cfg.hand_target,
                                  episodes=cfg.episodes)
    if (model_cfg.object_offset or model_cfg.seen_offset) and not cfg.object_loss:
        raise FitError("--object-offset and --seen-offset read the object head's estimate: they need "
                       "--object-loss > 0")
    if cfg.object_loss and data.targets is None:
        raise FitError(f"{cfg.demos} does not record object_xy for every episode; train with --object-loss 0")
    ckpt = start_or_resume(cfg, model_cfg, data)
    net = StudentPolicy(model_cfg)
    net.load_state_dict(ckpt.model)
    loss_fn = DenoisingLoss(net.train(), cfg.object_loss)
    trainable = loss_fn
    if world > 1:  # without the object loss the object head gets no gradient
        trainable = DistributedDataParallel(loss_fn, find_unused_parameters=not cfg.object_loss)
    optim = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, foreach=True)
    if ckpt.optimizer is not None:
        optim.load_state_dict(ckpt.optimizer)
    # Each rank (and each resume) draws its own sample stream.
    seed = cfg.seed * 1_000_003 + ckpt.step * 7919 + rank
    rng, gen = np.random.default_rng(seed), torch.Generator().manual_seed(seed)
    start, started = ckpt.step, time.perf_counter()
    bar = tqdm(range(start, cfg.steps), initial=start, total=cfg.steps, disable=rank != 0, desc="student fit")
    for step in bar:
        for group in optim.param_groups:
            group["lr"] = cfg.lr * lr_factor(step, cfg)
        batch = data.batch(rng.integers(0, len(data), cfg.batch // world), rng)
        loss, denoising = trainable(batch, gen)
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        ckpt.losses.append(mean_over_ranks(denoising.detach(), world))
        if rank == 0:
            ema_update(ckpt.ema, net, step, cfg.ema_max)
        ckpt.step = step + 1
        bar.set_postfix(loss=f"{ckpt.losses[-1]:.4f}")
        if rank == 0 and (ckpt.step % cfg.ckpt_every == 0 or ckpt.step == cfg.steps):
            save_run(cfg, ckpt, net, optim)
    summary = {"steps": ckpt.step, "steps_this_run": ckpt.step - start, "world_size": world,
               "seconds": time.perf_counter() - started,
               "loss_last_100": float(np.mean(ckpt.losses[-100:])) if ckpt.losses else None,
               "peak_rss_mb_per_rank": gather_per_rank(peak_rss_mb(), world),
               "ranks_in_sync": len(set(gather_per_rank(weights_checksum(net), world))) == 1,
               "fit": asdict(cfg), "model": json.loads(model_cfg.to_json())}
    if rank == 0:
        save_run(cfg, ckpt, net, optim)
        (Path(cfg.out) / "summary.json").write_text(json.dumps(summary, indent=1))
    if world > 1:
        dist.barrier()  # leave together: rank 0 writes its files before it
    return summary


def save_run(cfg: FitConfig, ckpt: Checkpoint, net: nn.Module, optim: torch.optim.Optimizer) -> None:
    ckpt.model, ckpt.optimizer = net.state_dict(), optim.state_dict()
    checkpoint.save(Path(cfg.out) / CKPT_NAME, ckpt)
    plot_losses(ckpt.losses, Path(cfg.out) / "loss.png")


def setup_distributed() -> tuple[int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("gloo")
    return (dist.get_rank(), world) if world > 1 else (0, 1)


def mean_over_ranks(value: torch.Tensor, world: int) -> float:
    if world > 1:
        value = value.clone()
        dist.all_reduce(value)
        value /= world
    return float(value)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def weights_checksum(net: nn.Module) -> float:
    """Position-weighted sum of all weights: equal on every rank iff data parallelism kept them in step."""
    flat = torch.cat([p.detach().double().flatten() for p in net.parameters()])
    return float((flat * torch.arange(1, len(flat) + 1, dtype=torch.float64).sin()).sum())


def gather_per_rank(value: float, world: int) -> list[float]:
    if world == 1:
        return [value]
    every = [torch.zeros(1, dtype=torch.float64) for _ in range(world)]
    dist.all_gather(every, torch.tensor([value], dtype=torch.float64))
    return [float(x) for x in every]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student fit", description=__doc__.split("\n\n")[0])
    add_dataclass_args(p, FitConfig)
    model_args = p.add_argument_group("model (must equal the checkpoint's when resuming)")
    add_dataclass_args(model_args, StudentConfig)
    args = p.parse_args(argv)
    for name in ("demos", "out"):
        if getattr(args, name) is None:
            p.error(f"--{name} is required")
    cfg, model_cfg = from_args(FitConfig, args), from_args(StudentConfig, args)
    try:
        summary = fit(cfg, model_cfg)
    except (checkpoint.CheckpointError, DatasetError) as exc:  # a file that is missing or not what it says
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if int(os.environ.get("RANK", "0")) == 0:
        print(json.dumps(summary))
    if dist.is_initialized():
        leave_without_teardown()
    return 0


def leave_without_teardown() -> None:
    """End a torchrun rank without destroying its gloo process group. The destructor joins gloo's worker
    threads while holding the GIL, and a worker still holding a finished collective's tensor needs the GIL
    to free it: a deadlock, seen on overloaded cores in 2 of 36 two-rank runs and once in CI (gdb:
    ~ProcessGroupGloo in thread::join, a pt_gloo_runloop thread in TensorImpl::decref_pyobject). The ranks
    met at fit's final barrier, after every file was written, so nothing is left to tear down."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
