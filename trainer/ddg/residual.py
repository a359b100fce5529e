"""Stable-Sim2Real's residual depth diffusion (its §3.2 and §3.5): the target it learns, how that target turns
back into depth, and sampling through the model's stages.

The target x0, float32 [2, H, W] in [-1, 1], of a paired frame (sim, sensor):

- channel 0, the residual: (sensor - sim) in metres through the model's ``ResidualCode`` (clipped to
  +-``residual_m``, divided by it and mu-law companded); 0 where either frame has no depth (there is no
  residual there to learn);
- channel 1, the holes: +1 where the sensor has no depth, -1 where it has.

The paper writes the residual as S - R in §3.2 but adds it to S in §3.4-3.5; R - S (sensor - sim) is the one
that adds up. Holes get their own channel because "no data" is not a depth offset: a residual cannot carry it.

The condition c is the simulator's depth as the policy reads it (``runtime.preprocess.normalise``: [0, 1] over
near_m..far_m of the model's DepthSpec, -1 where it has none): metric, since a stereo sensor's error grows
with range, which a per-frame relative scale (the DDG's) would hide.

``decode``: sim + the residual in whole mm, and 0 ("no data") where channel 1 is above 0, where the simulator
has no depth, or where the sum would not lie in front of the camera. A zero residual without holes gives back
the simulator's frame bit for bit: everything the model adds is its residual.

A residual model directory holds ``stage1/`` (eps(x_k ⊕ c, k)), and once trained ``discriminator/``
(``discriminator.py``) and ``stage2/`` (eps(x_k ⊕ c ⊕ stage I's output as a target, k); §3.4). Each stage
directory is a U-Net model directory (``model.py``) whose config records ``x0_scale`` "residual",
``residual_m``, ``residual_mu`` (absent: 0, linear) and ``io``. ``cache/`` keeps stage I's samples on training
frames, read by the discriminator's fit and stage II's.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runtime.preprocess import DepthSpec, normalise

from .graft import edge_bands, graft_edges
from .model import RESIDUAL_SCALE, ModelDirError, ddim_scheduler, load_config, model_id
from .sample import FrameError, OnnxEps, TorchEps, check_frames, ddim_reverse, frame_noise, generate_frames

TARGET_CHANNELS = 2
"""Residual and holes."""
HOLE_THRESHOLD = 0.0
"""A pixel of the hole channel above this is a hole: half way between "valid" (-1) and "hole" (+1). A stage's
config may set its own ``hole_threshold``: a few DDIM steps leave the channel blurred, and a lower threshold
gives back the sensor's hole rate (research/hole_threshold.sh). It may also set ``hole_threshold_edges``, the
threshold within the simulated frame's edge band (``graft.edge_band``): no single threshold gives both the
sensor's hole rate at edges and its rate on flat regions."""
STAGES = ("stage1", "stage2")
STAGE_SEED = 1 << 32
"""Stage k draws its noise under seed + (k - 1) * STAGE_SEED: its own, not stage I's again."""


def condition(sim_mm: np.ndarray, spec: DepthSpec) -> np.ndarray:
    """uint16 mm [N, H, W] -> c float32 [N, 1, H, W]: the policy's normalisation of the simulated depth."""
    return np.stack([normalise(d, 0.001, spec) for d in sim_mm])[:, None]


@dataclass(frozen=True)
class ResidualCode:
    """A residual in metres <-> channel 0 of the target, in [-1, 1]: clipped to +-``metres``, divided by it,
    then mu-law companded, sign(x) ln(1 + mu |x|) / ln(1 + mu) (``mu`` 0: linear). The sensor's typical
    error is a few mm in a range of 0.5 m: linear, 4 mm is 0.008, below what a sampled x0 resolves, and the
    shipped (linear) model puts 47 % of flat pixels more than 2 cm off where the sensor puts 7 %; mu 255 maps
    4 mm to 0.2 and cut that to 16 %, but lost the sensor's wrong depth at edges (31 % against 73 %) and
    FID (docs/residual.md, "Measured")."""

    metres: float = 0.5
    mu: float = 0.0

    def to_unit(self, metres: np.ndarray) -> np.ndarray:
        x = np.clip(metres / self.metres, -1.0, 1.0)
        return np.sign(x) * np.log1p(self.mu * np.abs(x)) / np.log1p(self.mu) if self.mu else x

    def to_metres(self, unit: np.ndarray) -> np.ndarray:
        u = np.clip(unit, -1.0, 1.0)
        x = np.sign(u) * np.expm1(np.abs(u) * np.log1p(self.mu)) / self.mu if self.mu else u
        return x * self.metres


