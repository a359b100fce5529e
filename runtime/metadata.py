"""The policy file's self-description (contract): one JSON document in ``student.onnx``'s metadata_props.

Export writes it, the runtime reads it and refuses a file whose schema it does not know. Normalisation is
applied inside the graph; its statistics are repeated here for audit.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

from runtime.franka_driver.kinematics import HIL_SIM_Q_OFFSET
from runtime.preprocess import DepthSpec

SCHEMA = "diffudepgrasp.policy/1"
METADATA_KEY = "diffudepgrasp"  # the metadata_props key that holds the JSON
DDIM_SPACINGS = ("leading", "trailing")
"""Where K inference steps sit among the training steps (diffusers' ``timestep_spacing``): ``leading`` starts
at T - T/K (75 of 100 at K = 4), reading the start noise as a sample already 37 % signal; ``trailing`` at the
last step (pure noise, as the start noise is; Lin et al. 2024, "Common diffusion noise schedules and sample
steps are flawed")."""


class MetadataError(ValueError):
    """A policy file whose metadata is missing, of an unknown schema, or inconsistent."""


def _drop_retired(d: dict[str, Any]) -> None:
    """Files exported from 2026-11-25 until ``--first-frame`` was retired carry ``first_frame``: false means
    what every other file does; true, a depth input led by the episode's first frame, which the runtime no
    longer stacks."""
    if d.pop("first_frame", False) is not False:
        raise MetadataError("first_frame students are no longer supported (their depth input leads with the "
                            "episode's first frame); use a student that reads the last frames alone")


def _check_schema(schema: Any) -> None:
    if schema != SCHEMA:
        raise MetadataError(f"policy metadata schema {schema!r} is not supported (expected {SCHEMA!r}); "
                            "re-export the student with this version")


@dataclass(frozen=True)
class PolicyMetadata:
    preprocess: DepthSpec
    """How raw depth becomes the ``depth`` input; the runtime applies exactly this."""
    control_rate_hz: float = 10.0
    action_scale: float = 0.05
    """``s`` of paper eq. 1, already applied to the 7 joint deltas the graph outputs (radians)."""
    obs_horizon: int = 3
    """Depth frames stacked in the ``depth`` input, oldest first."""
    action_horizon: int = 16
    """Ha: actions predicted per inference."""
    exec_horizon: int = 8
    """Actions executed from each chunk before the next inference result replaces them."""
    ddim_steps: int = 4
    ddim_spacing: str = "leading"
    """``DDIM_SPACINGS``; files from before this field were all ``leading``."""
    state_dim: int = 8
    action_dim: int = 8
    normalisation: dict[str, Any] = field(default_factory=dict)
    """Statistics used inside the graph (e.g. state/action min and max), for audit."""
    training_data: dict[str, Any] = field(default_factory=dict)
    """Fingerprint of the demos, depth source (gt|randnoise|ddg|...), training command."""
    joint_offset_rad: tuple[float, ...] = tuple(-x for x in HIL_SIM_Q_OFFSET)
    """Added to the joint angles a robot reports (libfranka's convention) to get those the policy was trained
    on: hil_sim's Panda model's, whose joint 6 reads pi/2 less (``preprocess.policy_state``)."""
    trained: bool = False
    """False for the untrained fixtures that tests build; the runtime warns loudly when running one."""
    schema: str = SCHEMA

    def __post_init__(self) -> None:
        _check_schema(self.schema)
        if not (0 < self.exec_horizon <= self.action_horizon):
            raise MetadataError(f"exec_horizon {self.exec_horizon} must be in 1..action_horizon "
                                f"({self.action_horizon})")
        for name in ("control_rate_hz", "action_scale"):
            if not getattr(self, name) > 0:
                raise MetadataError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("obs_horizon", "ddim_steps", "state_dim", "action_dim"):
            if not getattr(self, name) >= 1:
                raise MetadataError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.ddim_spacing not in DDIM_SPACINGS:
            raise MetadataError(f"ddim_spacing must be one of {DDIM_SPACINGS}, got {self.ddim_spacing!r}")
        if not all(math.isfinite(x) for x in self.joint_offset_rad):
            raise MetadataError(f"joint_offset_rad must be finite angles, got {self.joint_offset_rad}")

    def input_shapes(self) -> dict[str, list[int]]:
        """Static graph input shapes, batch 1."""
        spec = self.preprocess
        return {"depth": [1, self.obs_horizon, spec.out_height, spec.out_width],
                "state": [1, self.state_dim], "noise": [1, self.action_horizon, self.action_dim]}

    def to_json(self) -> str:
        return json.dumps({**asdict(self), "preprocess": self.preprocess.to_dict()}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> PolicyMetadata:
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise MetadataError(f"policy metadata is not valid JSON: {exc}") from None
        if not isinstance(d, dict):
            raise MetadataError("policy metadata must be a JSON object")
        _check_schema(d.get("schema"))  # first: another schema's fields are no error of this one
        _drop_retired(d)
        if unknown := set(d) - set(cls.__dataclass_fields__):
            raise MetadataError(f"unknown policy metadata fields {sorted(unknown)}")
        try:
            return cls(**{**d, "preprocess": DepthSpec.from_dict(d.get("preprocess", {})),
                          "joint_offset_rad": tuple(d.get("joint_offset_rad", cls.joint_offset_rad))})
        except (TypeError, ValueError) as exc:
            raise MetadataError(f"invalid policy metadata: {exc}") from None
