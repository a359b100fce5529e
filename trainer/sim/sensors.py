"""Sensor models for evaluation: a sensor maps the clean uint16 depth frame (policy resolution, mm) to what
the policy sees, e.g. with simulated holes and noise. ``--sensor NAME[:ARG]`` picks one.

A *scene sensor* (``SceneSensor``: ``stereo``) cannot work from clean depth: it gets the world, renders
the full 848x480 stream itself, and the rollout crops it with ``runtime.preprocess`` as the runtime does.

Add a sensor with ``register("name", factory)`` from its module and list that module in ``PLUGINS`` (imported
on first use), or name it inline as ``package.module:factory[:ARG]``. A factory takes the ARG string ('' when
absent) and returns the callable; it runs inside each worker process, so it may load models.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class SceneSensor(Protocol):
    def reset(self, world, seed: int) -> None:
        """Start an episode in ``world`` (``hil_sim.world.World``); per-episode draws come from ``seed``."""

    def stream(self, world) -> np.ndarray:
        """uint16 depth at the stream resolution, sensor units (mm), 0 = no data."""


@runtime_checkable
class SeededSensor(Protocol):
    """A sensor that maps clean depth with random draws, restarted from each episode's seed."""

    def reseed(self, seed: int) -> None: ...

    def __call__(self, depth: np.ndarray) -> np.ndarray: ...


Sensor = Callable[[np.ndarray], np.ndarray] | SceneSensor
Factory = Callable[[str], Sensor]


class SensorError(ValueError):
    """A sensor spec that names no registered sensor or importable factory."""


def clean(depth: np.ndarray) -> np.ndarray:
    """The simulator's exact depth (what the teacher demos store)."""
    return depth


def stereo(arg: str) -> SceneSensor:
    """The active-stereo D455 of ``hil_sim.stereo``; ARG: a parameters file (default: the fitted one)."""
    from hil_sim.stereo import StereoParams, StereoSensor

    return StereoSensor(StereoParams.load(arg or None))


SENSORS: dict[str, Factory] = {"clean": lambda _arg: clean, "stereo": stereo}
SCENE_SENSORS = frozenset({"stereo"})
"""Registered names whose sensor is a ``SceneSensor``: the env need not render clean depth for them."""
PLUGINS: tuple[str, ...] = ("trainer.ddg.baselines",)
"""Modules that call ``register`` when imported (the DDG and noise baselines add theirs here)."""


def register(name: str, factory: Factory) -> None:
    SENSORS[name] = factory


def reads_clean_depth(spec: str) -> bool:
    """Whether the sensor ``spec`` maps the env's clean depth (False for a registered scene sensor)."""
    return spec.partition(":")[0] not in SCENE_SENSORS


def make_sensor(spec: str) -> Sensor:
    for module in PLUGINS:
        importlib.import_module(module)
    name, _, arg = spec.partition(":")
    if name in SENSORS:
        return SENSORS[name](arg)
    if "." in name and ":" in spec:
        module, _, rest = spec.partition(":")
        func, _, arg = rest.partition(":")
        try:
            return getattr(importlib.import_module(module), func)(arg)
        except (ImportError, AttributeError) as exc:
            raise SensorError(f"sensor {spec!r}: cannot load {module}:{func} ({exc})") from None
    raise SensorError(f"unknown sensor {spec!r}; known: {', '.join(sorted(SENSORS))} "
                      f"(or package.module:factory[:ARG])")
