"""Every labelled step of a recipe's stores (the expert's demos and the DAgger rounds) as tensors on the
training device, so a batch is a few index gathers rather than a Python loop per sample.

Depth is held as the sensor's 16 bits (half the memory of float32 frames; as int16, since CUDA cannot index a
uint16 tensor); a CPU fit keeps them in an unlinked file beside the stores, mapped into memory: the page cache
holds what fits and the kernel can drop it, where a fit's own copy of 300k frames at 192 x 144 (17 GB) leaves
a 24 GiB machine no room. Frames are normalised per batch through a table of
``runtime.preprocess.normalise`` over every uint16 value, the one implementation the runtime runs; stacks
follow the ``FrameStack`` rule (the episode's first frame fills the history): a sample's stack is what the
runtime feeds the policy at that step (tests/student/test_recipe.py).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from runtime.preprocess import DepthSpec, normalise
from trainer.dataset import DEPTH_SOURCES, DemoStore, sizes


class StepsError(ValueError):
    """Stores the recipe cannot train on (no labels, another resolution, no frames of the depth asked)."""


STORED = tuple(source for source in DEPTH_SOURCES if source != "randnoise")
"""The depth sources a fit reads as stored: the clean frames, those a sensor showed the learner, or a
generator's made from the clean ones (``trainer ddg generate``)."""


@dataclass(frozen=True)
class StepBatch:
    depth: torch.Tensor | None
    """float32 [B, To, H, W] preprocessed stacks, oldest first; None when the steps carry no depth."""
    state: torch.Tensor
    labels: torch.Tensor
    """float32 [B, 12] (``trainer.sim.labels.LABELS``)."""
    chunk: torch.Tensor | None
    """float32 [B, Ha, 8] the expert's action chunk from the step's state, env units; None when the steps
    are read without them (a perception-only fit)."""
    teacher_depth: torch.Tensor | None = None
    """float32 [B, To, H, W] the same stacks from a feature teacher's depth source (``teacher_source``),
    else None."""


