"""The conditional U-Net (eps_theta(d_k ⊕ c, k), paper eq. 8), its noise schedule and the model directory.

A model directory holds ``config.json`` (this module's configs + the DepthSpec), ``unet.safetensors`` (EMA
weights) and ``unet.onnx`` (the same network for onnxruntime). Nothing is pickled. The DDG's net reads 2
channels (d_k, c) and writes 1; the residual diffusion (``residual.py``) builds the same net with other
channel counts, which its config records as ``io``, and its own ``x0_scale``, so neither kind of model is
loaded as the other.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from diffusers import DDIMScheduler, DDPMScheduler, UNet2DModel

from runtime.preprocess import DepthSpec

from .data import POLICY_SPEC
from .graft import X0_SCALE


class ModelDirError(ValueError):
    """A model directory that is missing files or has an unreadable config."""


@dataclass(frozen=True)
class UNetConfig:
    channels: tuple[int, ...] = (16, 32, 64)
    """U-Net widths per level (encoder-decoder with skips); compact so CPU generation stays fast."""
    layers_per_block: int = 1
    """ResNet blocks per level."""
    mid_attention: bool = True
    """Self-attention in the middle (lowest-resolution) block, for long-range hole patterns."""
    train_timesteps: int = 1000
    """DDPM diffusion steps used in training."""
    beta_schedule: str = "squaredcos_cap_v2"
    """diffusers beta schedule name."""
    prediction: str = "v_prediction"
    """What the network predicts: "v_prediction" (v = sqrt(abar) eps - sqrt(1 - abar) d_0, eq. 8's loss
    reweighted by 1 + 1/SNR) or "epsilon" (eq. 8 as written). With epsilon, the d_0 estimate at the first
    DDIM steps (SNR ~ 0 under this schedule) divides the noise error by sqrt(abar) ~ 0.02-0.15: measured,
    those steps alone turned ~17% of pixels into holes where real frames have 3% (docs/ddg.md)."""

    def __post_init__(self) -> None:
        if not self.channels or any(c % 8 for c in self.channels):
            raise ModelDirError(f"channels must be multiples of 8 (GroupNorm groups), got {self.channels}")
        if self.prediction not in ("epsilon", "v_prediction"):
            raise ModelDirError(f"prediction must be epsilon or v_prediction, got {self.prediction!r}")


DDG_IO = (2, 1)
"""(input, output) channels of the DDG's net: d_k ⊕ c in, the noise (or v) of d_k out."""


def build_unet(cfg: UNetConfig, spec: DepthSpec = POLICY_SPEC, io: tuple[int, int] = DDG_IO) -> UNet2DModel:
    n = len(cfg.channels)
    return UNet2DModel(
        sample_size=(spec.out_height, spec.out_width), in_channels=io[0], out_channels=io[1],
        block_out_channels=tuple(cfg.channels), layers_per_block=cfg.layers_per_block,
        down_block_types=("DownBlock2D",) * n, up_block_types=("UpBlock2D",) * n,
        add_attention=cfg.mid_attention, norm_num_groups=8, attention_head_dim=8)


def ddpm_scheduler(cfg: UNetConfig) -> DDPMScheduler:
    # clip_sample keeps the x0 estimate in the data range [-1, 1] (holes at -1, valid depth in [0, 1]).
    return DDPMScheduler(num_train_timesteps=cfg.train_timesteps, beta_schedule=cfg.beta_schedule,
                         prediction_type=cfg.prediction, clip_sample=True, clip_sample_range=1.0)


def ddim_scheduler(cfg: UNetConfig, steps: int) -> DDIMScheduler:
    if not 1 <= steps <= cfg.train_timesteps:
        raise ValueError(f"DDIM steps must be in 1..{cfg.train_timesteps}, got {steps}")
    s = DDIMScheduler.from_config(ddpm_scheduler(cfg).config, timestep_spacing="trailing")
    s.set_timesteps(steps)
    return s


