"""Student checkpoints: one ``torch.save`` file of plain tensors and JSON strings (loadable with
``weights_only=True``; no pickled objects), holding model, EMA, optimiser, step and metadata."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from runtime.preprocess import DepthSpec
from trainer.student.config import StudentConfig
from trainer.student.model import build_policy

FORMAT = "diffudepgrasp.student-ckpt/1"


class CheckpointError(ValueError):
    """A file that is not a student checkpoint of a known format."""


@dataclass(frozen=True)
class TrainingInfo:
    """What the policy file's metadata needs to know about the data the student was trained on."""

    depth_spec: DepthSpec = field(default_factory=DepthSpec)
    action_scale: float = 0.05
    """s of paper eq. 1: radians per unit of the 7 joint actions stored in the demos."""
    control_rate_hz: float = 10.0
    trained: bool = False
    data: dict[str, Any] = field(default_factory=dict)
    """Fingerprint of the demos, depth source, training command."""

    def to_json(self) -> str:
        return json.dumps({**asdict(self), "depth_spec": self.depth_spec.to_dict()}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainingInfo:
        d = json.loads(text)
        return cls(**{**d, "depth_spec": DepthSpec.from_dict(d["depth_spec"])})


@dataclass
class Checkpoint:
    config: StudentConfig
    info: TrainingInfo
    ema: dict[str, torch.Tensor]
    """Weights used for inference and export (EMA of ``model``)."""
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any] | None = None
    step: int = 0
    losses: list[float] = field(default_factory=list)

    def policy(self) -> nn.Module:
        """The inference network (EMA weights), in eval mode."""
        net = build_policy(self.config)
        net.load_state_dict(self.ema)
        return net.eval()


def save(path: Path, ckpt: Checkpoint) -> None:
    """Write atomically so an interrupted run never leaves a truncated checkpoint behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save({"format": FORMAT, "config": ckpt.config.to_json(), "info": ckpt.info.to_json(),
                "ema": ckpt.ema, "model": ckpt.model, "optimizer": ckpt.optimizer, "step": ckpt.step,
                "losses": torch.tensor(ckpt.losses, dtype=torch.float32)}, tmp)
    tmp.replace(path)


def load(path: Path) -> Checkpoint:
    try:
        d = torch.load(Path(path), map_location="cpu", weights_only=True)
    except OSError as exc:
        raise CheckpointError(f"cannot read student checkpoint {path}: {exc}") from None
    except Exception as exc:  # on a file that is not its zip, torch raises pickle, index or runtime errors
        raise CheckpointError(f"{path} is not a student checkpoint (torch.load: {type(exc).__name__})") \
            from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a student checkpoint (expected format {FORMAT!r})")
    return Checkpoint(StudentConfig.from_json(d["config"]), TrainingInfo.from_json(d["info"]), d["ema"],
                      d["model"], d["optimizer"], int(d["step"]), d["losses"].tolist())


def fresh(config: StudentConfig, info: TrainingInfo, seed: int = 0) -> Checkpoint:
    """A freshly initialised student with identity normalisation (the untrained fixture)."""
    torch.manual_seed(seed)
    state = build_policy(config).state_dict()
    return Checkpoint(config, info, ema={k: v.clone() for k, v in state.items()}, model=state)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
