"""``python -m trainer ddg bench``: generation throughput at the policy resolution, side by side.

Every (session mode, batch, DDIM steps) setting runs the whole generator on the same frames: the DDG's
``Generator`` (prior, DDIM loop, decoding, grafting) or, with ``--generator residual``, the residual
diffusion's (every stage of its model, each a DDIM loop, then decoding). Settings take turns within each
round, so a machine whose load drifts (a shared one) slows them alike. Per call it records wall time and
process CPU time per frame; the report gives medians and 99th percentiles over all calls, and frames/s =
1 / median wall time per frame.
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from trainer.ddg.generate import KINDS
from trainer.ddg.residual import ResidualGenerator
from trainer.ddg.sample import SESSION_MODES, Generator

from .sim_frames import from_demos, rendered


@dataclass(frozen=True)
class BenchConfig:
    generator: str = "ddg"
    """ddg or residual."""
    model: str = ""
    """The generator's model directory (default: the shipped one, models/ddg or models/residual)."""
    demos: str = ""
    """Demo store to take frames from (default: render randomised hil_sim.world scenes, at the policy's
    96x128: a residual model made at another resolution needs a store of its own)."""
    steps: tuple[int, ...] = (5, 10, 20)
    """DDIM step counts."""
    batches: tuple[int, ...] = (1, 16)
    """Frames per Generator call."""
    modes: tuple[str, ...] = SESSION_MODES
    """onnxruntime session modes (see ``trainer.ddg.sample.SESSION_MODES``)."""
    threads: int = 2
    """CPU cores per generator."""
    frames: int = 16
    """Frames each setting generates per round."""
    rounds: int = 4
    """Rounds (each setting once per round, in turn); the first, a warm-up, is not counted."""
    json: str = "runs/ddg/bench/bench.json"
    """Output JSON."""


def bench(cfg: BenchConfig) -> dict:
    if cfg.generator not in KINDS:
        raise ValueError(f"--generator {cfg.generator!r}: choose one of {sorted(KINDS)}")
    frames = from_demos(cfg.demos, cfg.frames) if cfg.demos else rendered(cfg.frames)
    settings = list(itertools.product(cfg.modes, cfg.batches, cfg.steps))
    kind = KINDS[cfg.generator]
    model = cfg.model or str(kind.shipped)
    gens = {s: kind.make(model, steps=s[2], threads=cfg.threads, mode=s[0]) for s in settings}
    samples: dict[tuple, list[tuple[float, float]]] = {s: [] for s in settings}
    for r in range(cfg.rounds):
        for s in settings:
            times = _timed_calls(gens[s], frames, s[1])
            if r:
                samples[s] += times
    rows = [_summary(s, samples[s]) for s in settings]
    result = {"config": asdict(cfg), "rows": rows}
    Path(cfg.json).parent.mkdir(parents=True, exist_ok=True)
    Path(cfg.json).write_text(json.dumps(result, indent=1))
    print(table(rows))
    return result


def _timed_calls(gen: Generator | ResidualGenerator, frames: np.ndarray, batch: int
                 ) -> list[tuple[float, float]]:
    """(wall ms per frame, CPU ms per frame) of each call over ``frames`` in batches."""
    out = []
    for lo in range(0, len(frames), batch):
        chunk = frames[lo:lo + batch]
        w0, c0 = time.perf_counter(), time.process_time()
        gen(chunk, np.arange(lo, lo + len(chunk)))
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        out.append((1000 * wall / len(chunk), 1000 * cpu / len(chunk)))
    return out


def _summary(setting: tuple, samples: list[tuple[float, float]]) -> dict:
    mode, batch, steps = setting
    wall, cpu = np.array(samples).T
    med, p99 = np.percentile(wall, [50, 99])
    return {"mode": mode, "batch": batch, "steps": steps, "calls": len(wall),
            "wall_ms_per_frame_p50": float(med), "wall_ms_per_frame_p99": float(p99),
            "cpu_ms_per_frame_p50": float(np.median(cpu)), "fps": float(1000 / med)}


def table(rows: list[dict]) -> str:
    head = (f"{'mode':<11}{'batch':>6}{'steps':>6}{'calls':>6}{'ms/frame p50':>14}{'p99':>9}"
            f"{'CPU ms p50':>12}{'fps':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['mode']:<11}{r['batch']:>6}{r['steps']:>6}{r['calls']:>6}"
                     f"{r['wall_ms_per_frame_p50']:14.1f}{r['wall_ms_per_frame_p99']:9.1f}"
                     f"{r['cpu_ms_per_frame_p50']:12.1f}{r['fps']:8.1f}")
    return "\n".join(lines)
