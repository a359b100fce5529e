"""``python -m trainer ddg vs-sensor``: each depth source against a simulated sensor's own frames of the same
views.

A paired store (``trainer student readout --sensor stereo --collect-only``, or ``collect --sensor stereo``)
holds for every step the clean frame and what the sensor showed of the same view. Each source is made from
the clean frames and set beside the sensor's on three counts:

- wrong depth: of the pixels a source measures in the policy's range, the share more than 2 cm and 5 cm off
  the clean depth, near the clean frame's depth edges and on flat regions. A faithful source matches the
  sensor's shares; zero is the simulator's, not the sensor's;
- holes: the share of pixels without depth, near edges and on flat regions, and the share of the sensor's
  holes of the same view that the source has too;
- realism: FID and KID (the judge of ``ddg metrics``) of its frames against the sensor's frames of the other
  half of the episodes, with bootstrap 95 % intervals by whole episode; the sensor's own frames of the judged
  half are the floor.

Episodes alternate between the reference half (even) and the judged half (odd), so no view is both judged and
referenced. The sources: ``gt``, ``randnoise``, each DDG with and without grafting, each residual diffusion
(and its stage I alone when it has a stage II, and its output edge-grafted).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from runtime.preprocess import DepthSpec
from trainer.dataset import DatasetError, DemoStore
from trainer.ddg.baselines import DEFAULT_MODEL, randnoise
from trainer.ddg.graft import edge_bands, graft_edges
from trainer.ddg.model import load_config
from trainer.ddg.residual import ResidualGenerator, stage_dirs
from trainer.ddg.sample import Generator, generate_frames

from .judge import RandomEncoder, features, fid, kid
from .paired_depth import hole_agreement, policy_range
from .realism import bootstrap_ci
from .realism_plots import plot_grid

OFF_MM = (20, 50)
"""The wrong-depth thresholds (mm) of the report."""


@dataclass(frozen=True)
class VsSensorConfig:
    store: str = ""
    """Paired store: data/depth (clean) and data/depth_sensor (the sensor's frames of the same views)."""
    ddg: tuple[str, ...] = (str(DEFAULT_MODEL), str(DEFAULT_MODEL.parent / "ddg_stereo"))
    """DDG model directories, each judged with and without grafting."""
    residual: tuple[str, ...] = ()
    """Residual diffusion model directories (``ddg residual-fit``)."""
    steps: int = 5
    """DDIM steps of every generator."""
    every: int = 10
    """Every k-th frame of the store is judged (neighbouring steps are nearly the same view)."""
    bootstrap: int = 100
    """Bootstrap replicates of the FID/KID intervals (0 = none)."""
    seed: int = 0
    """Seed of randnoise, the generators' noise and the bootstrap."""
    threads: int = 2
    """CPU threads."""
    json: str = ""
    """Also write the report here (JSON); a grid of frames per source (PNG) is written beside it."""


def edge_regions(clean_mm: np.ndarray, spec: DepthSpec) -> dict[str, np.ndarray]:
    """The judged pixels of clean frames [N, H, W], those whose clean depth lies in the policy's range, split
    into ``edge`` (near a clean depth edge) and ``flat`` (the rest): made once for every source."""
    in_range = policy_range(clean_mm, spec) & (clean_mm > 0)
    near = edge_bands(clean_mm)
    return {"edge": in_range & near, "flat": in_range & ~near}


def wrong_depth_by_region(depth_mm: np.ndarray, clean_mm: np.ndarray, regions: dict[str, np.ndarray]) -> dict:
    """Frames [N, H, W] against the clean frames of the same views, per region of ``edge_regions``: the share
    of its pixels without depth and the share of the measured ones more than each ``OFF_MM`` off (%)."""
    if depth_mm.shape != clean_mm.shape:
        raise ValueError(f"frames {depth_mm.shape} and clean frames {clean_mm.shape} differ in shape")
    off = np.abs(depth_mm.astype(np.int32) - clean_mm.astype(np.int32))
    out = {}
    for region, mask in regions.items():
        kept = mask & (depth_mm > 0)
        out[f"{region}_holes_pct"] = _pct(1 - kept.sum() / max(mask.sum(), 1))
        for mm in OFF_MM:
            out[f"{region}_off_{mm}mm_pct"] = _pct((off[kept] > mm).mean() if kept.any() else 0.0)
    return out


def vs_sensor(cfg: VsSensorConfig) -> dict:
    torch.set_num_threads(cfg.threads)
    try:
        store = DemoStore.open(cfg.store)
    except DatasetError as exc:  # the ddg commands' input errors are ValueErrors
        raise ValueError(str(exc)) from None
    if "data/depth_sensor" not in store.root:
        raise ValueError(f"{cfg.store} keeps no sensor frames (data/depth_sensor): collect a paired store "
                         "with `trainer student readout --sensor stereo --collect-only`")
    clean, sensor, episode = _frames(store, cfg.every)
    ref, judged = episode % 2 == 0, episode % 2 == 1
    if not ref.any() or not judged.any():
        raise ValueError(f"{cfg.store}: needs at least 2 episodes (one referenced, one judged)")
    sources = {"sensor": sensor[judged], **_sources(cfg, clean[judged], store.depth_spec)}
    enc = RandomEncoder()
    ref_feats, groups = features(sensor[ref], enc), episode[ref]
    regions, rows = edge_regions(clean[judged], store.depth_spec), {}
    for name, frames in sources.items():
        feats = features(frames, enc)
        rows[name] = {"fid": fid(feats, ref_feats), "kid": kid(feats, ref_feats),
                      **bootstrap_ci(feats, episode[judged], ref_feats, groups, cfg.bootstrap, cfg.seed),
                      **wrong_depth_by_region(frames, clean[judged], regions),
                      **hole_agreement(frames, sensor[judged], clean[judged], store.depth_spec)}
    result = {"store": cfg.store, "frames": {"judged": int(judged.sum()), "reference": int(ref.sum())},
              "config": asdict(cfg), "sources": rows}
    print(table(result))
    if cfg.json:
        out = Path(cfg.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")
        plot_grid({"clean": clean[judged], **sources}, out.with_suffix(".png"))
    return result


def _frames(store: DemoStore, every: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every ``every``-th frame's (clean, sensor) uint16 mm and episode index."""
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    n = store.n_steps
    pick = np.arange(0, n, every)
    episode = np.searchsorted(store.episode_ends, pick, side="right")
    clean, sensor = (np.asarray(store.root[name][:n])[pick] for name in ("data/depth", "data/depth_sensor"))
    return clean, sensor, episode


def _sources(cfg: VsSensorConfig, clean: np.ndarray, spec: DepthSpec) -> dict[str, np.ndarray]:
    """Each source's frames of the clean ones (frame i's generator noise seeded by i)."""
    rng = np.random.default_rng(cfg.seed)
    out = {"gt": clean, "randnoise": np.stack([randnoise(d, rng) for d in clean])}
    for model in cfg.ddg:
        own = load_config(model)["depth_spec"]  # raw mm frames: the model reads them over its own range
        frames = replace(spec, near_m=own.near_m, far_m=own.far_m)
        gen = Generator(model, steps=cfg.steps, seed=cfg.seed, threads=cfg.threads, frames=frames)
        name = Path(model).name
        out[f"{name} grafted"], out[f"{name} ungrafted"] = generate_frames(gen, clean, name)
    for model in cfg.residual:
        name, stages = Path(model).name, len(stage_dirs(model))
        for k in range(1, stages + 1):
            gen = ResidualGenerator(model, steps=cfg.steps, seed=cfg.seed, threads=cfg.threads, stages=k)
            label = f"{name} stage {'I' * k}"
            out[label] = generate_frames(gen, clean, label)
        out[f"{name} edge-grafted"] = graft_edges(clean, out[label])  # the last stage's
    return out


def table(result: dict) -> str:
    """The report as a markdown table."""
    frames = result["frames"]
    lines = [f"{frames['judged']} judged frames against the sensor's {frames['reference']} of other episodes",
             "| source | FID [95 %] | KID x1e3 | holes %, edge / flat | of the sensor's holes, shared % | "
             "> 2 cm off %, edge / flat | > 5 cm off %, edge / flat |", "|---|---|---|---|---|---|---|"]
    for name, r in result["sources"].items():
        ci = r.get("fid_ci95")
        fid_text = f"{r['fid']:.3f}" + (f" [{ci[0]:.3f}, {ci[1]:.3f}]" if ci else "")
        lines.append(f"| {name} | {fid_text} | {1e3 * r['kid']:.2f} | {r['edge_holes_pct']} / "
                     f"{r['flat_holes_pct']} | {r['sensor_holes_shared_pct']} | {r['edge_off_20mm_pct']} / "
                     f"{r['flat_off_20mm_pct']} | {r['edge_off_50mm_pct']} / {r['flat_off_50mm_pct']} |")
    return "\n".join(lines)


def _pct(share: float) -> float:
    return round(100 * float(share), 2)
