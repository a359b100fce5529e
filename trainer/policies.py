"""What ``collect`` and ``evaluate`` run in the simulated world: ``make_policy(spec)``.

A policy has ``reset(env_info)`` (the dict ``GraspEnv.reset`` returns) and ``act(obs) -> np.ndarray(8)``
(env action: 7 joint deltas in [-1, 1] before the scale s, gripper -1/+1). ``obs`` is an ``Observation``
holding all three views of the world, so a privileged teacher and a depth student share one loop.

Specs: ``scripted`` | ``reactive[:BIAS_CM]`` | ``ppo:CHECKPOINT`` | ``student:ONNX`` |
``oracle:CKPT[@BIAS_CM]`` (the action head on the true object facts: ``trainer.student.oracle_policy``). Other
engineers' modules provide ``trainer.teacher.ppo.load(path)`` and ``trainer.student.onnx_policy.load(path)``;
they are imported only when asked for. Add a kind by adding one entry to ``LOADERS``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np

from runtime.preprocess import DepthSpec


class PolicyError(ValueError):
    """A policy spec that names no known kind, or whose loader module is missing."""


@dataclass(frozen=True)
class Observation:
    privileged: np.ndarray
    """float32 [40], layout in ``trainer.sim.env``."""
    depth_frame: np.ndarray | Callable[[], np.ndarray | None] | None
    """The depth frame, or a function that makes it on first use of ``depth``: sensor models are costly and
    a student reads only the frames its next inference stacks. None when the env does not render depth."""
    state: np.ndarray
    """float32 [8]: 7 joint angles (rad) + gripper opening (m)."""

    @cached_property
    def depth(self) -> np.ndarray | None:
        """uint16 [H, W] mm at the policy resolution (0 = no data), after the sensor model."""
        return self.depth_frame() if callable(self.depth_frame) else self.depth_frame


class Policy(Protocol):
    def reset(self, env_info: dict) -> None: ...

    def act(self, obs: Observation) -> np.ndarray: ...


def _scripted(_: str) -> Policy:
    from trainer.teacher.scripted import ScriptedExpert

    return ScriptedExpert()


def _reactive(bias: str) -> Policy:
    """The scripted planner with its phase read off each observation (no memory a student cannot see);
    ``reactive:B``: the same reading the object B cm off (``trainer.teacher.scripted.aim_bias``), the grasp's
    own tolerance."""
    from trainer.teacher.scripted import BiasedExpert, ReactiveExpert

    bias_m = aim_bias_m(f"reactive:{bias}", bias)
    return BiasedExpert(bias_m) if bias_m else ReactiveExpert()


def aim_bias_m(spec: str, bias: str) -> float:
    """A spec's centimetres after ``@`` or ``:``, in metres (none: 0); refused in one line naming the spec."""
    try:
        return float(bias) / 100 if bias else 0.0
    except ValueError:
        raise PolicyError(f"{spec}: the bias is centimetres, e.g. reactive:1.0 or oracle:CKPT@0.5") from None


def _lazy(module: str, kind: str) -> Callable[[str], Policy]:
    def load(path: str) -> Policy:
        if not path:
            raise PolicyError(f"policy spec {kind}: needs a path, e.g. {kind}:PATH")
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            raise PolicyError(f"policy kind {kind!r} needs {module}, not available ({exc})") from None
        return mod.load(path)

    return load


LOADERS: dict[str, Callable[[str], Policy]] = {
    "scripted": _scripted,
    "reactive": _reactive,
    "ppo": _lazy("trainer.teacher.ppo", "ppo"),
    "student": _lazy("trainer.student.onnx_policy", "student"),
    "oracle": _lazy("trainer.student.oracle_policy", "oracle"),
}

NEEDS_DEPTH = {"scripted": False, "reactive": False, "ppo": False, "student": True, "oracle": False}
"""Whether the env must render depth for this kind (privileged teachers run much faster without)."""


def parse(spec: str) -> tuple[str, str]:
    kind, _, arg = spec.partition(":")
    if kind not in LOADERS:
        raise PolicyError(f"unknown policy {spec!r}; expected one of: "
                          "scripted, reactive[:BIAS_CM], ppo:CKPT, student:ONNX, oracle:CKPT[@BIAS_CM]")
    return kind, arg


def depth_spec(spec: str) -> DepthSpec:
    """The crop and resolution the policy reads: a student file's own (its metadata), for the env to render;
    the default for privileged teachers, which read none."""
    kind, arg = parse(spec)
    if not NEEDS_DEPTH[kind]:
        return DepthSpec()
    from runtime.policy import Policy as RuntimePolicy
    from runtime.policy import PolicyError as FileError

    try:
        return RuntimePolicy(arg).metadata.preprocess
    except FileError as exc:
        raise PolicyError(str(exc)) from None


def make_policy(spec: str) -> Policy:
    kind, arg = parse(spec)
    return LOADERS[kind](arg)
