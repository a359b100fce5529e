"""``python -m trainer ddg metrics``: realism of each depth source against real captures (paper Table I).

Reference: held-out D4xx frames of --real (``data.HOLDOUT_FRAMES``; all D4xx frames with --subset all), each
cut into random policy-resolution crops. Sources: ``gt`` (sim), ``randnoise`` (sim), ``inpaint`` (as in the
paper, Sim GT judged against inpainted real depth), ``ddg_nograft`` and ``ddg`` (sim through the generator),
plus two real references: ``real_train`` (D4xx training frames: the floor a perfect generator could reach)
and ``real_other_sensors`` (the non-D4xx captures: how far other sensors' artifacts are from a D4xx's).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .baselines import DEFAULT_MODEL, inpaint, randnoise
from .data import RealDataError, load_real_dir, policy_crop, split
from .features import RandomEncoder, features, fid, kid
from .holestats import hole_stats
from .plots import plot_grid, plot_tsne
from .simframes import from_demos, rendered


@dataclass(frozen=True)
class MetricsConfig:
    real: str = "../shared/data/real_depth"
    """Directory of real captures (.npz with depth_m), the reference."""
    json: str = "runs/ddg/metrics/metrics.json"
    """Output JSON; the grid and t-SNE PNGs are written beside it."""
    model: str = str(DEFAULT_MODEL)
    """DDG model directory ('' skips the DDG sources)."""
    demos: str = ""
    """Demo store to take simulated frames from (default: render randomised hil_sim.world scenes)."""
    subset: str = "holdout"
    """Reference frames: holdout (the held-out D4xx frames) or all (every D4xx frame in --real)."""
    crops: int = 16
    """Random crops per real frame."""
    sim_frames: int = 192
    """Simulated frames per source."""
    steps: int = 10
    """DDIM steps for the DDG sources."""
    seed: int = 0
    """Seed for crops, noise and generation."""


def run_metrics(cfg: MetricsConfig) -> dict:
    rng = np.random.default_rng(cfg.seed)
    ref, extra_real = _real_sets(cfg, rng)
    sim = from_demos(cfg.demos, cfg.sim_frames) if cfg.demos else rendered(cfg.sim_frames, cfg.seed)
    frames = {**extra_real, "gt": sim, "randnoise": np.stack([randnoise(d, rng) for d in sim]),
              "inpaint": sim, **_ddg_sources(cfg, sim)}
    judged_against = {"inpaint": np.stack([inpaint(d, rng) for d in ref])}
    enc = RandomEncoder()
    ref_feats = features(ref, enc)
    result = {"reference": {"frames": len(ref), **hole_stats(ref)}, "sources": {}, "config": asdict(cfg)}
    feats = {}
    for name, fr in frames.items():
        feats[name] = features(fr, enc)
        against = features(judged_against[name], enc) if name in judged_against else ref_feats
        result["sources"][name] = {"fid": fid(feats[name], against), "kid": kid(feats[name], against),
                                   "vs": "real_inpaint" if name in judged_against else "real",
                                   "frames": len(fr), **hole_stats(fr)}
    out = Path(cfg.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(table(result))
    plot_grid({"real": ref, **{k: v for k, v in frames.items() if k != "inpaint"},
               "real_inpaint": judged_against["inpaint"]}, out.with_name("grid.png"))
    plot_tsne(ref_feats, {k: v for k, v in feats.items() if k != "inpaint"}, out.with_name("tsne.png"))
    return result


def table(result: dict) -> str:
    """Table I analogue plus hole statistics, one row per source."""
    head = (f"{'source':<20}{'FID':>9}{'KIDx100':>9}{'holes%':>8}{'p50 size':>9}{'edge/flat':>10}"
            f"{'grad p90':>9}")
    rows = [head, "-" * len(head)]
    ref = result["reference"]
    rows.append(_row("real (reference)", None, None, ref))
    for name, s in result["sources"].items():
        label = "inpaint (gt vs inp.)" if s["vs"] == "real_inpaint" else name
        rows.append(_row(label, s["fid"], s["kid"], s))
    return "\n".join(rows)


def _row(name: str, f: float | None, k: float | None, s: dict) -> str:
    ratio = s["edge_flat_ratio"]
    return (f"{name:<20}{'' if f is None else f'{f:9.2f}':>9}{'' if k is None else f'{100 * k:9.3f}':>9}"
            f"{100 * s['hole_fraction']:8.2f}{s['hole_size_px_p50_p90'][0]:9.1f}"
            f"{'-' if ratio is None else f'{ratio:.1f}':>10}{s['grad_mm_per_px_p50_p90_p99'][1]:9.1f}")


def _real_sets(cfg: MetricsConfig, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if cfg.subset not in ("holdout", "all"):
        raise RealDataError(f"--subset must be holdout or all, got {cfg.subset!r}")
    every = load_real_dir(cfg.real, "all")
    d4xx = [f for f in every if f.sensor == "d4xx"]
    if not d4xx:
        raise RealDataError(f"{cfg.real}: no RealSense D4xx frames to use as the reference")
    train, held = split(d4xx)
    if cfg.subset == "holdout" and not held:
        raise RealDataError(f"{cfg.real}: none of the held-out frames is there; use --subset all")
    reference = held if cfg.subset == "holdout" else d4xx
    extra = {"real_train": train if cfg.subset == "holdout" else [],
             "real_other_sensors": [f for f in every if f.sensor != "d4xx"]}
    crops = {name: _crops(fs, cfg.crops, rng) for name, fs in extra.items() if fs}
    return _crops(reference, cfg.crops, rng), crops


def _crops(frames, per_frame: int, rng: np.random.Generator) -> np.ndarray:
    return np.stack([policy_crop(f.depth_mm, rng)[0] for f in frames for _ in range(per_frame)])


def _ddg_sources(cfg: MetricsConfig, sim: np.ndarray) -> dict[str, np.ndarray]:
    if not cfg.model:
        return {}
    from .sample import Generator

    gen = Generator(cfg.model, steps=cfg.steps, seed=cfg.seed)
    parts = [gen(sim[i:i + 64], np.arange(i, min(len(sim), i + 64))) for i in range(0, len(sim), 64)]
    return {"ddg_nograft": np.concatenate([p[1] for p in parts]),
            "ddg": np.concatenate([p[0] for p in parts])}
