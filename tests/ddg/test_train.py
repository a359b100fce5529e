from dataclasses import replace

import numpy as np
import pytest
import torch

from trainer.ddg.bank import save_bank
from trainer.ddg.model import UNetConfig, build_unet, ddpm_scheduler
from trainer.ddg.train import FitConfig, fit, train_step
from trainer.diffusion import training_target

from .conftest import scene


def _tiny_bank(n=4):
    rng = np.random.default_rng(0)
    depth = np.stack([scene(rng) for _ in range(n)])
    depth[:, 40:50, 60:80] = 0  # a hole where every frame has one: learnable
    c = np.stack([np.linspace(-1, 1, 96 * 128).reshape(96, 128)] * n).astype(np.float16)
    scale = np.tile(np.float32([0.2, 0.4]), (n, 1))  # 0.54-1.02 m on the relative target scale
    return {"depth_mm": depth, "c": c, "scale": scale, "frame": np.arange(n),
            "names": np.array([f"f{i}" for i in range(n)])}


def _eval_loss(unet, sched, x0, c):
    g = torch.Generator().manual_seed(123)
    eps = torch.randn(x0.shape, generator=g)
    k = torch.linspace(50, 900, len(x0)).long()
    with torch.no_grad():
        pred = unet(torch.cat([sched.add_noise(x0, eps, k), c], 1), k).sample
    return float(torch.nn.functional.mse_loss(pred, training_target(sched, x0, eps, k)))


def test_a_tiny_model_overfits_a_tiny_set():
    from trainer.ddg.bank import training_arrays

    torch.manual_seed(0)
    x0, c = (torch.from_numpy(a) for a in training_arrays(_tiny_bank()))
    x0s, cs = x0[:, None, :32, :32], c[:, None, :32, :32]  # 32x32 patches keep it fast
    cfg = FitConfig(batch=4, patch=(0, 0), seed=0)
    unet = build_unet(UNetConfig(channels=(8, 8, 16)))
    sched = ddpm_scheduler(UNetConfig())
    opt = torch.optim.AdamW(unet.parameters(), lr=3e-3)
    before = _eval_loss(unet, sched, x0s, cs)
    for step in range(120):
        train_step(unet, opt, sched, x0[:, :32, :32], c[:, :32, :32], cfg, step)
    after = _eval_loss(unet, sched, x0s, cs)
    assert after < 0.35 * before, (before, after)


def test_fit_checkpoints_resumes_and_writes_a_model_dir(tmp_path):
    bank = tmp_path / "bank.npz"
    save_bank(_tiny_bank(), bank)
    common = dict(bank=(str(bank),), run=str(tmp_path / "run"), out=str(tmp_path / "model"), batch=2,
                  patch=(32, 32), ckpt_every=2, channels=(8, 8, 16), threads=1)
    fit(FitConfig(steps=2, **common))
    first = torch.load(tmp_path / "run" / "ckpt.pt", weights_only=True)
    out = fit(FitConfig(steps=4, **common))
    ck = torch.load(tmp_path / "run" / "ckpt.pt", weights_only=True)
    assert first["step"] == 2 and ck["step"] == 4 and ck["losses"][:2] == first["losses"]
    assert {p.name for p in out.iterdir()} >= {"config.json", "unet.safetensors", "unet.onnx", "loss.png",
                                               "frames.txt"}
    assert (out / "frames.txt").read_text().split() == ["f0", "f1", "f2", "f3"]


def _far_scene() -> np.ndarray:
    """A floor receding from 1 m (bottom row) to 5 m (top row), with holes along its far end."""
    depth = np.rint(np.linspace(5000, 1000, 96))[:, None].repeat(128, axis=1).astype(np.uint16)
    depth[:10, ::3] = 0
    return depth


