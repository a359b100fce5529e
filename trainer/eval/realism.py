"""``python -m trainer ddg metrics``: realism of each depth source against real captures (paper Table I).

Reference: held-out D4xx frames of --real (``data.HOLDOUT_FRAMES``; all D4xx frames with --subset all), each
cut into random policy-resolution crops. Every judged set has ``sim_frames`` frames, so FID's small-sample
bias is the same for all of them. The 95% intervals come from a bootstrap that resamples the reference by
whole frame (its crops are not independent) and the judged set by frame.

Sources: ``gt`` (sim), ``randnoise`` (sim), ``inpaint`` (as in the paper, Sim GT judged against inpainted
real depth), ``ddg_nograft`` and ``ddg`` (sim through the generator), plus two real references:
``real_train`` (D4xx training frames: the floor a perfect generator could reach) and ``real_other_sensors``
(the non-D4xx captures: how far other sensors' artifacts are from a D4xx's).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from trainer.ddg.baselines import DEFAULT_MODEL, inpaint, randnoise
from trainer.ddg.data import (
    POLICY_SPEC,
    RealDataError,
    load_real_dir,
    policy_crop,
    source_of,
    split,
)

from .holes import hole_stats
from .judge import JUDGE_CHANNELS, RandomEncoder, features, fid, kid
from .realism_plots import plot_grid, plot_holes, plot_tsne
from .sim_frames import from_demos, rendered, void_as_far


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
    source: str = ""
    """Instead of --subset, every D4xx frame of this capture source (the name before '__', e.g.
    anygrasp_tracking), the other sources' as ``real_train``: judged with a DDG fitted ``--leave-out`` that
    source, how the generator does on captures from elsewhere (the JSON counts the reference frames the model
    trained on: 0 for a left-out source)."""
    crops: int = 16
    """Random crops per real frame."""
    sim_frames: int = 192
    """Simulated frames per source."""
    steps: int = 10
    """DDIM steps for the DDG sources."""
    eta: float = 0.0
    """DDIM eta for the DDG sources (0 = deterministic DDIM, 1 = DDPM-like)."""
    seed: int = 0
    """Seed for crops, noise and generation."""
    bootstrap: int = 100
    """Bootstrap replicates for the FID/KID 95% intervals (0 = none)."""
    threads: int = 2
    """torch and onnxruntime CPU threads."""
    views: str = "policy"
    """Simulated frames rendered (without --demos) from: policy (the robot's camera: the demos' view, with the
    void past the table) or matched (close views of the object at the real captures' range, 0.5-1.0 m, where
    the scene differs less from theirs; trainer.eval.sim_frames)."""
    judge: str = "both"
    """What the judge sees: both (relative valid depth and the hole mask), holes (the hole mask alone: where
    the artifacts fall, the scene's depth hidden) or depth (relative valid depth alone, a hole reading 0)."""
    void_as_far: bool = False
    """Diagnostic: give the simulated frames' "no data" pixels (in hil_sim's view: the void past the table,
    beyond the D455's range) the far depth before anything is judged, as if the world had a wall in range."""


def run_metrics(cfg: MetricsConfig) -> dict:
    _check(cfg)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    (ref, ref_groups), extra_real = _real_sets(cfg, rng)
    if cfg.demos:
        sim = from_demos(cfg.demos, cfg.sim_frames)
    else:
        sim = rendered(cfg.sim_frames, cfg.seed, cfg.views)
    if cfg.void_as_far:
        sim = void_as_far(sim, POLICY_SPEC)
    sim_groups = np.arange(len(sim))
    noisy = np.stack([randnoise(d, rng) for d in sim])
    simulated = {"gt": sim, "randnoise": noisy, **_ddg_sources(cfg, sim)}
    if cfg.judge != "holes":  # Sim GT and inpainted real depth both have none: nothing for that judge to see
        simulated["inpaint"] = sim
    frames = {**extra_real, **{k: (v, sim_groups) for k, v in simulated.items()}}
    judged_against = {"inpaint": np.stack([inpaint(d, rng) for d in ref])}
    enc = RandomEncoder()
    ref_feats = features(ref, enc, cfg.judge)
    result = {"reference": {"frames": len(ref), "real_frames": len(np.unique(ref_groups)), **hole_stats(ref),
                            **_seen_by_model(cfg)},
              "sources": {}, "config": asdict(cfg)}
    feats = {}
    for name, (fr, groups) in frames.items():
        feats[name] = features(fr, enc, cfg.judge)
        against = features(judged_against[name], enc, cfg.judge) if name in judged_against else ref_feats
        ci = bootstrap_ci(feats[name], groups, against, ref_groups, cfg.bootstrap, cfg.seed)
        result["sources"][name] = {"fid": fid(feats[name], against), "kid": kid(feats[name], against), **ci,
                                   "vs": "real_inpaint" if name in judged_against else "real",
                                   "frames": len(fr), **hole_stats(fr)}
        if name in simulated:
            result["sources"][name]["off_sim_mm_p50_p90"] = off_sim_mm(fr, sim)
    out = Path(cfg.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(table(result))
    plot_grid({"real": ref, **{k: v for k, (v, _) in frames.items() if k != "inpaint"},
               "real_inpaint": judged_against["inpaint"]}, out.with_name("grid.png"))
    plot_holes({"real": ref, **{k: v for k, (v, _) in frames.items() if k != "inpaint"}},
               {"real": result["reference"], **result["sources"]}, out.with_name("holes.png"))
    plot_tsne(ref_feats, {k: v for k, v in feats.items() if k != "inpaint"}, out.with_name("tsne.png"))
    return result


def _check(cfg: MetricsConfig) -> None:
    if cfg.judge not in JUDGE_CHANNELS:
        raise RealDataError(f"--judge must be one of {', '.join(JUDGE_CHANNELS)}, got {cfg.judge!r}")
    if cfg.demos and cfg.views != "policy":
        raise RealDataError(f"--views {cfg.views} renders its own scenes; a demo store holds the policy's "
                            "view only (drop --demos or --views)")


def off_sim_mm(frames: np.ndarray, sim: np.ndarray) -> list[float]:
    """Median and p90 of |depth - the simulator's| over the pixels both measure: how far a source moves the
    scene's geometry (grafting keeps it: 0 by construction; the paper's reason for it)."""
    both = (frames > 0) & (sim > 0)
    off = np.abs(frames[both].astype(np.int32) - sim[both].astype(np.int32))
    return [float(v) for v in np.percentile(off, [50, 90])] if off.size else [float("nan")] * 2


def bootstrap_ci(a: np.ndarray, a_groups: np.ndarray, b: np.ndarray, b_groups: np.ndarray, replicates: int,
                 seed: int = 0) -> dict:
    """95% percentile intervals of FID and KID, resampling whole groups (frames) of both sets."""
    if replicates <= 0:
        return {}
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(replicates):
        ia, ib = _resample(a_groups, rng), _resample(b_groups, rng)
        draws.append((fid(a[ia], b[ib]), kid(a[ia], b[ib], subsets=10)))
    lo, hi = np.percentile(draws, [2.5, 97.5], axis=0)
    return {"fid_ci95": [float(lo[0]), float(hi[0])], "kid_ci95": [float(lo[1]), float(hi[1])]}


def _resample(groups: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Row indices of a bootstrap sample that draws whole groups with replacement."""
    ids = np.unique(groups)
    return np.concatenate([np.flatnonzero(groups == g) for g in rng.choice(ids, len(ids))])


def table(result: dict) -> str:
    """Table I analogue plus hole statistics, one row per source."""
    head = (f"{'source':<20}{'FID':>9}{'FID 95% CI':>16}{'KIDx100':>9}{'KIDx100 95% CI':>17}{'holes%':>8}"
            f"{'p50 size':>9}{'edge/flat':>10}{'grad p90':>9}{'off sim p50/p90 mm':>20}")
    rows = [head, "-" * len(head)]
    ref = result["reference"]
    rows.append(_row("real (reference)", ref))
    for name, s in result["sources"].items():
        rows.append(_row("inpaint (gt vs inp.)" if s["vs"] == "real_inpaint" else name, s))
    return "\n".join(rows)


def _row(name: str, s: dict) -> str:
    ratio = s["edge_flat_ratio"]
    fid_, kid_ = (f"{s['fid']:9.2f}", f"{100 * s['kid']:9.3f}") if "fid" in s else ("", "")
    fid_ci, kid_ci = (_interval(s.get("fid_ci95"), 1), _interval(s.get("kid_ci95"), 100))
    return (f"{name:<20}{fid_:>9}{fid_ci:>16}{kid_:>9}{kid_ci:>17}"
            f"{100 * s['hole_fraction']:8.2f}{s['hole_size_px_p50_p90'][0]:9.1f}"
            f"{'-' if ratio is None else f'{ratio:.1f}':>10}{s['grad_mm_per_px_p50_p90_p99'][1]:9.1f}"
            f"{' / '.join(f'{v:.0f}' for v in s.get('off_sim_mm_p50_p90', [])):>20}")


def _interval(ci: list[float] | None, scale: float) -> str:
    return f"[{scale * ci[0]:.2f}, {scale * ci[1]:.2f}]" if ci else ""


Crops = tuple[np.ndarray, np.ndarray]
"""(uint16 crops [N, H, W], the real frame each crop came from [N])."""


def _real_sets(cfg: MetricsConfig, rng: np.random.Generator) -> tuple[Crops, dict[str, Crops]]:
    if cfg.subset not in ("holdout", "all"):
        raise RealDataError(f"--subset must be holdout or all, got {cfg.subset!r}")
    every = load_real_dir(cfg.real, "all")
    d4xx = [f for f in every if f.sensor == "d4xx"]
    if not d4xx:
        raise RealDataError(f"{cfg.real}: no RealSense D4xx frames to use as the reference")
    if cfg.source:
        train, reference = split(d4xx, holdout=(), leave_out=cfg.source)
    else:
        train, held = split(d4xx)
        if cfg.subset == "holdout" and not held:
            raise RealDataError(f"{cfg.real}: none of the held-out frames is there; use --subset all")
        reference, train = (held, train) if cfg.subset == "holdout" else (d4xx, [])
    extra = {"real_train": train, "real_other_sensors": [f for f in every if f.sensor != "d4xx"]}
    crops = {name: _crops(fs, rng.integers(0, len(fs), cfg.sim_frames), rng)
             for name, fs in extra.items() if fs}
    return _crops(reference, np.repeat(np.arange(len(reference)), cfg.crops), rng), crops


def _seen_by_model(cfg: MetricsConfig) -> dict:
    """With --source: how many of its frames the DDG trained on (its config's ``frames``; a model that lists
    none is not counted)."""
    if not (cfg.source and cfg.model):
        return {}
    from trainer.ddg.model import load_config

    trained = load_config(cfg.model).get("frames")
    if trained is None:
        return {}
    return {"frames_the_model_trained_on": sum(source_of(name) == cfg.source for name in trained)}


def _crops(frames, which: np.ndarray, rng: np.random.Generator) -> Crops:
    """One policy crop of ``frames[i]`` for each i in ``which``: at the frame's own policy window when it
    has one (a capture by the robot's camera), else at random."""
    return np.stack([policy_crop(frames[i].depth_mm, rng, window=frames[i].window)[0] for i in which]), which


def _ddg_sources(cfg: MetricsConfig, sim: np.ndarray) -> dict[str, np.ndarray]:
    if not cfg.model:
        return {}
    from trainer.ddg.sample import Generator, generate_frames

    gen = Generator(cfg.model, steps=cfg.steps, seed=cfg.seed, threads=cfg.threads, eta=cfg.eta)
    grafted, ungrafted = generate_frames(gen, sim, "ddg", batch=64)
    return {"ddg_nograft": ungrafted, "ddg": grafted}