class EpsNet(torch.nn.Module):
    """(x [B, in, H, W], t [B] int64) -> eps [B, out, H, W]: the plain-tensor face exported to ONNX."""

    def __init__(self, unet: UNet2DModel) -> None:
        super().__init__()
        self.unet = unet

    def forward(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.unet(x, t).sample


def save_model(out: Path, unet: UNet2DModel, cfg: UNetConfig, spec: DepthSpec, extra: dict) -> None:
    from safetensors.torch import save_file

    out.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in unet.state_dict().items()}, out / "unet.safetensors")
    config = {"unet": asdict(cfg), "depth_spec": spec.to_dict(), "x0_scale": X0_SCALE, **extra}
    (out / "config.json").write_text(json.dumps(config, indent=1))
    export_onnx(unet, spec, out / "unet.onnx")


RESIDUAL_SCALE = "residual"
"""The ``x0_scale`` a residual model records: its target is the sensor's depth minus the simulator's."""
SCALE_KINDS = {X0_SCALE: "DDG", RESIDUAL_SCALE: "residual depth diffusion"}
"""A model's ``x0_scale`` -> the kind of model that made it."""


def load_config(model_dir: str | Path, x0_scale: str = X0_SCALE) -> dict:
    """The config of a model of the kind that ``x0_scale`` names; ``io`` is its (input, output) channels."""
    f = Path(model_dir) / "config.json"
    if not f.is_file():
        raise ModelDirError(f"{model_dir}: no config.json (not a {SCALE_KINDS[x0_scale]} model directory)")
    raw = json.loads(f.read_text())
    made = raw.get("x0_scale")
    if made != x0_scale and made in SCALE_KINDS:
        raise ModelDirError(f"{model_dir}: a {SCALE_KINDS[made]} model, not a {SCALE_KINDS[x0_scale]} one")
    if made != x0_scale or "prediction" not in raw["unet"]:
        old = raw.get("x0_scale", "metric"), raw["unet"].get("prediction", "eps")
        was = f"target scale {old[0]}, prediction {old[1]}"
        raise ModelDirError(f"{model_dir}: made by an older trainer ({was}); this version decodes the "
                            f"{x0_scale} scale and needs the prediction type: retrain it")
    raw["unet"] = UNetConfig(**{**raw["unet"], "channels": tuple(raw["unet"]["channels"])})
    raw["depth_spec"] = DepthSpec.from_dict(raw["depth_spec"])
    raw["io"] = tuple(raw.get("io", DDG_IO))
    return raw


def model_id(model_dir: str | Path) -> str:
    """Directory name + the first 12 hex digits of the ONNX weights' sha256: two trainings of one
    ``models/ddg`` differ, so a store's record of which generator made its depth can tell them apart."""
    f = Path(model_dir) / "unet.onnx"
    if not f.is_file():
        raise ModelDirError(f"{model_dir}: no unet.onnx")
    return f"{Path(model_dir).resolve().name}@{hashlib.sha256(f.read_bytes()).hexdigest()[:12]}"


def load_unet(model_dir: str | Path, x0_scale: str = X0_SCALE) -> tuple[UNet2DModel, dict]:
    from safetensors.torch import load_file

    cfg = load_config(model_dir, x0_scale)
    weights = Path(model_dir) / "unet.safetensors"
    if not weights.is_file():
        raise ModelDirError(f"{model_dir}: no unet.safetensors")
    unet = build_unet(cfg["unet"], cfg["depth_spec"], cfg["io"])
    unet.load_state_dict(load_file(weights))
    return unet.eval(), cfg


def export_onnx(unet: UNet2DModel, spec: DepthSpec, path: Path) -> None:
    x = torch.zeros(2, unet.config.in_channels, spec.out_height, spec.out_width)
    t = torch.full((2,), 10, dtype=torch.int64)
    torch.onnx.export(EpsNet(unet).eval(), (x, t), str(path), input_names=["x", "t"], output_names=["eps"],
                      dynamic_axes={"x": {0: "batch"}, "t": {0: "batch"}, "eps": {0: "batch"}},
                      opset_version=17, dynamo=False)