def encode(sim_mm: np.ndarray, sensor_mm: np.ndarray, code: ResidualCode) -> np.ndarray:
    """Paired uint16 mm frames [N, H, W] -> the target x0 float32 [N, 2, H, W] (module docstring)."""
    both = (sim_mm > 0) & (sensor_mm > 0)
    metres = (sensor_mm.astype(np.float64) - sim_mm.astype(np.float64)) / 1000.0
    residual = np.where(both, code.to_unit(metres), 0.0)
    holes = np.where(sensor_mm == 0, 1.0, -1.0)
    return np.stack([residual, holes], axis=1).astype(np.float32)


def decode(sim_mm: np.ndarray, x0: np.ndarray, code: ResidualCode,
           holes: float | np.ndarray = HOLE_THRESHOLD) -> np.ndarray:
    """uint16 mm [N, H, W] + a sampled x0 [N, 2, H, W] -> the generated uint16 mm depth, 0 = no data (and
    wherever the hole channel is above ``holes``: one threshold, or one per pixel [N, H, W])."""
    offset = np.rint(code.to_metres(x0[:, 0].astype(np.float64)) * 1000.0).astype(np.int64)
    depth = sim_mm.astype(np.int64) + offset
    none = (x0[:, 1] > holes) | (sim_mm == 0) | (depth <= 0)
    return np.where(none, 0, np.minimum(depth, 65535)).astype(np.uint16)


def stage_condition(sim_mm: np.ndarray, spec: DepthSpec, code: ResidualCode, earlier: np.ndarray | None = None
                    ) -> np.ndarray:
    """A stage's condition [N, 1 or 3, H, W]: c, and for stage II stage I's output ``earlier`` (uint16 mm)
    encoded as a target against the simulated frames, as the paper conditions on D_res^I and S."""
    c = condition(sim_mm, spec)
    return c if earlier is None else np.concatenate([c, encode(sim_mm, earlier, code)], axis=1)


def stage_io(stage: int) -> tuple[int, int]:
    """(input, output) channels of stage ``stage``'s U-Net: x_k and its condition in, the noise of x_k out."""
    return TARGET_CHANNELS + 1 + (stage - 1) * TARGET_CHANNELS, TARGET_CHANNELS


class Stage:
    """One stage's net, DDIM schedule and recorded encoding."""

    def __init__(self, stage_dir: Path, steps: int, threads: int, backend: str, mode: str) -> None:
        cfg = load_config(stage_dir, RESIDUAL_SCALE)
        self.spec, self.code = cfg["depth_spec"], ResidualCode(cfg["residual_m"], cfg.get("residual_mu", 0.0))
        self.holes = cfg.get("hole_threshold", HOLE_THRESHOLD)
        self.edge_holes = cfg.get("hole_threshold_edges")
        self.scheduler = ddim_scheduler(cfg["unet"], steps)
        self.eps = (OnnxEps(stage_dir, threads, mode) if backend == "onnx"
                    else TorchEps(stage_dir, RESIDUAL_SCALE))

    def thresholds(self, band: np.ndarray | None) -> float | np.ndarray:
        """The hole channel's threshold: one, or per pixel [N, H, W] where the config sets one for the edge
        ``band`` (the simulated frames' ``graft.edge_bands``; needed then)."""
        if self.edge_holes is None:
            return self.holes
        return np.where(band, np.float32(self.edge_holes), np.float32(self.holes))


def stage_dirs(model_dir: str | Path, stages: int = 0) -> list[Path]:
    """The model's stage directories, in order: the first ``stages`` of them, or (0) every one it has."""
    root = Path(model_dir)
    have = [root / s for s in STAGES if (root / s).is_dir()]
    if not have or have[0].name != STAGES[0]:
        raise ModelDirError(f"{model_dir}: no stage1/ (not a residual model directory; make one with "
                            "`python -m trainer ddg residual-fit`)")
    if stages > len(have):
        raise ModelDirError(f"{model_dir}: has {len(have)} stage(s), not {stages}")
    return have[:stages or len(have)]