def test_far_m_lets_the_prior_and_target_see_past_the_policy_range(tmp_path):
    from trainer.ddg.bank import BankConfig, bank_spec, build_bank, training_arrays
    from trainer.ddg.data import RealFrame
    from trainer.ddg.model import load_config

    frames = [RealFrame(f"f{i}", _far_scene(), "d4xx", "s", i) for i in range(2)]  # a crop is the whole frame
    beyond = slice(12, 40)  # rows at 3.3-4.5 m
    default, wide = (build_bank(frames, BankConfig(crops=2, far_m=far, depth_jitter=(1.0, 1.0)))
                     for far in (1.5, 6.0))
    assert bank_spec(default).far_m == 1.5 and bank_spec(wide).far_m == 6.0
    c_default, c_wide = (training_arrays(b)[1] for b in (default, wide))
    assert np.ptp(c_default[:, beyond], axis=1).max() == 0  # flattened: the far floor is one value
    assert np.ptp(c_wide[:, beyond], axis=1).min() > 0.1  # the far floor keeps its slope
    bank = tmp_path / "wide.npz"
    save_bank(wide, bank)
    out = fit(FitConfig(steps=1, bank=(str(bank),), far_m=6.0, run=str(tmp_path / "run"),
                        out=str(tmp_path / "model"), batch=2, patch=(32, 32), channels=(8, 8, 16), threads=1))
    assert load_config(out)["depth_spec"].far_m == 6.0  # generation uses the range the model learnt on


def test_banks_of_two_depth_ranges_are_not_mixed(tmp_path):
    from trainer.ddg.bank import concat_banks

    narrow, wide = _tiny_bank(), {**_tiny_bank(), "far_m": np.float64(6.0)}
    assert concat_banks([narrow, narrow])["far_m"] == 1.5
    with pytest.raises(ValueError, match="different depth ranges"):
        concat_banks([narrow, wide])
    save_bank(wide, tmp_path / "wide.npz")
    with pytest.raises(ValueError, match="far_m 6.0"):
        fit(FitConfig(steps=1, bank=(str(tmp_path / "wide.npz"),), run=str(tmp_path / "r"),
                      out=str(tmp_path / "m"), batch=2, patch=(32, 32), channels=(8, 8, 16), threads=1))
    with pytest.raises(ValueError, match="--leave-out picks frames of --real"):
        fit(FitConfig(steps=1, bank=(str(tmp_path / "wide.npz"),), leave_out="ucn_demo",
                      run=str(tmp_path / "r"), out=str(tmp_path / "m"), batch=2, patch=(32, 32),
                      channels=(8, 8, 16), threads=1))


def test_an_exact_prior_leaves_what_the_sensor_gets_wrong_to_the_target(tmp_path):
    from trainer.ddg.bank import BankConfig, build_bank, concat_banks, training_arrays
    from trainer.ddg.data import RealFrame

    exact = np.rint(np.linspace(1400, 900, 96))[:, None].repeat(128, axis=1).astype(np.uint16)
    sensed = exact.copy()
    sensed[40:56, 50:80] -= 150  # a patch the sensor sees 15 cm too near
    frames = [RealFrame(f"f{i}", sensed, "d4xx", "s", i, exact_mm=exact) for i in range(2)]
    cfg = BankConfig(crops=1, depth_jitter=(1.0, 1.0), scale_range=(1.0, 1.0))  # the whole frame
    fused, exact_bank = (build_bank(frames, replace(cfg, prior=p)) for p in ("fused", "exact"))

    def step(a: np.ndarray) -> float:  # the patch against the same rows beside it, in c or x0 units
        return float(np.median(a[0, 44:52, 55:75]) - np.median(a[0, 44:52, 90:110]))

    (x0_f, c_f), (x0_e, c_e) = training_arrays(fused), training_arrays(exact_bank)
    assert step(c_f) < -0.05 and step(x0_f) < -0.05  # fused: the wrong depth is in c, nothing to learn
    assert abs(step(c_e)) < 0.01 and step(x0_e) < -0.05  # exact: c is the true scene, x0 the wrong patch
    with pytest.raises(ValueError, match="different priors"):
        concat_banks([fused, exact_bank])
    with pytest.raises(ValueError, match="needs each frame's exact depth .* 2 frames have none"):
        build_bank([replace(f, exact_mm=None) for f in frames], replace(cfg, prior="exact"))
    save_bank(exact_bank, tmp_path / "exact.npz")
    with pytest.raises(ValueError, match="--prior fused but the crop bank was made with prior exact"):
        fit(FitConfig(steps=1, bank=(str(tmp_path / "exact.npz"),), run=str(tmp_path / "r"),
                      out=str(tmp_path / "m"), batch=2, patch=(32, 32), channels=(8, 8, 16), threads=1))
