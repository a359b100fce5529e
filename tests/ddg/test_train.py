import numpy as np
import torch

from trainer.ddg.bank import save_bank
from trainer.ddg.model import UNetConfig, build_unet, ddpm_scheduler
from trainer.ddg.train import FitConfig, fit, train_step, training_target

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