def residual_model_id(model_dir: str | Path) -> str:
    """Each stage's ``model_id`` and hole thresholds where its config sets them: a store's record of which
    residual model made its depth."""
    def stage_id(d: Path) -> str:
        cfg = load_config(d, RESIDUAL_SCALE)
        holes, edges = cfg.get("hole_threshold", HOLE_THRESHOLD), cfg.get("hole_threshold_edges")
        return (model_id(d) + (f"~holes{holes:g}" if holes != HOLE_THRESHOLD else "")
                + (f"~edges{edges:g}" if edges is not None else ""))
    return "+".join(stage_id(d) for d in stage_dirs(model_dir))


class ResidualGenerator:
    """Simulated uint16 mm frames [N, H, W] -> the sensor's depth as the residual diffusion makes it: stage I,
    then stage II on its output when the model has one (or ``stages`` of them); with ``edges``, kept only near
    the simulated frame's depth edges (``graft.graft_edges``).

    Each frame's noise comes from its own generator seeded by (seed, frame index), as the DDG's does, so a
    frame's output does not depend on batching or sharding."""

    def __init__(self, model_dir: str | Path, steps: int = 10, seed: int = 0, threads: int = 2,
                 backend: str = "onnx", mode: str = "split", eta: float = 0.0, stages: int = 0,
                 frames: DepthSpec | None = None, edges: bool = False) -> None:
        self.edges = edges
        self.stages = [Stage(d, steps, threads, backend, mode) for d in stage_dirs(model_dir, stages)]
        first = self.stages[0]
        self.spec, self.code, self.seed, self.eta = first.spec, first.code, seed, eta
        if any((s.spec, s.code) != (self.spec, self.code) for s in self.stages[1:]):
            raise ModelDirError(f"{model_dir}: stage2 was trained on another encoding (range or residual "
                                "code) than stage1; retrain it")
        # unlike the DDG's holes, a residual cannot be carried to another resolution: it is the depth itself
        if frames and (frames.out_height, frames.out_width) != (self.spec.out_height, self.spec.out_width):
            raise FrameError(f"{model_dir} makes {self.spec.out_height}x{self.spec.out_width} depth; frames "
                             f"at {frames.out_height}x{frames.out_width} need a residual model of their own")

    def check_frames(self, sim_mm: np.ndarray) -> None:
        """Refuse frames not at the model's resolution, before any work."""
        check_frames(sim_mm, self.spec)

    def __call__(self, sim_mm: np.ndarray, indices: np.ndarray) -> np.ndarray:
        self.check_frames(sim_mm)
        shape, out = (self.spec.out_height, self.spec.out_width), None
        # the edge band, made once for the stages' edge thresholds and the edge graft alike
        needs_band = self.edges or any(s.edge_holes is not None for s in self.stages)
        band = edge_bands(sim_mm) if needs_band else None
        for k, stage in enumerate(self.stages):
            seed = self.seed + k * STAGE_SEED
            noise = frame_noise(seed, indices, shape, channels=TARGET_CHANNELS)
            cond = stage_condition(sim_mm, self.spec, self.code, out)
            x0 = ddim_reverse(stage.eps, cond, noise, stage.scheduler, self.eta,
                              lambda j, s=seed: frame_noise(s, indices, shape, j, TARGET_CHANNELS))
            out = decode(sim_mm, x0, self.code, stage.thresholds(band))
        return graft_edges(sim_mm, out, band) if self.edges else out


def stage1_outputs(model_dir: str | Path, sim_mm: np.ndarray, steps: int, seed: int = 0, threads: int = 2,
                   batch: int = 16) -> np.ndarray:
    """Stage I's output on ``sim_mm`` (frame i seeded by its index i), kept in the model's ``cache/`` under
    the model's weights, the settings and the frames: the discriminator's fit and stage II's make it once."""
    key = hashlib.sha256(f"{model_id(stage_dirs(model_dir, 1)[0])} {steps} {seed}".encode()
                         + sim_mm.tobytes()).hexdigest()[:16]
    cached = Path(model_dir) / "cache" / f"stage1_{key}.npy"
    if cached.is_file():
        return np.load(cached)
    gen = ResidualGenerator(model_dir, steps=steps, seed=seed, threads=threads, stages=1)
    out = generate_frames(gen, sim_mm, "stage I on the frames", batch)
    cached.parent.mkdir(parents=True, exist_ok=True)
    with open(cached.with_suffix(".tmp"), "wb") as f:
        np.save(f, out)
    os.replace(cached.with_suffix(".tmp"), cached)  # a kill mid-save never leaves a broken cache
    return out
