"""The 3D-aware patch discriminator of Stable-Sim2Real (§3.3, supplementary C-D): a PointNet binary classifier
that tells stage I's point patches (``point_patches.py``) from the sensor's, guided by the simulated patch of
the same view.

Network: a point patch [n, 4] through a shared MLP (three layers of ``width``, ReLU) and a max-pool, the
global feature; the simulated patch through one shared layer and a max-pool, the guidance (the supplementary's
single-layer MLP); both concatenated, then a head (``width``, then 1): the logit that the patch is generated.

Training: each step takes ``batch`` training frames and every patch of each, stage I's labelled 1 and the
sensor's 0; binary cross-entropy and Adam at 1e-3 (PointNet's own setting). A stage-I patch is *caught* when
the discriminator calls it generated (logit > 0): stage II's loss weighs those with lambda.

``python -m trainer ddg residual-disc`` fits one discriminator per (patch size, width) given and reports each
one's accuracy on the held-out episodes (the supplementary's Tables II-III) and, once the model has a stage
II, the share of stage II's held-out patches it still catches beside stage I's (the paper's 67.8 -> 32.5 %).
The first pair's discriminator is the model's (``discriminator/``), the one stage II's fit reads.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from .model import ModelDirError
from .pairs import PARTS, Pairs, load_pairs
from .point_patches import POINT_FEATURES, POINT_SCALE, patch_grid, point_patches, tile
from .residual import ResidualGenerator, stage1_outputs, stage_dirs
from .sample import generate_frames
from .train import checkpoint, resume

DISC_DIR = "discriminator"


class PatchDiscriminator(nn.Module):
    """(point patches [B, n, 4], simulated patches [B, n, 4]) -> logit [B] that the first are generated."""

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        self.points = nn.Sequential(nn.Linear(POINT_FEATURES, width), nn.ReLU(), nn.Linear(width, width),
                                    nn.ReLU(), nn.Linear(width, width))
        self.guide = nn.Linear(POINT_FEATURES, width)
        self.head = nn.Sequential(nn.ReLU(), nn.Linear(2 * width, width), nn.ReLU(), nn.Linear(width, 1))

    def forward(self, patches: torch.Tensor, sim: torch.Tensor) -> torch.Tensor:
        feature = torch.cat([self.points(patches).amax(dim=1), self.guide(sim).amax(dim=1)], dim=1)
        return self.head(feature)[:, 0]


@dataclass(frozen=True)
class DiscConfig:
    store: tuple[str, ...] = ()
    """Demo store(s) of paired frames: data/depth (clean) and data/depth_sensor (trainer/ddg/pairs.py)."""
    model: str = "runs/residual/model"
    """Residual model directory: stage I (and stage II, if made) are read from it, the first pair's
    discriminator is written to its discriminator/."""
    run: str = "runs/residual/disc"
    """Run directory: one checkpoint per (patch, width) pair, resumed from when present."""
    patch: tuple[int, ...] = (16,)
    """Patch sides in pixels to fit a discriminator for (each must divide the frames' height and width): 16
    splits a 96x128 frame into 6x8 patches of 256 points."""
    width: tuple[int, ...] = (64,)
    """PointNet layer widths to fit a discriminator for (the paper's best: 64)."""
    steps: int = 2000
    """Optimiser steps per discriminator."""
    batch: int = 8
    """Frames per step (every patch of each, stage I's and the sensor's)."""
    lr: float = 1e-3
    """Adam learning rate."""
    ddim_steps: int = 10
    """DDIM steps of the stages' samples."""
    holdout_every: int = 10
    """Every k-th episode of each store is held out: never trained on, the accuracy is measured on it."""
    stride: int = 1
    """Every s-th step of an episode is read (neighbouring steps are nearly the same view)."""
    ckpt_every: int = 250
    """Steps between checkpoints."""
    seed: int = 0
    """Seed of the stages' noise, the weights and the batches."""
    threads: int = 2
    """CPU threads."""
    json: str = ""
    """Also write the report here (JSON)."""


def fit_discriminators(cfg: DiscConfig) -> dict:
    """Fit one discriminator per (patch, width), report each one's held-out accuracy; returns the report."""
    torch.set_num_threads(cfg.threads)
    pairs = [(p, w) for p in cfg.patch for w in cfg.width]
    if not pairs:
        raise ValueError("give at least one --patch and one --width")
    train, held = (load_pairs(cfg.store, part, cfg.holdout_every, cfg.stride) for part in PARTS)
    for p in cfg.patch:
        patch_grid(train.sim.shape[1:], p)  # a size that does not tile the frames fails before any work
    generated, judged = _stage_outputs(cfg, train, held)
    rows = []
    for i, (p, w) in enumerate(pairs):
        disc = _fit(train, generated, p, w, cfg, Path(cfg.run) / f"p{p}_w{w}")
        rows.append(_judge(disc, held, judged, p, w))
        if i == 0:
            record = {"train": asdict(cfg), "heldout": rows[0]}
            save_discriminator(Path(cfg.model) / DISC_DIR, disc, p, w, record)
    report = {"frames": {"train": len(train), "heldout": len(held)}, "rows": rows}
    print(format_table(rows))
    if cfg.json:
        Path(cfg.json).parent.mkdir(parents=True, exist_ok=True)
        Path(cfg.json).write_text(json.dumps(report, indent=1))
    return report


def _stage_outputs(cfg: DiscConfig, train: Pairs, held: Pairs) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Stage I's output on the training frames, and each stage's (stage I's, and stage II's when the model
    has one) on the held-out frames."""
    generated = stage1_outputs(cfg.model, train.sim, cfg.ddim_steps, cfg.seed, cfg.threads)
    judged = {"stage1": stage1_outputs(cfg.model, held.sim, cfg.ddim_steps, cfg.seed, cfg.threads)}
    if len(stage_dirs(cfg.model)) > 1:
        gen = ResidualGenerator(cfg.model, steps=cfg.ddim_steps, seed=cfg.seed, threads=cfg.threads)
        judged["stage2"] = generate_frames(gen, held.sim, "stage II on the held-out frames")
    return generated, judged


def _judge(disc: PatchDiscriminator, held: Pairs, judged: dict[str, np.ndarray], p: int, width: int) -> dict:
    """Held-out shares of the patches where the simulator sees something: accuracy (stage I's patches and
    the sensor's, balanced), the sensor's patches called real, and each stage's patches caught."""
    seen = tile(held.sim > 0, p).any(axis=2)
    shares = {f"caught_{stage}": float(caught(disc, held.sim, out, held.K, p)[seen].mean())
              for stage, out in judged.items()}
    real = 1.0 - float(caught(disc, held.sim, held.real, held.K, p)[seen].mean())
    row = {"accuracy": (shares["caught_stage1"] + real) / 2, "real_correct": real, **shares}
    return {"patch": p, "width": width, **{k: round(v, 4) for k, v in row.items()}}


def _fit(train: Pairs, generated: np.ndarray, p: int, width: int, cfg: DiscConfig, run: Path
         ) -> PatchDiscriminator:
    """One discriminator, checkpointed in ``run`` and resumed from there; batches seeded by (seed, step)."""
    torch.manual_seed(cfg.seed)
    disc = PatchDiscriminator(width)
    opt = torch.optim.Adam(disc.parameters(), lr=cfg.lr)
    parts = {"disc": disc, "opt": opt}
    run.mkdir(parents=True, exist_ok=True)
    state = resume(run / "ckpt.pt", parts)
    losses, t0 = state["losses"], time.monotonic() - state["elapsed"]
    bar = tqdm(range(state["step"], cfg.steps), initial=state["step"], total=cfg.steps,
               desc=f"discriminator p{p} w{width}")
    for step in bar:
        idx = np.random.default_rng([cfg.seed, step]).integers(0, len(train), cfg.batch)
        losses.append(_step(disc, opt, train.sim[idx], train.real[idx], generated[idx], train.K[idx], p))
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
        if (step + 1) % cfg.ckpt_every == 0 or step + 1 == cfg.steps:
            checkpoint(run, parts, step + 1, losses, time.monotonic() - t0)
    return disc.eval()


def _step(disc: PatchDiscriminator, opt: torch.optim.Optimizer, sim: np.ndarray, real: np.ndarray,
          generated: np.ndarray, K: np.ndarray, p: int) -> float:
    """One binary cross-entropy step on the frames' patches where the simulator sees something (elsewhere
    both sides are "no data" alike): the sensor's (0) and stage I's (1)."""
    guide, centre = point_patches(sim, K, p)
    seen = guide[..., 3].any(axis=2)
    patches = np.concatenate([point_patches(d, K, p, centre)[0][seen] for d in (real, generated)])
    n = int(seen.sum())
    labels = torch.cat([torch.zeros(n), torch.ones(n)])
    logits = disc(torch.from_numpy(patches), torch.from_numpy(np.concatenate([guide[seen], guide[seen]])))
    loss = nn.functional.binary_cross_entropy_with_logits(logits, labels)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss.item()


@torch.no_grad()
def caught(disc: PatchDiscriminator, sim: np.ndarray, depth: np.ndarray, K: np.ndarray, p: int,
           batch: int = 16) -> np.ndarray:
    """bool [N, P]: whether the discriminator calls each p x p patch of ``depth`` (uint16 mm [N, H, W],
    guided by ``sim`` of the same views) generated; never where the simulator sees nothing (it is not
    trained there)."""
    out = []
    for i in range(0, len(sim), batch):
        guide, centre = point_patches(sim[i:i + batch], K[i:i + batch], p)
        patches, _ = point_patches(depth[i:i + batch], K[i:i + batch], p, centre)
        flat = [torch.from_numpy(a.reshape(-1, *a.shape[2:])) for a in (patches, guide)]
        out.append((disc(*flat) > 0).numpy().reshape(guide.shape[:2]) & guide[..., 3].any(axis=2))
    return np.concatenate(out)


def save_discriminator(out: Path, disc: PatchDiscriminator, p: int, width: int, extra: dict) -> None:
    from safetensors.torch import save_file

    out.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in disc.state_dict().items()}, out / "weights.safetensors")
    config = {"patch": p, "width": width, "point_scale": POINT_SCALE, **extra}
    (out / "config.json").write_text(json.dumps(config, indent=1))


def load_discriminator(model_dir: str | Path) -> tuple[PatchDiscriminator, int]:
    """The model's discriminator and its patch size."""
    from safetensors.torch import load_file

    d = Path(model_dir) / DISC_DIR
    if not (d / "config.json").is_file():
        raise ModelDirError(f"{model_dir}: no {DISC_DIR}/ (fit one first: `python -m trainer ddg "
                            f"residual-disc --model {model_dir} --store ...`)")
    cfg = json.loads((d / "config.json").read_text())
    if cfg["point_scale"] != POINT_SCALE:
        raise ModelDirError(f"{d}: made for points in units of 1/{cfg['point_scale']} m; refit it")
    disc = PatchDiscriminator(cfg["width"])
    disc.load_state_dict(load_file(d / "weights.safetensors"))
    return disc.eval(), int(cfg["patch"])


def format_table(rows: list[dict]) -> str:
    """The report as a markdown table, shares in %."""
    keys = [k for k in rows[0] if k not in ("patch", "width")]
    lines = ["| patch | width | " + " | ".join(k.replace("_", " ") + " %" for k in keys) + " |",
             "|---|---|" + "---|" * len(keys)]
    lines += [f"| {r['patch']} | {r['width']} | " + " | ".join(f"{100 * r[k]:.1f}" for k in keys) + " |"
              for r in rows]
    return "\n".join(lines)
