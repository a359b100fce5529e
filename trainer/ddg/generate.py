"""Add a generator's depth to a demo store, batched, resumable and shardable: the DDG's ``data/depth_ddg`` and
``data/depth_ddg_nograft``, or the residual diffusion's ``data/depth_residual`` (``--generator residual``) or
``data/depth_residual_edges`` (``--generator residual_edges``: edge-grafted, ``graft.graft_edges``).

Work is split in chunks of ``chunk`` frames (the output arrays' zarr chunks), so each chunk is written by
exactly one shard and the store records it (``DemoStore.generation_outputs``): a killed run resumes where it
stopped, and ``--shard i/n`` on n machines covers every chunk once; shards may start together (the first to
take the store's lock file creates the outputs). Each frame's noise is seeded by its index, so the result is
the same however the work is split.
"""

from __future__ import annotations

import fcntl
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import zarr
from tqdm import tqdm

from trainer.dataset import GENERATORS, DemoStore

from .baselines import DEFAULT_MODEL, DEFAULT_RESIDUAL
from .model import model_id
from .residual import ResidualGenerator, residual_model_id
from .sample import Generator

LOCK_NAME = "ddg_generate.lock"


@dataclass(frozen=True)
class GeneratorKind:
    """What differs between the generators: the model used when --model is not given, how a store's settings
    name a model, and the class that runs one (both take the same settings and ``check_frames``)."""

    shipped: Path
    model_id: Callable[[str | Path], str]
    make: Callable[..., Generator | ResidualGenerator]


KINDS = {"ddg": GeneratorKind(DEFAULT_MODEL, model_id, Generator),
         "residual": GeneratorKind(DEFAULT_RESIDUAL, residual_model_id, ResidualGenerator),
         "residual_edges": GeneratorKind(DEFAULT_RESIDUAL, residual_model_id,
                                         partial(ResidualGenerator, edges=True))}
"""Each generator by name; the sources it makes are ``trainer.dataset.GENERATORS``'."""
Generate = Callable[[np.ndarray, np.ndarray], dict[str, np.ndarray]]
"""(simulated frames, their indices in the store) -> each source the generator makes -> its frames."""


class DemoStoreError(ValueError):
    """A demo store without the expected depth array, or a resume that would mix two generator settings."""


@dataclass(frozen=True)
class GenerateConfig:
    demos: str = ""
    """Demo store (zarr) holding data/depth uint16 [N, H, W] mm: for the DDG, the model's crop at any
    resolution (the generator runs at its own and its holes are carried back, nearest-neighbour); for the
    residual diffusion, the model's resolution."""
    generator: str = "ddg"
    """ddg (data/depth_ddg and data/depth_ddg_nograft), residual (data/depth_residual: the residual depth
    diffusion, trainer/ddg/residual.py, every stage its model has) or residual_edges
    (data/depth_residual_edges: the same kept only near the simulated frame's depth edges)."""
    model: str = ""
    """The generator's model directory (default: the shipped one, models/ddg or models/residual)."""
    steps: int = 10
    """DDIM steps."""
    eta: float = 0.0
    """DDIM eta: 0 = deterministic DDIM, 1 = DDPM-like fresh noise each step (per-frame seeded)."""
    shard: str = "0/1"
    """This worker's share, i/n: chunks with index % n == i."""
    batch: int = 64
    """Frames per onnxruntime call."""
    chunk: int = 256
    """Frames per output chunk (the unit of resume and sharding)."""
    seed: int = 0
    """Noise seed (per frame: seed, frame index)."""
    episodes: int = 0
    """Only the chunks that the first N episodes span (0: all); a student then trains with --episodes N."""
    threads: int = 2
    """CPU cores for onnxruntime."""
    mode: str = "split"
    """How a batch is spread over the cores: split | intra | intra_spin (see ``sample.SESSION_MODES``)."""
    replace: bool = False
    """Drop this generator's depth that the store holds from other settings (another model, steps, seed or
    chunk) and start over, instead of refusing: for a copy of a store made to hold another model's depth."""

    @property
    def model_dir(self) -> str:
        return self.model or str(KINDS[self.generator].shipped)

    def shard_pair(self) -> tuple[int, int]:
        try:
            i, n = (int(v) for v in self.shard.split("/"))
        except ValueError:
            raise DemoStoreError(f"--shard must look like i/n, got {self.shard!r}") from None
        if not 0 <= i < n:
            raise DemoStoreError(f"--shard {self.shard}: need 0 <= i < n")
        return i, n


