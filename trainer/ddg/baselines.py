"""Depth sources, one registry for every place that picks one (``trainer evaluate --sensor``, the student's
loader, the realism metrics). Each source is a plain function: uint16 mm policy-resolution depth [H, W] + a
numpy Generator -> uint16 mm depth [H, W] (0 = hole).

- ``gt``: the clean depth, unchanged.
- ``randnoise``: procedural noise in the style of DextrAH-G's depth augmentation: depth-dependent Gaussian
  noise, random pixel dropout, holes along depth edges and a few random blobs.
- ``inpaint``: OpenCV Navier-Stokes inpainting of the holes (DexGraspNet 2.0's deploy-time restoration
  baseline, the runtime's ``--restore inpaint``; applied to real depth).
- ``ddg_nograft`` / ``ddg``: the Diffusion Depth Generator without / with Noise Grafting (needs a model).
- ``residual``: Stable-Sim2Real's residual depth diffusion (``residual.py``; needs a model made with
  ``ddg residual-fit``): the simulated frame plus a generated residual, the sensor's holes included.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from runtime.preprocess import restore_holes

from .graft import depth_steps

DepthSource = Callable[[np.ndarray, np.random.Generator], np.ndarray]

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "ddg"
DEFAULT_RESIDUAL = DEFAULT_MODEL.parent / "residual"


class UnknownSourceError(ValueError):
    """A depth-source name that is not in the registry."""


@dataclass(frozen=True)
class RandNoiseConfig:
    sigma_mm: float = 0.5
    """Gaussian noise floor (mm)."""
    sigma_quad_mm: float = 1.5
    """Extra noise at 1 m; stereo depth error grows with depth squared."""
    dropout_max: float = 0.02
    """Per-frame pixel dropout probability, drawn from U(0, dropout_max)."""
    edge_grad_mm: float = 20.0
    """A depth jump above this (mm per pixel) counts as an edge."""
    edge_drop: float = 0.5
    """Probability that an edge pixel becomes a hole."""
    blobs_mean: float = 2.0
    """Mean number (Poisson) of elliptical holes of 2-6 px radius."""


def gt(depth_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return depth_mm.copy()


def randnoise(depth_mm: np.ndarray, rng: np.random.Generator, cfg: RandNoiseConfig = RandNoiseConfig()
              ) -> np.ndarray:
    z = depth_mm.astype(np.float32)
    sigma = cfg.sigma_mm + cfg.sigma_quad_mm * (z / 1000.0) ** 2
    noisy = np.clip(np.rint(z + rng.standard_normal(z.shape, np.float32) * sigma), 1, 65535)
    holes = (depth_mm == 0) | (rng.random(z.shape) < rng.uniform(0, cfg.dropout_max))
    holes |= (depth_steps(depth_mm, cfg.edge_grad_mm) & (rng.random(z.shape) < cfg.edge_drop))
    for _ in range(rng.poisson(cfg.blobs_mean)):
        centre = (int(rng.integers(0, z.shape[1])), int(rng.integers(0, z.shape[0])))
        axes = (int(rng.integers(2, 7)), int(rng.integers(2, 7)))
        blob = np.zeros(z.shape, np.uint8)
        cv2.ellipse(blob, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        holes |= blob.astype(bool)
    return np.where(holes, 0, noisy).astype(np.uint16)


def inpaint(depth_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return restore_holes(depth_mm, "inpaint").copy()


class DDGSource:
    """One frame at a time through the generator; the frame's noise comes from ``rng``.

    A frame at another resolution than the model's (a finer student's) is taken to be of the model's crop, the
    default every policy uses, and goes through a generator told so (``Generator(frames=)``): the holes come
    back at the frame's resolution and the frame keeps its own geometry."""

    def __init__(self, model: str | Path = DEFAULT_MODEL, steps: int = 10, grafted: bool = True) -> None:
        from .sample import Generator

        self.generator, self.grafted = Generator(model, steps=steps), grafted
        self.model, self.steps, self.finer = model, steps, {}

    def __call__(self, depth_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        index = np.array([rng.integers(0, 2**62)])
        ddg, nograft = self._generator(depth_mm)(depth_mm[None], index)
        return (ddg if self.grafted else nograft)[0]

    def _generator(self, depth_mm: np.ndarray):
        """The generator for this frame's resolution, made on first sight of it; a frame of another rank goes
        to the model's own, which refuses it by name."""
        from .sample import Generator

        spec, shape = self.generator.spec, depth_mm.shape
        if depth_mm.ndim != 2 or shape == (spec.out_height, spec.out_width):
            return self.generator
        if shape not in self.finer:
            frames = replace(spec, out_height=shape[0], out_width=shape[1])
            self.finer[shape] = Generator(self.model, steps=self.steps, frames=frames)
        return self.finer[shape]


class ResidualSource:
    """One frame at a time through the residual diffusion (at the model's resolution); the frame's noise
    comes from ``rng``."""

    def __init__(self, model: str | Path = DEFAULT_RESIDUAL, steps: int = 10, edges: bool = False) -> None:
        from .residual import ResidualGenerator

        self.generator = ResidualGenerator(model, steps=steps, edges=edges)

    def __call__(self, depth_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return self.generator(depth_mm[None], np.array([rng.integers(0, 2**62)]))[0]


SOURCES: dict[str, Callable[..., DepthSource]] = {
    "gt": lambda **_: gt,
    "randnoise": lambda **_: randnoise,
    "inpaint": lambda **_: inpaint,
    "ddg_nograft": lambda model=DEFAULT_MODEL, steps=10: DDGSource(model, steps, grafted=False),
    "ddg": lambda model=DEFAULT_MODEL, steps=10: DDGSource(model, steps, grafted=True),
    "residual": lambda model=DEFAULT_RESIDUAL, steps=10: ResidualSource(model, steps),
    "residual_edges": lambda model=DEFAULT_RESIDUAL, steps=10: ResidualSource(model, steps, edges=True),
}


def get_source(name: str, model: str | Path | None = None, steps: int = 10) -> DepthSource:
    """The depth source called ``name``; ``model`` (default: the source's own) and ``steps`` matter for the
    generated sources only."""
    if name not in SOURCES:
        raise UnknownSourceError(f"unknown depth source {name!r}; choose one of {sorted(SOURCES)}")
    return SOURCES[name](**({"model": model} if model else {}), steps=steps)


class SeededSource:
    """A depth source as an evaluation sensor (``trainer.sim.sensors.SeededSensor``): its draws come from a
    generator that each episode restarts from its seed."""

    STREAM = 0x5E45
    """Mixed into the episode's seed, so the sensor's draws are not the policy's."""

    def __init__(self, source: Callable[[np.ndarray, np.random.Generator], np.ndarray]) -> None:
        self.source, self.rng = source, np.random.default_rng(0)

    def reseed(self, seed: int) -> None:
        self.rng = np.random.default_rng([seed, self.STREAM])

    def __call__(self, depth: np.ndarray) -> np.ndarray:
        return self.source(depth, self.rng)


def sensor_factory(name: str) -> Callable[[str], SeededSource]:
    """Adapter to ``trainer.sim.sensors``' factory shape. ARG is ``[model=DIR][,steps=K]`` (defaults: the
    source's model, 10 DDIM steps); a bare ARG is the model dir."""
    def factory(arg: str) -> SeededSource:
        return SeededSource(get_source(name, **parse_sensor_arg(name, arg)))
    return factory


def parse_sensor_arg(name: str, arg: str) -> dict:
    """``model=DIR,steps=K`` (either optional; a bare value is the model) -> get_source's keywords."""
    options: dict = {}
    for item in filter(None, arg.split(",")):
        key, _, value = item.partition("=") if "=" in item else ("model", "", item)
        if key == "model":
            options["model"] = value
        elif key == "steps" and value.isdigit() and int(value) > 0:
            options["steps"] = int(value)
        else:
            raise UnknownSourceError(f"sensor {name!r}: cannot read {item!r}; "
                                     "expected model=DIR or steps=K (K >= 1)")
    return options


def _register() -> None:
    from trainer.sim import sensors

    for name in SOURCES:
        if name != "gt":  # "clean" is the simulator's own name for it
            sensors.register(name, sensor_factory(name))


_register()
