"""Sensor models for evaluation: a sensor maps the clean uint16 depth frame (policy resolution, mm) to what
the policy sees, e.g. with simulated holes and noise. ``--sensor NAME[:ARG]`` picks one.

Add a sensor with ``register("name", factory)`` from its module and list that module in ``PLUGINS`` (imported
on first use), or name it inline as ``package.module:factory[:ARG]``. A factory takes the ARG string ('' when
absent) and returns the callable; it runs inside each worker process, so it may load models.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

Sensor = Callable[[np.ndarray], np.ndarray]
Factory = Callable[[str], Sensor]


class SensorError(ValueError):
    """A sensor spec that names no registered sensor or importable factory."""


def clean(depth: np.ndarray) -> np.ndarray:
    """The simulator's exact depth (what the teacher demos store)."""
    return depth


SENSORS: dict[str, Factory] = {"clean": lambda _arg: clean}
PLUGINS: tuple[str, ...] = ("trainer.ddg.baselines",)
"""Modules that call ``register`` when imported (the DDG and noise baselines add theirs here)."""


def register(name: str, factory: Factory) -> None:
    SENSORS[name] = factory


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