def generate(cfg: GenerateConfig) -> dict:
    """Fill this shard's missing chunks; returns {"frames", "seconds", "fps"}."""
    if cfg.generator not in GENERATORS:
        raise DemoStoreError(f"--generator {cfg.generator!r}: choose one of {sorted(GENERATORS)}")
    store = _open(cfg.demos)
    depth = store.root["data/depth"]
    n = depth.shape[0]
    i, shards = cfg.shard_pair()
    gen = _generator(cfg, store)
    needed = -(-(_frames_of(store, cfg.episodes) if cfg.episodes else n) // cfg.chunk)  # chunks to fill
    with _exclusive(cfg.demos):  # shards started together: the first creates the outputs, the rest see them
        outs, done = _outputs(_open(cfg.demos), cfg)  # reopened: attrs as the holder left them
    todo = [k for k in range(needed) if k % shards == i and not done[k]]
    frames, t0 = 0, time.perf_counter()
    bar = tqdm(todo, desc=f"{cfg.generator} generate shard {cfg.shard}", unit="chunk")
    for k in bar:
        lo, hi = k * cfg.chunk, min(n, (k + 1) * cfg.chunk)
        sim = np.asarray(depth[lo:hi])
        parts = [gen(sim[b:b + cfg.batch], np.arange(lo + b, min(hi, lo + b + cfg.batch)))
                 for b in range(0, hi - lo, cfg.batch)]
        for source, out in outs.items():
            out[lo:hi] = np.concatenate([p[source] for p in parts])
        done[k] = True
        frames += hi - lo
        bar.set_postfix(fps=f"{frames / (time.perf_counter() - t0):.1f}")
    seconds = time.perf_counter() - t0
    stats = {"frames": frames, "seconds": round(seconds, 2), "fps": round(frames / max(seconds, 1e-9), 2)}
    print(f"generated {frames} frames of {cfg.generator} depth in {seconds:.1f} s: {stats['fps']} frames/s "
          f"(DDIM {cfg.steps} steps, batch {cfg.batch}, {cfg.threads} cores {cfg.mode}, shard {cfg.shard})")
    return stats


def _generator(cfg: GenerateConfig, store: DemoStore) -> Generate:
    """``cfg``'s generator; it refuses the store's frames here, before any work."""
    # a store made by hand (tests) may carry no spec: its frames are then taken to be the model's
    store_spec = store.depth_spec if "depth_spec" in store.root.attrs else None
    gen = KINDS[cfg.generator].make(cfg.model_dir, steps=cfg.steps, seed=cfg.seed, threads=cfg.threads,
                                    mode=cfg.mode, eta=cfg.eta, frames=store_spec)
    gen.check_frames(store.root["data/depth"])
    made = GENERATORS[cfg.generator]

    def by_source(sim: np.ndarray, indices: np.ndarray) -> dict[str, np.ndarray]:
        out = gen(sim, indices)  # the DDG's two outputs, or the residual diffusion's one
        return dict(zip(made, out if isinstance(out, tuple) else (out,), strict=True))
    return by_source


def _frames_of(store: DemoStore, episodes: int) -> int:
    """Frames of the store's first ``episodes`` episodes."""
    ends = store.episode_ends
    if not 0 < episodes <= len(ends):
        raise DemoStoreError(f"--episodes {episodes}: the store holds {len(ends)} episodes")
    return int(ends[episodes - 1])


def _open(path: str) -> DemoStore:
    """The store for writing; any zarr group with a data/depth array will do (tests make them by hand)."""
    if not path or not Path(path).exists():
        raise DemoStoreError(f"no demo store at {path!r}")
    root = zarr.open_group(path, mode="r+")
    if "data/depth" not in root:
        raise DemoStoreError(f"{path}: no data/depth array")
    d = root["data/depth"]
    if d.dtype != np.uint16 or d.ndim != 3:
        raise DemoStoreError(f"{path}: data/depth must be uint16 [N, H, W], got {d.dtype} {d.shape}")
    return DemoStore(root, path)


@contextmanager
def _exclusive(path: str) -> Iterator[None]:
    """Hold the store's lock file (``LOCK_NAME``; zarr ignores it) until the block ends."""
    with open(Path(path) / LOCK_NAME, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _outputs(store: DemoStore, cfg: GenerateConfig) -> tuple[dict[str, zarr.Array], zarr.Array]:
    """The store's outputs of ``cfg``'s generator for its settings; its depth made with others is refused, or
    dropped with ``--replace``."""
    name = KINDS[cfg.generator].model_id(cfg.model_dir)
    settings = {"model": name, "steps": cfg.steps, "seed": cfg.seed,
                "chunk": cfg.chunk, **({"eta": cfg.eta} if cfg.eta else {})}  # stores made before eta resume
    previous = store.generated_with(cfg.generator)
    if previous is not None and previous != settings:
        if not cfg.replace:
            raise DemoStoreError(f"store already holds {cfg.generator} depth made with {previous}, not "
                                 f"{settings}; pass --replace to drop it and regenerate")
        store.drop_generated(cfg.generator)
    return store.generation_outputs(cfg.generator, settings, cfg.chunk)