class LabelledSteps:
    def __init__(self, paths: list[Path], obs_horizon: int, action_horizon: int, *, depth: bool,
                 chunks: bool = True, device: torch.device | str = "cpu", depth_source: str = "gt",
                 teacher_source: str | None = None) -> None:
        """``chunks``: read the expert's action chunks too (every store must hold them); without, the steps
        serve perception alone, and stores of frame labels only (a ``RoundSpec.horizon`` 0 round) will do.
        ``depth_source``: ``gt`` (the clean frames), ``sensor`` (what a round's ``RoundSpec.sensor``
        showed the learner) or a generated source (``STORED``). ``teacher_source``: a second source whose
        stacks of the same steps each batch carries too (``StepBatch.teacher_depth``)."""
        self.device = torch.device(device)
        sources = [depth_source] + ([teacher_source] if teacher_source else [])
        for source in sources:
            if source not in STORED:
                raise StepsError(f"unknown depth source {source!r}; choose one of {sorted(STORED)}")
        stores = [DemoStore.open(p) for p in paths]
        arrays = [depth_arrays(stores, source) for source in (sources if depth else [])]  # refused up front
        parts = [self._read(store, p, action_horizon if chunks else 0)
                 for store, p in zip(stores, paths, strict=True)]
        self.spec: DepthSpec = parts[0]["spec"]
        for p, part in zip(paths, parts, strict=True):
            if part["spec"] != self.spec:
                raise StepsError(f"{p} holds {sizes(part['spec'])}, {paths[0]} {sizes(self.spec)}")
        offsets = np.cumsum([0] + [len(part["state"]) for part in parts])
        start = np.concatenate([part["start"] + off for part, off in zip(parts, offsets, strict=False)])
        self.state_np = np.concatenate([part["state"] for part in parts])
        self.labels_np = np.concatenate([part["labels"] for part in parts])
        self.chunk_np = np.concatenate([part["chunk"] for part in parts]) if chunks else None
        self.kinds = np.concatenate([part["kinds"] for part in parts])
        """str [N]: the object kind of each step's episode."""
        back = np.arange(obs_horizon - 1, -1, -1)
        stacks = np.maximum(np.arange(len(start))[:, None] - back, start[:, None])
        self.stack_index = torch.from_numpy(stacks).to(self.device)
        scales = {part["depth_scale"] for part in parts}
        if len(scales) > 1:
            raise StepsError(f"{paths} mix depth scales {sorted(scales)}")
        spill = paths[0].parent if self.device.type == "cpu" else None  # a GPU copy frees the host's at once
        held = [torch.from_numpy(_frames(stores, names, spill).view(np.int16)).to(self.device)
                for names in arrays]
        self.frames = held[0] if held else None
        self.teacher_frames = held[1] if len(held) > 1 else None
        self.normalised = torch.from_numpy(normalise(np.arange(2 ** 16, dtype=np.uint16), scales.pop(),
                                                     self.spec)).to(self.device)
        """float32 [65536]: ``normalise`` of each uint16 sensor value."""
        self.state, self.labels, self.chunk = (None if a is None else torch.from_numpy(a).to(self.device)
                                               for a in (self.state_np, self.labels_np, self.chunk_np))

    @staticmethod
    def _read(store: DemoStore, path: Path, action_horizon: int) -> dict:
        """A store's steps, with the expert's chunks of ``action_horizon`` actions (none when 0)."""
        root, n = store.root, store.n_steps
        if "data/labels" not in root:
            raise StepsError(f"{path} records no perception labels: make it with `trainer student recipe`")
        kept = store.attrs.get("chunk_horizon", 0)
        if kept < action_horizon:
            raise StepsError(f"{path} labels chunks of {kept} steps, the student predicts {action_horizon}"
                             + ("" if kept else ": its frames are labelled alone, for a perception-only fit"))
        ends = store.episode_ends
        lengths = np.diff(ends, prepend=0)
        chunk = np.asarray(root["data/chunk"][:n, :action_horizon], np.float32) if action_horizon else None
        return {"spec": store.depth_spec, "state": np.asarray(root["data/state"][:n], np.float32),
                "labels": np.asarray(root["data/labels"][:n], np.float32), "chunk": chunk,
                "start": np.repeat(ends - lengths, lengths), "kinds": np.repeat(store.kinds, lengths),
                "depth_scale": float(store.attrs["depth_scale"])}

    def __len__(self) -> int:
        return len(self.state_np)

    def batch(self, index: torch.Tensor) -> StepBatch:
        index = index.to(self.device)
        chunk = None if self.chunk is None else self.chunk[index]
        return StepBatch(self._stacks(self.frames, index), self.state[index], self.labels[index], chunk,
                         self._stacks(self.teacher_frames, index))

    def _stacks(self, frames: torch.Tensor | None, index: torch.Tensor) -> torch.Tensor | None:
        if frames is None:
            return None
        sensor = frames[self.stack_index[index]].int() & 0xFFFF  # int16 bits -> uint16 values
        return self.normalised[sensor]


def depth_arrays(stores: list[DemoStore], source: str) -> list[str]:
    """Each store's array of depth ``source`` (``DemoStore.check_depth``: refused when absent, or where a
    generator's chunks are unfinished, zeros)."""
    return [store.check_depth(source, store.n_steps) for store in stores]


def _frames(stores: list[DemoStore], names: list[str], folder: Path | None) -> np.ndarray:
    """Every store's frames of one depth source (``names``: its array in each store, ``depth_arrays``) in
    one uint16 array [steps, H, W], filled a zarr chunk at a time; with a ``folder``, into a file there that
    is unlinked at once (the space comes back when the array goes, even if the process is killed), else in
    memory. Nothing is held twice: per-store copies joined by ``np.concatenate`` were, and a 192 x 144
    recipe's round-5 fit (250k frames, 14 GB) was killed for it on a 24 GiB machine."""
    arrays = [store.root[name] for store, name in zip(stores, names, strict=True)]
    steps = sum(store.n_steps for store in stores)
    shape = (steps, *arrays[0].shape[1:])
    if folder is None:
        out = np.empty(shape, np.uint16)
    else:
        with tempfile.TemporaryFile(dir=folder, prefix="frames-") as file:
            out = np.memmap(file, np.uint16, "w+", shape=shape)  # the mapping keeps the unlinked file alive
    at = 0
    for store, depth in zip(stores, arrays, strict=True):
        n = store.n_steps
        for i in range(0, n, depth.chunks[0]):
            j = min(i + depth.chunks[0], n)
            out[at + i:at + j] = depth[i:j]
        at += n
    return out
