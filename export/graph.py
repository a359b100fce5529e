"""Student checkpoint -> one ONNX graph: encoder once, K DDIM updates unrolled, un-normalisation inside."""

from __future__ import annotations

import io
import os
import warnings
from pathlib import Path

import onnx
import torch
from torch import nn

from export import reference
from export.reference import example_feeds
from runtime.metadata import METADATA_KEY, PolicyMetadata
from trainer.student.checkpoint import Checkpoint, sha256
from trainer.student.ddim import ddim_plan, denoise

INPUT_NAMES = ("depth", "state", "noise")
OUTPUT_NAMES = ("actions",)
OPSET = 18


class UnrolledPolicy(nn.Module):
    """(depth, state, noise) -> actions in robot units; the DDIM timesteps are Python constants, so tracing
    unrolls the loop and bakes each step's coefficients into the graph."""

    def __init__(self, policy: nn.Module, ddim_steps: int, action_scale: float,
                 spacing: str = "leading") -> None:
        super().__init__()
        self.policy = policy
        self.plan = ddim_plan(policy.config.train_timesteps, ddim_steps, spacing)
        joint_scale = torch.ones(policy.config.action_dim)
        joint_scale[:7] = action_scale  # paper eq. 1: the 7 joint deltas in radians; the gripper stays as is
        self.register_buffer("robot_scale", joint_scale)

    def forward(self, depth: torch.Tensor, state: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        obs = self.policy.encode(depth, state)
        x = denoise(self.policy, obs, noise, self.plan, self.policy.config.prediction)
        return self.policy.action_norm.unnormalise(x) * self.robot_scale


def portable(value):
    """``value`` (a string, or a dict or list holding strings at any depth) with paths under the working
    directory made relative and those under the home folder written from ``~``: a shipped file names no
    machine's absolute paths (a composed student's record nests its two parts' commands)."""
    if isinstance(value, dict):
        return {k: portable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [portable(v) for v in value]
    if not isinstance(value, str):
        return value
    for root, short in ((Path.cwd(), ""), (Path.home(), "~" + os.sep)):
        value = value.replace(f"{root}{os.sep}", short)
    return value


def policy_metadata(ckpt: Checkpoint, ddim_steps: int, ckpt_path: Path,
                    spacing: str = "leading") -> PolicyMetadata:
    cfg, info, net = ckpt.config, ckpt.info, ckpt.policy()
    return PolicyMetadata(
        preprocess=info.depth_spec, control_rate_hz=info.control_rate_hz, action_scale=info.action_scale,
        obs_horizon=cfg.obs_horizon, action_horizon=cfg.action_horizon, exec_horizon=cfg.exec_horizon,
        ddim_steps=ddim_steps, ddim_spacing=spacing, state_dim=cfg.state_dim, action_dim=cfg.action_dim,
        normalisation={"state": net.state_norm.summary(), "action": net.action_norm.summary(),
                       "action_units": "env [-1, 1]; joints x action_scale in the graph output"},
        training_data={**portable(info.data),
                       "checkpoint": portable(str(Path(ckpt_path).resolve())),
                       "checkpoint_sha256": sha256(ckpt_path), "train_step": ckpt.step,
                       "student_config": cfg.to_json()},
        trained=info.trained)


def build_model(ckpt: Checkpoint, ckpt_path: Path, ddim_steps: int,
                spacing: str = "leading") -> tuple[onnx.ModelProto, PolicyMetadata]:
    """Trace the unrolled policy to ONNX (TorchScript exporter, one file, static shapes); attach metadata and
    the torch reference actions ``export.check`` compares against where the checkpoint is not at hand."""
    meta = policy_metadata(ckpt, ddim_steps, ckpt_path, spacing)
    policy = ckpt.policy()
    model = trace(policy, meta)
    set_metadata(model, meta, reference.record(policy, meta))
    onnx.checker.check_model(model, full_check=True)
    return model, meta


def trace(policy: nn.Module, meta: PolicyMetadata) -> onnx.ModelProto:
    """The unrolled graph of ``policy`` for the DDIM plan and action scale ``meta`` names; no metadata."""
    module = UnrolledPolicy(policy, meta.ddim_steps, meta.action_scale, meta.ddim_spacing).eval()
    buf = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python constants are the point here
        example = tuple(torch.from_numpy(v) for v in example_feeds(meta).values())
        torch.onnx.export(module, example, buf, input_names=list(INPUT_NAMES),
                          output_names=list(OUTPUT_NAMES), opset_version=OPSET, dynamo=False)
    return onnx.load_from_string(buf.getvalue())


def set_metadata(model: onnx.ModelProto, meta: PolicyMetadata, recorded_reference: str) -> None:
    del model.metadata_props[:]
    for key, value in ((METADATA_KEY, meta.to_json()), (reference.REFERENCE_KEY, recorded_reference)):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value


def read_metadata(model: onnx.ModelProto) -> PolicyMetadata:
    props = {p.key: p.value for p in model.metadata_props}
    return PolicyMetadata.from_json(props.get(METADATA_KEY, "{}"))
