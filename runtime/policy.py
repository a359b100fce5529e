"""The student policy: ``student.onnx`` in onnxruntime (CPU), checked against its own metadata at load time.

A missing or corrupt file, an unknown metadata schema or graph inputs/outputs that disagree with the metadata
are a ``PolicyError`` naming the file and the problem, raised at load rather than at the first tick.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort

from runtime.metadata import METADATA_KEY, MetadataError, PolicyMetadata
from runtime.protocol import DOF


class PolicyError(RuntimeError):
    """A policy file or output the runtime refuses; the text names the file and the problem."""


class NanActionError(PolicyError):
    """The policy produced non-finite actions; the loop holds the arm (status ``nan_action``)."""


@dataclass(frozen=True)
class SessionConfig:
    """onnxruntime CPU settings, measured on the 2-core target with camera and robot traffic running
    (docs/runtime.md): one intra-op thread, not spinning, leaves the second core to the camera and driver."""

    intra_op_threads: int = 1
    allow_spinning: bool = False  # let idle intra-op threads busy-wait for work

    def options(self) -> ort.SessionOptions:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.inter_op_num_threads = self.intra_op_threads, 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if self.allow_spinning else "0")
        opts.add_session_config_entry("session.inter_op.allow_spinning", "0")
        opts.log_severity_level = 3
        return opts


class Policy:
    """Runs the student: a depth stack + joint state -> an action chunk of joint deltas and gripper."""

    def __init__(self, path: str | Path, config: SessionConfig = SessionConfig(), seed: int = 0) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise PolicyError(f"{path}: no such policy file")
        try:
            self.session = ort.InferenceSession(str(path), config.options(),
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own untyped pybind errors for bad files
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise PolicyError(f"{path}: not a loadable ONNX model ({reason:.200})") from None
        self.metadata = _read_metadata(self.path, self.session)
        _check_signature(self.path, self.session, self.metadata)
        self.reseed(seed)
        if not self.metadata.trained:
            print(f"runtime: WARNING {self.path} is an UNTRAINED policy (metadata trained=false); "
                  "it will not grasp anything", file=sys.stderr)

    def reseed(self, seed: int) -> None:
        """Restart the start noise's generator: the same inputs then give the same actions (the evaluator
        reseeds per episode, so an episode does not depend on those before it)."""
        self._rng = np.random.default_rng(seed)

    @property
    def noise_shape(self) -> tuple[int, int, int]:
        return (1, self.metadata.action_horizon, self.metadata.action_dim)

    def __call__(self, depth: np.ndarray, state: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        """depth float32 [obs_horizon, H, W] (oldest first), state float32 [8] -> actions float32 [Ha, 8].
        The start noise is drawn from the policy's own generator unless given (paired offline comparisons)."""
        if noise is None:
            noise = self._rng.standard_normal(self.noise_shape, dtype=np.float32)
        feeds = {"depth": np.ascontiguousarray(depth, dtype=np.float32)[None],
                 "state": np.ascontiguousarray(state, dtype=np.float32)[None], "noise": noise}
        actions = self.session.run(["actions"], feeds)[0][0]
        if not np.isfinite(actions).all():
            raise NanActionError(f"{self.path.name} produced {int((~np.isfinite(actions)).sum())} non-finite "
                                 "action values")
        return actions

    def warmup(self, runs: int = 5) -> list[float]:
        """Run on a blank input ``runs`` times (first-call allocations); return each duration in seconds."""
        shapes = self.metadata.input_shapes()
        depth, state = np.zeros(shapes["depth"][1:], np.float32), np.zeros(shapes["state"][1:], np.float32)
        durations = []
        for _ in range(runs):
            t = time.perf_counter()
            self(depth, state)
            durations.append(time.perf_counter() - t)
        return durations


def _read_metadata(path: Path, session: ort.InferenceSession) -> PolicyMetadata:
    props = session.get_modelmeta().custom_metadata_map
    if METADATA_KEY not in props:
        raise PolicyError(f"{path}: no {METADATA_KEY!r} entry in metadata_props; "
                          "export the student with `python -m export`")
    try:
        meta = PolicyMetadata.from_json(props[METADATA_KEY])
    except MetadataError as exc:
        raise PolicyError(f"{path}: {exc}") from None
    for name in ("state_dim", "action_dim"):
        if getattr(meta, name) != DOF + 1:
            raise PolicyError(f"{path}: metadata {name}={getattr(meta, name)}, the Panda runtime needs "
                              f"{DOF + 1} (7 joints + gripper)")
    if len(meta.joint_offset_rad) != DOF:
        raise PolicyError(f"{path}: metadata joint_offset_rad has {len(meta.joint_offset_rad)} angles, the "
                          f"Panda has {DOF} joints")
    return meta


def _check_signature(path: Path, session: ort.InferenceSession, meta: PolicyMetadata) -> None:
    """Graph inputs/outputs must be float32 with the shapes the metadata promises (batch may be symbolic)."""
    want = {**meta.input_shapes(), "actions": [1, meta.action_horizon, meta.action_dim]}
    inputs = {i.name: i for i in session.get_inputs()}
    outputs = {o.name: o for o in session.get_outputs()}
    if set(inputs) != {"depth", "state", "noise"}:
        raise PolicyError(f"{path}: graph inputs {sorted(inputs)}, expected ['depth', 'noise', 'state']")
    if "actions" not in outputs:
        raise PolicyError(f"{path}: graph has no 'actions' output (outputs: {sorted(outputs)})")
    for name, arg in {**inputs, "actions": outputs["actions"]}.items():
        if arg.type != "tensor(float)":
            raise PolicyError(f"{path}: {name} is {arg.type}, expected tensor(float)")
        batch, *rest = arg.shape or [None]
        if (isinstance(batch, int) and batch != 1) or rest != want[name][1:]:  # batch may be symbolic
            raise PolicyError(f"{path}: {name} has shape {arg.shape}, metadata implies {want[name]}")
